"""UDP datagrams out of packet captures (pcap and pcapng, as written by Wireshark/tcpdump), through ``dpkt``.

Handles Ethernet (with VLAN tags), Linux cooked (SLL, SLL2), BSD loopback and raw-IP link types, and
reassembles fragmented IPv4 datagrams (large NatNet frames and MODELDEFs exceed one Ethernet MTU).
Limitation: a pcapng file is read with the link type of its first interface.
"""

from __future__ import annotations

import socket
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from beambench.common.errors import BeambenchError
from beambench.common.inputs import check_input_file

__all__ = ["CaptureError", "UdpDatagram", "read_udp"]


class CaptureError(BeambenchError, ValueError):
    """The file is not a readable pcap/pcapng capture, or its link type is not supported."""


@dataclass(frozen=True)
class UdpDatagram:
    """One UDP payload with its capture time (s since the epoch) and addresses."""

    time: float
    src: str
    sport: int
    dst: str
    dport: int
    payload: bytes


# pcap link types (https://www.tcpdump.org/linktypes.html)
_ETHERNET, _NULL, _RAW, _RAW_OPENBSD, _LOOP, _SLL, _IPV4, _SLL2 = 1, 0, 101, 12, 108, 113, 228, 276


def _reader(f):
    import dpkt

    head = f.read(4)
    f.seek(0)
    try:
        if head == b"\x0a\x0d\x0d\x0a":
            return dpkt.pcapng.Reader(f)
        return dpkt.pcap.Reader(f)
    except (ValueError, dpkt.dpkt.Error) as exc:
        raise CaptureError(f"not a pcap or pcapng capture ({exc})") from None


def _ip_of(linktype: int, buf: bytes):
    """The IPv4 packet inside one link-layer frame, or None."""
    import dpkt

    if linktype == _ETHERNET:
        pkt = dpkt.ethernet.Ethernet(buf).data
    elif linktype == _SLL:
        pkt = dpkt.sll.SLL(buf).data
    elif linktype == _SLL2:
        pkt = dpkt.sll2.SLL2(buf).data
    elif linktype in (_NULL, _LOOP):
        pkt = dpkt.loopback.Loopback(buf).data
    elif linktype in (_RAW, _RAW_OPENBSD, _IPV4):
        pkt = dpkt.ip.IP(buf) if buf[:1] and buf[0] >> 4 == 4 else None
    else:
        raise CaptureError(f"unsupported link type {linktype}")
    return pkt if isinstance(pkt, dpkt.ip.IP) else None


MAX_PENDING = 1024  # datagrams being reassembled at once; the oldest is dropped beyond this
MAX_DATAGRAM = 65_535  # an IPv4 datagram cannot be larger


def _datagrams(packets: Iterable[tuple[float, bytes]], linktype: int) -> Iterator[tuple[float, Any, bytes]]:
    """(time, ip, UDP bytes) with IPv4 fragments reassembled; malformed frames are skipped.

    A fragment that cannot be part of a valid datagram is dropped: an empty one (which advanced nothing and
    hung the joining loop), one past 64 KiB; a datagram whose fragments do not join end to end is never yielded.
    At most :data:`MAX_PENDING` datagrams wait for their missing fragments.
    """
    import dpkt

    frags: dict[tuple, dict[int, bytes]] = {}
    last: dict[tuple, int] = {}
    for ts, buf in packets:
        try:
            ip = _ip_of(linktype, buf)
        except (dpkt.dpkt.UnpackError, dpkt.dpkt.NeedData, IndexError, ValueError):
            continue
        if ip is None or ip.p != dpkt.ip.IP_PROTO_UDP:
            continue
        body = bytes(ip.data) if not isinstance(ip.data, bytes) else ip.data
        offset = ip.offset  # bytes
        if not ip.mf and offset == 0:
            yield ts, ip, body
            continue
        if not body or offset + len(body) > MAX_DATAGRAM:
            continue
        key = (ip.src, ip.dst, ip.id, ip.p)
        if key not in frags and len(frags) >= MAX_PENDING:
            oldest = next(iter(frags))
            del frags[oldest]
            last.pop(oldest, None)
        frags.setdefault(key, {})[offset] = body
        if not ip.mf:
            last[key] = offset + len(body)
        if key in last:
            joined = _join(frags[key], last[key])
            if joined is not None:
                del frags[key], last[key]
                yield ts, ip, joined


def _join(parts: dict[int, bytes], total: int) -> bytes | None:
    """The fragments joined from offset 0 to ``total``, or None while one is missing. Every part is non-empty,
    so each turn of the loop advances."""
    out = bytearray()
    while len(out) < total:
        part = parts.get(len(out))
        if not part:
            return None
        out += part
    return bytes(out[:total])


def read_udp(path: str | Path, ports: Iterable[int] | None = None) -> Iterator[UdpDatagram]:
    """Every UDP datagram of a capture, in file order; with ``ports``, only those to or from one of them."""
    import dpkt

    want = set(ports) if ports is not None else None
    p = Path(path)
    check_input_file(p, "capture", None, CaptureError)  # streamed, so any size; but a file, not a FIFO/device
    try:
        f = p.open("rb")
    except OSError as exc:
        raise CaptureError(f"cannot open {p}: {exc.strerror}") from None
    with f:
        rd = _reader(f)
        linktype = rd.datalink()
        if linktype not in (_ETHERNET, _NULL, _RAW, _RAW_OPENBSD, _LOOP, _SLL, _IPV4, _SLL2):
            raise CaptureError(f"unsupported link type {linktype}")
        try:
            for ts, ip, raw in _datagrams(rd, linktype):
                if len(raw) < 8:
                    continue
                try:
                    udp = dpkt.udp.UDP(raw)
                except (dpkt.dpkt.UnpackError, dpkt.dpkt.NeedData):
                    continue
                if want is not None and udp.sport not in want and udp.dport not in want:
                    continue
                yield UdpDatagram(
                    float(ts), socket.inet_ntoa(ip.src), udp.sport, socket.inet_ntoa(ip.dst), udp.dport, bytes(udp.data)
                )
        except (ValueError, dpkt.dpkt.Error, EOFError) as exc:  # truncated capture file
            raise CaptureError(f"{p}: damaged capture ({exc})") from None
