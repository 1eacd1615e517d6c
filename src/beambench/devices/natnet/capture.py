"""Decode the NatNet traffic of a packet capture into frames and a one-row-per-frame table.

The NatNet version comes from a SERVERINFO in the capture (and follows an acknowledged ``Bitstream,X.Y``
command), else from the caller. Used by ``beambench natnet decode`` and by the decoder's tests.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from beambench.common.text import printable
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.natnet.pcap import read_udp

__all__ = ["CaptureDecode", "decode_capture", "frames_table"]

NATNET_PORTS = (1510, 1511)
BASE_COLUMNS = (
    "capture_time_s",
    "frame",
    "timecode",
    "timestamp_s",
    "mid_exposure_ticks",
    "data_received_ticks",
    "transmit_ticks",
    "precision_s",
    "precision_frac",
    "software_latency_ms",
    "system_latency_ms",
    "params",
    "n_rigid_bodies",
    "n_labeled_markers",
    "n_other_markers",
)


@dataclass
class CaptureDecode:
    """Frames of a capture (capture time, frame), the version used and what went wrong."""

    frames: list[tuple[float, nf.FrameOfData]] = field(default_factory=list)
    server_info: nn.ServerInfo | None = None
    version: nw.Version | None = None
    version_source: str = ""
    datagrams: int = 0
    parse_errors: int = 0
    dropped_frames: int = 0
    out_of_order: int = 0
    errors: list[str] = field(default_factory=list)
    note: str = ""

    @property
    def frame_rate_hz(self) -> float | None:
        """From the median spacing of Motive's frame timestamps."""
        ts = sorted(f.timestamp for _, f in self.frames)
        d = sorted(b - a for a, b in itertools.pairwise(ts) if b > a)
        return 1.0 / d[len(d) // 2] if d else None

    def summary(self, name: str = "capture") -> str:
        n = len(self.frames)
        span = f" ({self.frames[0][1].frame_number}–{self.frames[-1][1].frame_number})" if n else ""
        rate = self.frame_rate_hz
        src = self.version_source
        if self.server_info is not None and src == "SERVERINFO":
            src += f": {printable(self.server_info.app_name, 80)} {printable(self.server_info.app_version, 40)}"
        parts = [
            f"{name}: {n} frames{span}",
            f"{self.dropped_frames} dropped",
            f"{self.out_of_order} out of order",
            f"{self.parse_errors} parse errors",
            f"NatNet {self.version.short() if self.version else '?'} ({src})",
        ]
        if rate:
            parts.append(f"{rate:.2f} Hz")
        line = ", ".join(parts)
        return f"{line}; {self.note}" if self.note else line


def decode_capture(
    path: str | Path, version: str | nw.Version | None = None, ports: Iterable[int] = NATNET_PORTS
) -> CaptureDecode:
    """Decode every NatNet frame of a pcap/pcapng file. Raises ValueError if no version can be known."""
    grams = list(read_udp(path, ports))
    out = CaptureDecode(datagrams=len(grams))
    given = None
    if version is not None:
        given = nw.Version.parse(version) if isinstance(version, str) else nw.Version(*version)
        given = nw.Version(given.major, given.minor)
    current: nw.Version | None = None
    for g in grams:  # the first SERVERINFO sets the version of the whole capture's start
        if len(g.payload) >= 4 and nn.peek_message_id(g.payload) == nw.MessageId.SERVERINFO:
            try:
                info = nn.decode(g.payload)
            except nw.NatNetParseError:
                continue
            out.server_info = info  # type: ignore[assignment]
            current = nw.Version(info.natnet_version.major, info.natnet_version.minor)  # type: ignore[union-attr]
            out.version_source = "SERVERINFO"
            if given is not None and given != current:
                out.note = f"--natnet-version {given.short()} ignored: SERVERINFO says {current.short()}"
            break
    if current is None:
        if given is None:
            raise ValueError("no SERVERINFO in the capture: give the NatNet version (--natnet-version X.Y)")
        current, out.version_source = given, "option"
    out.version = current
    pending: nw.Version | None = None
    last: int | None = None
    for g in grams:
        p = g.payload
        if len(p) < 4:
            continue
        mid = nn.peek_message_id(p)
        try:
            if mid == nw.MessageId.FRAMEOFDATA:
                frame = nn.decode(p, current)
                assert isinstance(frame, nf.FrameOfData)
                n = frame.frame_number
                if last is not None:
                    if n > last + 1:
                        out.dropped_frames += n - last - 1
                    elif n <= last:
                        out.out_of_order += 1
                last = n
                out.frames.append((g.time, frame))
            elif mid == nw.MessageId.REQUEST:
                cmd = nn.decode(p).command  # type: ignore[union-attr]
                name, _, arg = cmd.partition(",")
                pending = None
                if name.strip().lower() == "bitstream" and arg:
                    try:
                        v = nw.Version.parse(arg)
                        pending = nw.Version(v.major, v.minor)
                    except ValueError:
                        pending = None
            elif mid == nw.MessageId.RESPONSE and pending is not None:
                resp = nn.decode(p)
                if len(resp.payload_bytes) == 4 and resp.as_int() == 0:  # type: ignore[union-attr]
                    current = pending
                pending = None
        except nw.NatNetParseError as exc:
            out.parse_errors += 1
            if len(out.errors) < 20:
                out.errors.append(f"t={g.time:.6f} {g.src}:{g.sport}→{g.dst}:{g.dport}: {exc}")
    return out


def frames_table(decoded: CaptureDecode):
    """One row per frame: frame number, timestamp suffix, rigid bodies and labeled markers (wide, by id).

    Rigid-body columns are ``rb<id>_{x,y,z,qx,qy,qz,qw,error,valid}``; labeled-marker columns
    ``m<model>_<marker>_{x,y,z,size,occluded,params}``; empty where a frame lacks that body or marker.
    """
    import pandas as pd

    freq = decoded.server_info.clock_frequency if decoded.server_info else None
    rows = []
    rb_ids: set[int] = set()
    mk_ids: set[tuple[int, int]] = set()
    for t, f in decoded.frames:
        row: dict[str, object] = {
            "capture_time_s": t,
            "frame": f.frame_number,
            "timecode": f.timecode_string,
            "timestamp_s": f.timestamp,
            "mid_exposure_ticks": f.mid_exposure,
            "data_received_ticks": f.data_received,
            "transmit_ticks": f.transmit,
            "precision_s": f.precision_seconds,
            "precision_frac": f.precision_fraction,
            "software_latency_ms": (f.transmit - f.data_received) * 1e3 / freq if freq else None,
            "system_latency_ms": (f.transmit - f.mid_exposure) * 1e3 / freq if freq else None,
            "params": f.params,
            "n_rigid_bodies": len(f.rigid_bodies),
            "n_labeled_markers": len(f.labeled_markers),
            "n_other_markers": len(f.other_markers),
        }
        for rb in f.rigid_bodies:
            rb_ids.add(rb.id)
            k = f"rb{rb.id}_"
            row.update(zip((k + c for c in ("x", "y", "z")), rb.position))
            row.update(zip((k + c for c in ("qx", "qy", "qz", "qw")), rb.orientation))
            row[k + "error"] = rb.error
            row[k + "valid"] = int(rb.tracking_valid)
        for lm in f.labeled_markers:
            mk_ids.add((lm.model_id, lm.marker_id))
            k = f"m{lm.model_id}_{lm.marker_id}_"
            row.update(zip((k + c for c in ("x", "y", "z")), lm.position))
            row[k + "size"] = lm.size
            row[k + "occluded"] = int(lm.occluded)
            row[k + "params"] = lm.params
        rows.append(row)
    cols = list(BASE_COLUMNS) + [
        f"rb{i}_{c}" for i in sorted(rb_ids) for c in ("x", "y", "z", "qx", "qy", "qz", "qw", "error", "valid")
    ]
    cols += [f"m{a}_{b}_{c}" for a, b in sorted(mk_ids) for c in ("x", "y", "z", "size", "occluded", "params")]
    df = pd.DataFrame(rows, columns=cols)
    for c in df.columns:  # integer columns with gaps stay integers; QPC ticks are unsigned 64-bit on the wire
        if c.endswith("_ticks"):
            df[c] = df[c].astype("UInt64")
        elif c.endswith(("_valid", "_occluded", "_params")) or c in ("precision_s", "precision_frac"):
            df[c] = df[c].astype("Int64")
    return df
