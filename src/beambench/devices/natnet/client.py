"""NatNet client for OptiTrack Motive (NatNet 3.0, 4.0, 4.1).

:class:`NatNetClient` speaks the protocol over UDP: CONNECT → SERVERINFO on the command port (1510), then
MODELDEF, the ``FrameRate`` request and ECHO round trips (kept for clock sync, best by minimum round-trip
time). Frames arrive by multicast (239.255.42.99:1511 by default) or, in unicast, on the command socket, which
is kept alive with KEEPALIVE messages. Every address and port is configurable. One receive thread decodes
everything (frames too, unless a reader takes them raw: ``keep_raw``); a malformed packet is counted
(``stats.parse_errors``) and skipped, a gap in frame numbers adds to ``stats.dropped_frames``; nothing
received can stop the thread.

The ``mocap`` stream built on it is :mod:`beambench.devices.natnet.mocap`.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import queue
import selectors
import socket
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from beambench.acquisition.capabilities import DeviceFault
from beambench.devices.foreign import ForeignSenders
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import modeldef as nm
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.receive_time import enable_receive_timestamps, mono_minus_real_ns, recv_stamped

__all__ = ["EchoSample", "NatNetClient", "NatNetConfig", "NatNetError", "NatNetStats", "ping"]

log = logging.getLogger(__name__)

DEFAULT_MULTICAST = "239.255.42.99"
DEFAULT_DATA_PORT = 1511
BITSTREAM_GRACE_NS = 500_000_000  # after a bitstream change, frames encoded before it may arrive for this long
CLIENT_VERSION = nw.Version(0, 1, 0, 0)
# After a wake-up the receive thread waits this long, so that one pass reads ~7 frames at 360 Hz: waking up per
# frame costs more CPU than decoding it (receive thread 8.0 % of a core at 4 ms, 4.8 % at 20 ms, with the
# emulated Motive). The kernel's receive stamps keep each frame's own arrival time.
RECEIVE_COALESCE_S = 0.020
STREAM_SETTINGS = frozenset({"silence_timeout_s"})  # rig-file keys of the mocap stream, not of the client


class NatNetError(DeviceFault):
    """The NatNet server did not answer, refused a request, or the receive thread failed."""


@dataclass
class NatNetConfig:
    """Where Motive is and how to listen. ``None`` for data port / multicast group means "as SERVERINFO says"."""

    server_address: str = "127.0.0.1"
    local_address: str = "127.0.0.1"  # our interface: bind address, and where to join the multicast group
    command_port: int = 1510
    data_port: int | None = None
    multicast_address: str | None = None
    multicast: bool = True
    bitstream_version: str | None = None  # ask a NatNet 4.x server to stream this version ("3.0", "4.0", "4.1")
    timeout_s: float = 2.0
    keepalive_interval_s: float = 1.0
    echo_interval_s: float = 0.5
    echo_history: int = 256
    initial_echoes: int = 8
    recv_buffer_bytes: int = 4 << 20
    client_name: str = "beambench"

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any]) -> NatNetConfig:
        """Build from a rig-file mapping; unknown keys are an error naming them."""
        d = {k: v for k, v in d.items() if k not in STREAM_SETTINGS}
        known = set(cls.__dataclass_fields__)
        bad = sorted(set(d) - known)
        if bad:
            raise ValueError(f"unknown NatNet setting(s) {bad}; known: {sorted(known)}")
        return cls(**dict(d))


@dataclass(frozen=True)
class EchoSample:
    """One ECHO round trip: host send/receive (monotonic ns) and the server's QPC ticks on receipt."""

    host_send_ns: int
    host_recv_ns: int
    server_ticks: int

    @property
    def rtt_ns(self) -> int:
        return self.host_recv_ns - self.host_send_ns

    @property
    def host_mid_ns(self) -> int:
        return (self.host_send_ns + self.host_recv_ns) // 2


@dataclass
class NatNetStats:
    packets: int = 0
    frames: int = 0
    dropped_frames: int = 0  # sum of gaps in frame numbers
    out_of_order: int = 0  # frame numbers that went backwards or repeated
    parse_errors: int = 0
    ignored: int = 0  # packets that could not be used (e.g. frames before SERVERINFO)
    echoes: int = 0
    overflowed: int = 0  # frames pushed out of the receive buffer because nobody read them in time
    forged: int = 0  # datagrams from a sender that is not the server the handshake found (dropped)
    kernel_dropped: int = 0  # datagrams the kernel dropped before they were read (receive buffer full)
    last_frame_ns: int | None = None  # host monotonic time of the newest frame
    first_frame_number: int | None = None
    last_frame_number: int | None = None
    last_error: str = ""


class NatNetClient:
    """A NatNet client with one receive thread. Use as a context manager or ``connect()`` / ``close()``."""

    def __init__(
        self, config: NatNetConfig | None = None, on_frame: Callable[[int, nf.FrameOfData], None] | None = None
    ):
        self.config = config or NatNetConfig()
        self.on_frame = on_frame
        self.stats = NatNetStats()
        self.refused = ForeignSenders()  # the forged datagrams by sender, and the kernel's drops: names a flood
        self.server_info: nn.ServerInfo | None = None
        self.model_def: nm.ModelDef | None = None
        self.frame_rate: float | None = None
        self.version: nw.Version | None = None
        self.echoes: collections.deque[EchoSample] = collections.deque(maxlen=self.config.echo_history)
        self.frames: collections.deque[tuple[int, nf.FrameOfData]] = collections.deque(maxlen=100_000)
        self.keep_frames = False
        # keep_raw: frames are kept undecoded (host ns, packet, version) for a reader that decodes many at once
        # (NatNetMocap); the reader then counts them with account_frames()
        self.raw_frames: collections.deque[tuple[int, bytes, nw.Version]] = collections.deque(maxlen=100_000)
        self.keep_raw = False
        self._cmd: socket.socket | None = None
        self._data: socket.socket | None = None
        self._sel: selectors.DefaultSelector | None = None
        self._stamped = False  # the kernel stamps received datagrams (see receive_time)
        # the latest receive time handed on: stamps never go back (after the host stalls for longer than
        # receive_time's 1 s age limit, the first datagrams read get the read time and the next ones their older
        # kernel stamps; a frame is then stamped no earlier than the one before it)
        self._last_host_ns = 0
        self._pending_bitstream: nw.Version | None = None  # asked for, not yet confirmed
        # after a bitstream change: the version before it and until when (monotonic ns) a frame may still be in it
        self._previous_bitstream: tuple[nw.Version, int] | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._serverinfo_evt = threading.Event()
        self._modeldef_evt = threading.Event()
        self._responses: queue.Queue[nn.Response | nn.UnrecognizedRequest] = queue.Queue()
        self._request_lock = threading.Lock()
        self._pending_echo: dict[int, int] = {}
        self._last_keepalive = 0.0
        self._last_echo = 0.0
        self._thread_error: BaseException | None = None
        self._lock = threading.Lock()
        self._server_ip: str | None = None  # the server's address, resolved at connect

    # ------------------------------------------------------------------ lifecycle

    @property
    def server_address(self) -> tuple[str, int]:
        return (self.config.server_address, self.config.command_port)

    @property
    def receive_address(self) -> tuple[str, int] | None:
        """Our end of the command socket (host, port): where the server's replies, and in unicast its frames,
        arrive (what a unicast server sees as this client); None while not connected."""
        cmd = self._cmd
        if cmd is None:
            return None
        host, port = cmd.getsockname()
        return (host, port)

    def connect(self) -> NatNetClient:
        """Handshake (CONNECT/SERVERINFO), join the data stream, fetch MODELDEF and frame rate, sync clocks."""
        cfg = self.config
        try:
            self._server_ip = socket.gethostbyname(cfg.server_address)
        except OSError as exc:
            raise NatNetError(f"NatNet: cannot resolve the server address {cfg.server_address!r}: {exc}") from None
        try:
            self._cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
            self._cmd.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, cfg.recv_buffer_bytes)
            self._cmd.bind((cfg.local_address, 0))
            self._cmd.setblocking(False)
            self._stamped = enable_receive_timestamps(self._cmd)
        except OSError as exc:
            self.close()
            raise NatNetError(f"NatNet: cannot open the command socket on {cfg.local_address}: {exc}") from None
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._cmd, selectors.EVENT_READ)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="natnet-rx", daemon=True)
        self._thread.start()
        try:
            self._handshake()
        except BaseException:
            self.close()
            raise
        return self

    def _handshake(self) -> None:
        cfg = self.config
        hello = nn.Connect(nn.Sender(cfg.client_name, CLIENT_VERSION, nw.V4_1))
        for _ in range(3):
            self.send(hello)
            if self._serverinfo_evt.wait(cfg.timeout_s / 3):
                break
        else:
            raise NatNetError(
                f"NatNet: no SERVERINFO from {cfg.server_address}:{cfg.command_port} within {cfg.timeout_s} s"
            )
        info = self.server_info
        assert info is not None
        if info.natnet_version.major not in (3, 4):
            raise NatNetError(f"NatNet: server speaks NatNet {info.natnet_version}; supported are 3.0, 4.0 and 4.1")
        if info.natnet_version[:2] > (4, 1):
            log.warning("NatNet: server speaks %s; decoding as 4.1 (newer fields are skipped)", info.natnet_version)
        if cfg.multicast:
            self._open_data_socket(info)
        if cfg.bitstream_version:
            self.set_bitstream_version(cfg.bitstream_version)
        self.request_model_def()
        try:
            self.frame_rate = self.request("FrameRate").as_float()
        except (NatNetError, nw.NatNetParseError) as exc:
            log.warning("NatNet: FrameRate request failed: %s", exc)
        for _ in range(cfg.initial_echoes):
            self.send_echo()
            time.sleep(0.005)
        deadline = time.monotonic() + min(cfg.timeout_s, 0.5)
        while self.stats.echoes < cfg.initial_echoes and time.monotonic() < deadline:
            time.sleep(0.005)

    def _open_data_socket(self, info: nn.ServerInfo) -> None:
        cfg = self.config
        port = cfg.data_port or info.data_port or DEFAULT_DATA_PORT
        group = cfg.multicast_address or info.multicast_group or DEFAULT_MULTICAST
        if group in ("0.0.0.0", "255.255.255.255"):
            group = DEFAULT_MULTICAST
        try:
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if hasattr(socket, "SO_REUSEPORT"):
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, cfg.recv_buffer_bytes)
            s.bind(("" if sys.platform == "win32" else group, port))
            iface = socket.inet_aton(cfg.local_address if cfg.local_address not in ("", "0.0.0.0") else "0.0.0.0")
            s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, socket.inet_aton(group) + iface)
            s.setblocking(False)
            self._stamped = self._stamped and enable_receive_timestamps(s)
        except OSError as exc:
            raise NatNetError(f"NatNet: cannot join multicast {group}:{port} on {cfg.local_address}: {exc}") from None
        self._data = s
        assert self._sel is not None
        self._sel.register(s, selectors.EVENT_READ)

    def close(self) -> None:
        """Stop the thread and close the sockets (tells a unicast server we left). Idempotent."""
        if self._cmd is not None and not self.config.multicast and self.server_info is not None:
            with contextlib.suppress(OSError):
                self.send(nn.Disconnect())
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        self.note_kernel_drops()  # the last count, before the sockets are gone
        for s in (self._data, self._cmd):
            if s is not None:
                with contextlib.suppress(OSError):
                    s.close()
        self._data = self._cmd = None
        if self._sel is not None:
            self._sel.close()
            self._sel = None

    def __enter__(self) -> NatNetClient:
        return self.connect() if self._cmd is None else self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ requests

    def send(self, message: nn.Message) -> None:
        if self._cmd is None:
            raise NatNetError("NatNet: client is not connected")
        self._cmd.sendto(nn.encode(message, self.version), self.server_address)

    def request(self, command: str, timeout: float | None = None) -> nn.Response:
        """Send a text command (e.g. ``"FrameRate"``) and wait for its RESPONSE."""
        with self._request_lock:
            while not self._responses.empty():
                self._responses.get_nowait()
            self.send(nn.Request(command))
            try:
                reply = self._responses.get(timeout=timeout or self.config.timeout_s)
            except queue.Empty:
                raise NatNetError(
                    f"NatNet: no response to {command!r} within {timeout or self.config.timeout_s} s"
                ) from None
        if isinstance(reply, nn.UnrecognizedRequest):
            raise NatNetError(f"NatNet: server does not recognise {command!r}")
        return reply

    def request_model_def(self, timeout: float | None = None) -> nm.ModelDef | None:
        self._modeldef_evt.clear()
        self.send(nn.RequestModelDef())
        if not self._modeldef_evt.wait(timeout or self.config.timeout_s):
            log.warning("NatNet: no MODELDEF within %s s", timeout or self.config.timeout_s)
        return self.model_def

    def set_bitstream_version(self, version: str) -> None:
        """Ask a NatNet 4.x server to stream another version; frames are decoded with it from then on."""
        want = nw.Version.parse(version)
        want = nw.Version(want.major, want.minor)
        if want not in nw.SUPPORTED_VERSIONS:
            raise NatNetError(f"NatNet: cannot request bitstream {want}; supported: 3.0, 4.0, 4.1")
        assert self.server_info is not None
        if self.version is not None and (self.version.major, self.version.minor) == want[:2]:
            return
        if self.server_info.natnet_version.major < 4:
            raise NatNetError(f"NatNet: a NatNet {self.server_info.natnet_version} server cannot change its bitstream")
        with self._lock:
            self._pending_bitstream = want
        try:
            code = self.request(f"Bitstream,{want.major}.{want.minor}").as_int()
        finally:
            with self._lock:
                self._pending_bitstream = None
        if code != 0:
            raise NatNetError(f"NatNet: server refused bitstream {want} (code {code})")
        with self._lock:
            if self.version != want:
                self._switch_bitstream(want)

    def send_echo(self) -> None:
        stamp = time.monotonic_ns()
        with self._lock:
            self._pending_echo[stamp] = stamp
            if len(self._pending_echo) > 64:
                self._pending_echo.pop(next(iter(self._pending_echo)))
        self._last_echo = time.monotonic()
        self.send(nn.EchoRequest(stamp))

    # ------------------------------------------------------------------ clock sync

    def best_echo(self) -> EchoSample | None:
        """The echo with the smallest round trip among those kept (the min-RTT filter)."""
        samples = list(self.echoes)
        return min(samples, key=lambda e: e.rtt_ns) if samples else None

    def server_ticks_to_host_ns(self, ticks: int) -> int | None:
        """Host monotonic ns of a server QPC tick count, by the best echo (offset only; drift is for sync)."""
        best, freq = self.best_echo(), self.clock_frequency
        if best is None or not freq:
            return None
        return best.host_mid_ns + round((ticks - best.server_ticks) * 1e9 / freq)

    def echo_table(self) -> dict[str, np.ndarray]:
        """All kept echoes as arrays (host send/receive ns, server ticks), for fitting a clock map in sync."""
        e = list(self.echoes)
        return {
            "host_send_ns": np.array([x.host_send_ns for x in e], dtype=np.int64),
            "host_recv_ns": np.array([x.host_recv_ns for x in e], dtype=np.int64),
            "server_ticks": np.array([x.server_ticks for x in e], dtype=np.uint64),
        }

    @property
    def clock_frequency(self) -> int | None:
        return self.server_info.clock_frequency if self.server_info else None

    # ------------------------------------------------------------------ receive thread

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                sel = self._sel
                if sel is None:
                    break
                ready = sel.select(timeout=0.05)
                if ready and self._stamped:
                    time.sleep(RECEIVE_COALESCE_S)  # let a few frames gather: one wake-up reads them all
                for key, _ in ready:
                    self._drain(key.fileobj)  # type: ignore[arg-type]
                self._timers()
        except BaseException as exc:  # pragma: no cover - reported through read()/check()
            if not self._stop.is_set():
                self._thread_error = exc
                log.exception("NatNet receive thread failed")

    def _drain(self, sock: socket.socket) -> None:
        mono_minus_real = mono_minus_real_ns()
        for _ in range(256):
            try:
                data, addr, host_ns = recv_stamped(sock, 65536, self._stamped, mono_minus_real)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            if not self._from_server(sock, addr):
                if self._early(sock, addr):
                    self.stats.ignored += 1  # the server's, before its SERVERINFO named the port: not read
                else:
                    self._forged(addr)
                continue
            host_ns = self._last_host_ns = max(host_ns, self._last_host_ns)
            self._handle(data, host_ns)

    def _from_server(self, sock: socket.socket, addr: tuple[str, int]) -> bool:
        """Is this datagram from the server the handshake found? Multicast data: its address (the group is
        open to any sender on the network). Command socket (replies, and unicast data): its address and one of
        its ports, the command port or the data port its SERVERINFO announced."""
        if addr[0] != self._server_ip:
            return False
        if sock is self._data:
            return True
        info = self.server_info
        return addr[1] == self.config.command_port or (info is not None and addr[1] == info.data_port)

    def _early(self, sock: socket.socket, addr: tuple[str, int]) -> bool:
        """A datagram from the server's address that came before its SERVERINFO named its data port (a server
        may start streaming to a new client before its reply arrives): dropped like a forgery, but not counted as
        one."""
        return sock is self._cmd and addr[0] == self._server_ip and self.server_info is None

    def _forged(self, addr: tuple[str, int]) -> None:
        """A datagram not from the server: dropped, counted by sender (bounded work; the run names a flood once,
        at its end: :meth:`flood`)."""
        self.stats.forged += 1
        self.refused.add(addr)

    def note_kernel_drops(self) -> int:
        """The kernel's count of datagrams it dropped for this client's sockets before they were read."""
        self.refused.note_kernel(self._cmd, self._data)
        self.stats.kernel_dropped = self.refused.kernel_dropped
        return self.stats.kernel_dropped

    def flood(self) -> str:
        """``flood: N datagrams from host:port dropped …`` when the client's sockets were flooded, else ""."""
        self.note_kernel_drops()
        return self.refused.flood()

    def _timers(self) -> None:
        if self.server_info is None or self._cmd is None:
            return
        now = time.monotonic()
        try:
            if not self.config.multicast and now - self._last_keepalive >= self.config.keepalive_interval_s:
                self._last_keepalive = now
                self.send(nn.KeepAlive())
            if self.config.echo_interval_s > 0 and now - self._last_echo >= self.config.echo_interval_s:
                self.send_echo()
        except OSError as exc:
            self.stats.last_error = f"send failed: {exc}"

    def _handle(self, data: bytes, host_ns: int) -> None:
        st = self.stats
        st.packets += 1
        try:
            mid = nn.peek_message_id(data)
            if mid in (nw.MessageId.FRAMEOFDATA, nw.MessageId.MODELDEF) and self.version is None:
                st.ignored += 1
                return
            version = self.version
            if mid == nw.MessageId.FRAMEOFDATA and self._pending_bitstream is not None:
                version = self._transition_version(data)
            elif mid == nw.MessageId.FRAMEOFDATA and self._previous_bitstream is not None:
                version = self._after_switch_version(data)
            if mid == nw.MessageId.FRAMEOFDATA and self.keep_raw:
                raw = self.raw_frames
                if len(raw) == raw.maxlen:
                    st.overflowed += 1
                raw.append((host_ns, data, version))  # type: ignore[arg-type]  # not None: checked above
                st.last_frame_ns = host_ns
                return
            msg = nn.decode(data, version)
        except nw.NatNetParseError as exc:
            st.parse_errors += 1
            st.last_error = str(exc)
            return
        if isinstance(msg, nf.FrameOfData):
            self._on_frame(host_ns, msg)
        elif isinstance(msg, nn.EchoResponse):
            with self._lock:
                sent = self._pending_echo.pop(msg.client_stamp, None)
            if sent is not None:
                self.echoes.append(EchoSample(sent, host_ns, msg.server_stamp))
                st.echoes += 1
        elif isinstance(msg, nn.ServerInfo):
            with self._lock:
                if self.server_info is None:
                    self.version = nw.Version(msg.natnet_version.major, msg.natnet_version.minor)
                self.server_info = msg
            self._serverinfo_evt.set()
        elif isinstance(msg, nm.ModelDef):
            self.model_def = msg
            self._modeldef_evt.set()
        elif isinstance(msg, (nn.Response, nn.UnrecognizedRequest)):
            if isinstance(msg, nn.Response):
                self._accept_bitstream(msg)
            self._responses.put(msg)
        elif isinstance(msg, nn.MessageString):
            log.info("NatNet server message: %s", msg.text)
        else:
            st.ignored += 1

    def _transition_version(self, data: bytes) -> nw.Version | None:
        """The version a frame that arrives while a bitstream change awaits its reply is in: the server may
        switch its stream before its reply goes out (its stream and command threads race), so a frame that does
        not decode in the current version but does in the requested one is in the requested one."""
        want = self._pending_bitstream
        if want is None or self.version is None:
            return self.version
        return self._version_decoding(data, want)

    def _after_switch_version(self, data: bytes) -> nw.Version | None:
        """Just after a bitstream change, a frame the server encoded before it may still arrive (its stream thread
        encodes, the command thread switches and replies, then the older frame goes out): a frame that does not
        decode in the new version but does in the previous one, within :data:`BITSTREAM_GRACE_NS`, is in that."""
        assert self._previous_bitstream is not None
        previous, until_ns = self._previous_bitstream
        if time.monotonic_ns() > until_ns:
            self._previous_bitstream = None
            return self.version
        return self._version_decoding(data, previous)

    def _version_decoding(self, data: bytes, other: nw.Version) -> nw.Version | None:
        """The current version, unless ``data`` does not decode in it but does in ``other``."""
        try:
            nn.decode(data, self.version)
        except nw.NatNetParseError:
            with contextlib.suppress(nw.NatNetParseError):
                nn.decode(data, other)
                return other
        return self.version

    def _switch_bitstream(self, want: nw.Version) -> None:
        """Decode with ``want`` from now on, keeping the old version for frames already on their way (lock held)."""
        if self.version is not None and self.version != want:
            self._previous_bitstream = (self.version, time.monotonic_ns() + BITSTREAM_GRACE_NS)
        self.version = want

    def _accept_bitstream(self, reply: nn.Response) -> None:
        """The server's yes to a bitstream change: decode with the new version from the next packet on (the
        server sends the reply, then frames in the new version; the requesting thread would switch too late)."""
        with self._lock:
            want = self._pending_bitstream
            if want is None:
                return
            with contextlib.suppress(ValueError, nw.NatNetParseError):
                if reply.as_int() == 0:
                    self._switch_bitstream(want)
                    self._pending_bitstream = None

    def _on_frame(self, host_ns: int, frame: nf.FrameOfData) -> None:
        st = self.stats
        self.account_frames((frame.frame_number,))
        st.last_frame_ns = host_ns
        if self.keep_frames:
            if len(self.frames) == self.frames.maxlen:
                st.overflowed += 1
            self.frames.append((host_ns, frame))
        if self.on_frame is not None:
            self.on_frame(host_ns, frame)

    def account_frames(self, numbers: Sequence[int]) -> None:
        """Count decoded frames, in arrival order, by frame number: a gap is dropped frames; a number that goes
        back or repeats is out of order. Called by the receive thread, or by the raw frames' reader."""
        st = self.stats
        last = st.last_frame_number
        for n in numbers:
            if last is None:
                st.first_frame_number = n
            elif n > last + 1:
                st.dropped_frames += n - last - 1
            elif n <= last:
                st.out_of_order += 1
            last = n
        st.last_frame_number = last
        st.frames += len(numbers)

    def check(self) -> None:
        if self._thread_error is not None:
            raise NatNetError(f"NatNet receive thread failed: {self._thread_error!r}")

    def info(self) -> dict[str, Any]:
        """What the server told us: application, versions, frame rate, clock, connection."""
        i = self.server_info
        best = self.best_echo()
        return {
            "app_name": i.app_name if i else None,
            "app_version": str(i.app_version) if i else None,
            "natnet_version": str(i.natnet_version) if i else None,
            "stream_version": self.version.short() if self.version else None,
            "frame_rate_hz": self.frame_rate,
            "clock_frequency_hz": i.clock_frequency if i else None,
            "multicast": self.config.multicast,
            "server": f"{self.config.server_address}:{self.config.command_port}",
            "min_rtt_ms": best.rtt_ns / 1e6 if best else None,
        }


def ping(config: NatNetConfig | None = None) -> dict[str, Any]:
    """Connect, read the server's identity and frame rate, disconnect. For ``beambench devices``."""
    cfg = config or NatNetConfig()
    quick = NatNetConfig(**{**cfg.__dict__, "initial_echoes": 3, "echo_interval_s": 0.0})
    with NatNetClient(quick) as c:
        return c.info()
