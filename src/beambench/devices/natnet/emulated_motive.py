"""An emulated OptiTrack Motive: a NatNet 3.0 / 4.0 / 4.1 server on UDP (loopback by default).

It answers CONNECT (SERVERINFO), MODELDEF requests, the ``FrameRate``, ``Bitstream[,X.Y]`` and
``AnalogSamplesPerMocapFrame`` commands, ECHO requests (with its own QPC ticks) and KEEPALIVE, and streams
frames at ``rate_hz`` (360 Hz default) by multicast or to each connected unicast client, from the first
CONNECT on (``wait_for_client``) or from ``start()``. Marker positions
come from ``positions(t) -> array (M, 3)`` in metres, ``t`` = seconds since streaming started
(frame index / rate), so a physics simulation can drive it.

Its clock is a QPC tick counter: ``ticks = (offset_s + (1 + drift_ppm·1e-6) · time.monotonic()) · qpc_hz``.
A frame is exposed at ``t_k = t_0 + k / rate`` (host monotonic); it is sent ``latency_s + |N(0, jitter_s)|``
later, and carries mid-exposure, data-received and transmit stamps on that clock. Frame drops and marker
occlusions can be injected; what was injected is recorded (``dropped_frames``, ``occlusions``) so tests can
check that a client counts exactly that.
"""

from __future__ import annotations

import collections
import math
import socket
import threading
import time
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from beambench.acquisition.clocks import DriftingClock
from beambench.acquisition.protocol.schema import ClockModel
from beambench.acquisition.streams import MOCAP
from beambench.devices.natnet import frame as nf
from beambench.devices.natnet import modeldef as nm
from beambench.devices.natnet import protocol as nn
from beambench.devices.natnet import wire as nw
from beambench.devices.peer import PeerContext, Wiring

__all__ = ["APP_VERSIONS", "EmulatorClock", "MotiveEmulator", "MotivePeer"]

APP_VERSIONS = {nw.V3_0: nw.Version(2, 2, 0, 0), nw.V4_0: nw.Version(3, 0, 0, 0), nw.V4_1: nw.Version(3, 1, 0, 0)}

PositionSource = Callable[[float], np.ndarray]

MOTIVE_GEOMETRY = {"up_axis": "y", "forward_axis": "x"}  # Motive's default world frame (y up)
_Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) → (x, z, −y)


def motive_frame(source: PositionSource) -> PositionSource:
    """Marker positions from a z-up world (MuJoCo's) as Motive streams them: in its default y-up frame."""

    def positions(t: float) -> np.ndarray:
        return np.asarray(source(t), float) @ _Z_UP_TO_Y_UP.T

    return positions


@dataclass
class EmulatorClock:
    """Motive's QPC clock as a function of host monotonic time (the :class:`DriftingClock` model, counted at
    ``frequency_hz``); ``jitter_s``/``latency_s`` delay sending."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0
    jitter_s: float = 0.0
    latency_s: float = 0.0005
    frequency_hz: int = 10_000_000

    def seconds(self, host_s: float) -> float:
        return DriftingClock(self.offset_s, self.drift_ppm).device_time(host_s)

    def ticks(self, host_s: float) -> int:
        return max(0, round(self.seconds(host_s) * self.frequency_hz))

    @classmethod
    def from_model(cls, model: ClockModel, frequency_hz: int = 10_000_000) -> EmulatorClock:
        """From the protocol's clock model (``sim.clocks.mocap``)."""
        return cls(model.offset_s, model.drift_ppm, model.jitter_s, model.latency_s, frequency_hz)


def _still(n: int) -> PositionSource:
    base = np.column_stack([np.linspace(0.0, 0.1 * (n - 1), n), np.zeros(n), np.full(n, 0.05)])
    return lambda t: base


@dataclass
class _Client:
    address: tuple[str, int]
    last_seen: float


@dataclass
class MotiveEmulator:
    """A Motive look-alike. ``start()`` it, point a client at ``command_address``; ``stop()`` when done."""

    version: str = "4.1"
    rate_hz: float = 360.0
    marker_names: Sequence[str] = ("stage", "tip", "foot")
    positions: PositionSource | None = None
    marker_ids: Sequence[int] | None = None  # labeled ids (model << 16 | marker); default asset 1, markers 1..M
    asset_name: str = "beam"
    rigid_bodies: Mapping[int, Sequence[int]] = field(default_factory=dict)  # id → marker indices
    host: str = "127.0.0.1"
    command_port: int = 1510  # 0 = any free port
    data_port: int = 1511
    multicast: bool = True
    multicast_address: str = "239.255.42.99"
    multicast_ttl: int = 0  # 0: multicast never leaves this host
    clock: EmulatorClock = field(default_factory=EmulatorClock)
    drop: Callable[[int], bool] | Collection[int] | float | None = None  # by frame number, or a probability
    occlude: Callable[[int], Iterable[int]] | Mapping[int, Iterable[int]] | float | None = None  # marker indices
    seed: int = 0
    first_frame: int = 1
    unicast_timeout_s: float = 5.0
    app_name: str = "Motive"
    max_frames: int | None = None  # stop streaming after this many frames (sent or dropped)
    wait_for_client: bool = True  # frame 1 is exposed when the first CONNECT arrives (else at start())
    keep_sent: int = 0  # keep this many of the last frames sent in ``sent`` (for tests)
    # answer requests this much later, the stream going on meanwhile: frames in a newly requested bitstream
    # version reach the client before the reply does (the race of a server's command and stream threads)
    reply_delay_s: float = 0.0

    def __post_init__(self) -> None:
        v = nw.Version.parse(self.version)
        self.stream_version = nw.Version(v.major, v.minor)
        if self.stream_version not in nw.SUPPORTED_VERSIONS:
            raise ValueError(f"NatNet version {self.version} not emulated (3.0, 4.0, 4.1)")
        self.server_version = self.stream_version
        m = len(self.marker_names)
        if self.marker_ids is None:
            self.marker_ids = [(1 << 16) | (i + 1) for i in range(m)]
        if len(self.marker_ids) != m:
            raise ValueError(f"{len(self.marker_ids)} marker ids for {m} markers")
        if self.positions is None:
            self.positions = _still(m)
        self.rng = np.random.default_rng(self.seed)
        self.dropped_frames: list[int] = []
        self.occlusions: list[tuple[int, int]] = []  # (frame number, marker index)
        self.frames_sent = 0
        self.sent: collections.deque[nf.FrameOfData] = collections.deque(maxlen=max(self.keep_sent, 1))
        self.requests: list[str] = []
        self.clients: dict[tuple[str, int], _Client] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._cmd: socket.socket | None = None
        self._data: socket.socket | None = None
        self.streaming = threading.Event()
        self._connected = threading.Event()
        self.t0: float | None = None
        self.error: BaseException | None = None  # what stopped the stream thread, if anything

    # ------------------------------------------------------------------ lifecycle

    @property
    def command_address(self) -> tuple[str, int]:
        assert self._cmd is not None, "emulator not started"
        return self._cmd.getsockname()

    def start(self) -> MotiveEmulator:
        self._cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        self._cmd.bind((self.host, self.command_port))
        self._cmd.settimeout(0.05)
        self._data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        self._data.bind((self.host, 0))
        if self.multicast:
            self._data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(self.host))
            self._data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, self.multicast_ttl)
            self._data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._serve_commands, name="motive-cmd", daemon=True),
            threading.Thread(target=self._stream, name="motive-data", daemon=True),
        ]
        for t in self._threads:
            t.start()
        if not self.wait_for_client:
            self.streaming.wait(2.0)
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
        for s in (self._cmd, self._data):
            if s is not None:
                s.close()
        self._cmd = self._data = None

    def __enter__(self) -> MotiveEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def set_positions(self, positions: PositionSource) -> None:
        self.positions = positions

    def check(self) -> None:
        """Raise what stopped the stream thread (e.g. a position source that failed)."""
        if self.error is not None:
            raise RuntimeError(f"emulated Motive stopped streaming: {self.error!r}") from self.error

    # ------------------------------------------------------------------ command port

    def server_info(self) -> nn.ServerInfo:
        sender = nn.Sender(self.app_name, APP_VERSIONS[self.server_version], nw.Version(*self.server_version))
        # multicast: the group's port; unicast: the port frames are sent from (clients accept data only from it)
        port = self.data_port if self.multicast or self._data is None else self._data.getsockname()[1]
        return nn.ServerInfo(sender, self.clock.frequency_hz, port, self.multicast, self.multicast_address)

    def model_def(self) -> nm.ModelDef:
        names = tuple(self.marker_names)
        sets: list = [nm.MarkerSetDescription(self.asset_name, names)]
        p0 = np.asarray(self.positions(0.0), dtype=float)  # type: ignore[misc]
        for rb_id, idx in self.rigid_bodies.items():
            centre = p0[list(idx)].mean(axis=0)
            markers = tuple(
                nm.RigidBodyMarker(
                    (float(p0[i][0] - centre[0]), float(p0[i][1] - centre[1]), float(p0[i][2] - centre[2])), 0, names[i]
                )
                for i in idx
            )
            sets.append(nm.RigidBodyDescription(f"rigid_body_{rb_id}", rb_id, -1, (0.0, 0.0, 0.0), markers))
        sets.append(nm.MarkerSetDescription("all", tuple(f"{self.asset_name}_{n}" for n in names)))
        return nm.ModelDef(tuple(sets))

    def _reply(self, msg: nn.Message, addr: tuple[str, int]) -> None:
        if self._cmd is not None:
            self._cmd.sendto(nn.encode(msg, self.stream_version), addr)

    def _serve_commands(self) -> None:
        while not self._stop.is_set():
            sock = self._cmd
            if sock is None:
                return
            try:
                data, addr = sock.recvfrom(65536)
            except (TimeoutError, BlockingIOError):
                continue
            except OSError:
                return
            now_ticks = self.clock.ticks(time.monotonic())
            try:
                msg = nn.decode(data, self.stream_version)
            except nw.NatNetParseError:
                continue
            try:
                self._command(msg, addr, now_ticks)
            except OSError:
                continue

    def _command(self, msg: nn.Message, addr: tuple[str, int], now_ticks: int) -> None:
        if isinstance(msg, (nn.Connect, nn.Discovery)):
            if isinstance(msg, nn.Connect) and not isinstance(msg, nn.Discovery):
                if not self.multicast:
                    with self._lock:
                        self.clients[addr] = _Client(addr, time.monotonic())
                self._connected.set()
            self._reply(self.server_info(), addr)
        elif isinstance(msg, nn.KeepAlive):
            with self._lock:
                if addr in self.clients:
                    self.clients[addr].last_seen = time.monotonic()
        elif isinstance(msg, nn.Disconnect):
            with self._lock:
                self.clients.pop(addr, None)
        elif isinstance(msg, nn.EchoRequest):
            self._reply(nn.EchoResponse(msg.client_stamp, now_ticks), addr)
        elif isinstance(msg, nn.RequestModelDef):
            self._reply(self.model_def(), addr)
        elif isinstance(msg, nn.Request):
            self.requests.append(msg.command)
            answer = self._answer(msg.command)
            if self.reply_delay_s > 0:
                time.sleep(self.reply_delay_s)
            self._reply(answer, addr)

    def _answer(self, command: str) -> nn.Message:
        name, _, arg = command.partition(",")
        key = name.strip().lower()
        if key == "framerate":
            return nn.Response.of_float(self.rate_hz)
        if key == "analogsamplespermocapframe":
            return nn.Response.of_int(0)
        if key == "bitstream":
            if not arg:
                return nn.Response.of_text(f"Bitstream,{self.stream_version.short()}")
            try:
                want = nw.Version.parse(arg)
            except ValueError:
                return nn.Response.of_int(-1)
            want = nw.Version(want.major, want.minor)
            if self.server_version.major < 4 or want not in nw.SUPPORTED_VERSIONS:
                return nn.Response.of_int(-1)
            self.stream_version = want
            return nn.Response.of_int(0)
        return nn.UnrecognizedRequest()

    # ------------------------------------------------------------------ data stream

    def _targets(self) -> list[tuple[str, int]]:
        if self.multicast:
            return [(self.multicast_address, self.data_port)]
        now = time.monotonic()
        with self._lock:
            for a in [a for a, c in self.clients.items() if now - c.last_seen > self.unicast_timeout_s]:
                del self.clients[a]
            return list(self.clients)

    def send_packet(self, packet: bytes) -> int:
        """Send ``packet`` as it is from the data port, where the stream's frames come from, to every client (the
        group in multicast): a packet the stream would not make, e.g. a frame encoded before a bitstream change
        that goes out after it. Returns the number of targets it was sent to."""
        sock = self._data
        if sock is None:
            raise RuntimeError("emulator not started")
        targets = self._targets()
        for addr in targets:
            sock.sendto(packet, addr)
        return len(targets)

    def _is_dropped(self, number: int) -> bool:
        d = self.drop
        if d is None:
            return False
        if callable(d):
            return bool(d(number))
        if isinstance(d, float):
            return bool(self.rng.random() < d)
        return number in d

    def _occluded(self, number: int, m: int) -> set[int]:
        o = self.occlude
        if o is None:
            return set()
        if callable(o):
            hidden = set(o(number))
        elif isinstance(o, float):
            hidden = set(np.flatnonzero(self.rng.random(m) < o).tolist())
        else:
            hidden = set(o.get(number, ()))
        return {i for i in hidden if 0 <= i < m}

    def make_frame(self, k: int, t_exposure: float, t_send: float, hidden: set[int]) -> nf.FrameOfData:
        """Frame ``k`` (0-based) exposed at host time ``t_exposure``, sent at ``t_send``."""
        number = self.first_frame + k
        pos = np.asarray(self.positions(k / self.rate_hz), dtype=float)  # type: ignore[misc]
        m = len(self.marker_names)
        if pos.shape != (m, 3):
            raise ValueError(f"positions(t) returned shape {pos.shape}, expected ({m}, 3)")
        lms = []
        for i, mid in enumerate(self.marker_ids):  # type: ignore[arg-type]
            occl = i in hidden
            params = (0x01 | 0x04 | 0x08) if occl else (0x02 | 0x08)  # occluded+model-solved | point-cloud-solved
            lms.append(nf.LabeledMarker(mid, tuple(pos[i].tolist()), 0.014, params, 0.0 if occl else 1e-4))
        rbs = []
        for rb_id, idx in self.rigid_bodies.items():
            seen = [i for i in idx if i not in hidden]
            valid = len(seen) >= max(1, len(idx) - 1)  # tracked while at most one of its markers is hidden
            c = pos[list(idx)].mean(axis=0)
            rbs.append(
                nf.RigidBody(rb_id, tuple(c.tolist()), (0.0, 0.0, 0.0, 1.0), 1e-4 if valid else 0.0, 1 if valid else 0)
            )
        clk = self.clock
        mid_ticks = clk.ticks(t_exposure)
        recv_ticks = clk.ticks(t_exposure + 0.6 * clk.latency_s)
        tx_ticks = clk.ticks(t_send)
        dev_s = clk.seconds(t_exposure)
        secs = max(0, math.floor(dev_s))
        frac = int((dev_s - math.floor(dev_s)) * 2**32) & 0xFFFFFFFF
        elapsed = k / self.rate_hz
        hh, mm, ss = int(elapsed // 3600) % 24, int(elapsed // 60) % 60, int(elapsed) % 60
        ff = int((elapsed % 1.0) * 30)
        timecode = (hh << 24) | (mm << 16) | (ss << 8) | ff
        sub = round(elapsed * self.rate_hz) % max(1, round(self.rate_hz / 30))
        return nf.FrameOfData(
            frame_number=number,
            marker_sets=(
                nf.MarkerSetData(self.asset_name, tuple(tuple(p) for p in pos.tolist())),
                nf.MarkerSetData("all", tuple(tuple(p) for p in pos.tolist())),
            ),
            rigid_bodies=tuple(rbs),
            labeled_markers=tuple(lms),
            timecode=timecode,
            timecode_sub=sub,
            timestamp=number / self.rate_hz,
            mid_exposure=mid_ticks,
            data_received=recv_ticks,
            transmit=tx_ticks,
            precision_seconds=secs,
            precision_fraction=frac,
        )

    def _stream(self) -> None:
        period = 1.0 / self.rate_hz
        if self.wait_for_client:
            while not self._connected.wait(0.05):
                if self._stop.is_set():
                    return
        self.t0 = t0 = time.monotonic() + 0.001
        self.streaming.set()
        k = 0
        clk = self.clock
        while not self._stop.is_set():
            if self.max_frames is not None and k >= self.max_frames:
                self._stop.wait(0.05)
                continue
            t_exp = t0 + k * period
            delay = clk.latency_s + (abs(float(self.rng.normal(0.0, clk.jitter_s))) if clk.jitter_s > 0 else 0.0)
            t_send = t_exp + delay
            wait = t_send - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                break
            number = self.first_frame + k
            m = len(self.marker_names)
            if self._is_dropped(number):
                self.dropped_frames.append(number)
                k += 1
                continue
            try:
                hidden = self._occluded(number, m)
                frame = self.make_frame(k, t_exp, time.monotonic(), hidden)
                packet = nn.encode(frame, self.stream_version)
            except Exception as exc:  # a broken position source stops the stream; check() reports it
                self.error = exc
                break
            sock = self._data
            if sock is None:
                break
            targets = self._targets()
            sent = False
            for addr in targets:
                try:
                    sock.sendto(packet, addr)
                    sent = True
                except OSError:
                    pass
            if sent:
                self.occlusions.extend((number, i) for i in sorted(hidden))
                self.frames_sent += 1
                if self.keep_sent:
                    self.sent.append(frame)
            k += 1


class _Outage:
    """Frame filter: every frame is dropped from ``start()`` for ``seconds`` (a real UDP silence), and the frames
    numbered in ``base`` (the injected drops) always."""

    def __init__(self, base: Collection[int] | None) -> None:
        self.base = frozenset(base or ())
        self.t0: float | None = None
        self.seconds = 0.0

    def start(self, seconds: float) -> None:
        self.seconds, self.t0 = seconds, time.monotonic()

    def __call__(self, number: int) -> bool:
        if self.t0 is not None and time.monotonic() - self.t0 < self.seconds:
            return True
        return number in self.base


class MotivePeer:
    """The ``mocap`` stream's emulated peer: Motive on loopback (unicast), streaming the physics' markers in its
    y-up frame, each frame's markers taken at its own exposure time. Injections: ``mocap_drop`` (a probability
    per frame, or the frame numbers to drop), ``mocap_occlude`` (a probability per marker and frame, or
    {frame number: marker indices}); :meth:`outage` silences it for a while."""

    def __init__(self, ctx: PeerContext) -> None:
        physics = ctx.physics
        drop = ctx.inject.get("mocap_drop")
        self._outage = _Outage(None if isinstance(drop, float) else drop)

        def exposed(t: float) -> np.ndarray:  # t: stream time of a frame, exposed at stream start + t
            if self.emulator.t0 is None:  # not streaming yet (the model definition asks): now
                return physics.positions(t)
            return physics.positions_at(self.emulator.t0 + t)

        self.emulator = MotiveEmulator(
            marker_names=physics.markers,
            positions=motive_frame(exposed),
            command_port=0,
            multicast=False,
            clock=EmulatorClock.from_model(ctx.clock(MOCAP)),
            seed=ctx.seed,
            drop=drop if isinstance(drop, float) else self._outage,
            occlude=ctx.inject.get("mocap_occlude"),
        )

    def open(self) -> Wiring:
        self.emulator.start()  # binds its ports; streams once the client connects
        host, port = self.emulator.command_address
        markers = {
            name: f"{mid >> 16}:{mid & 0xFFFF}"
            for name, mid in zip(self.emulator.marker_names, self.emulator.marker_ids or ())
        }
        natnet = {
            "server_address": host,
            "local_address": host,
            "command_port": port,
            "multicast": False,
            "markers": markers,
        }
        return {"natnet": natnet, "geometry": dict(MOTIVE_GEOMETRY)}

    def start(self) -> None:
        pass  # streaming started when the client connected

    def outage(self, seconds: float) -> None:
        """Send nothing for ``seconds`` from now."""
        self._outage.start(seconds)

    def stop(self) -> None:
        self.emulator.stop()

    def report(self) -> dict[str, Any]:
        m = self.emulator
        return {
            "dropped_frames": list(m.dropped_frames),
            "occlusions": list(m.occlusions),
            "frames_sent": m.frames_sent,
            "error": repr(m.error) if m.error else "",
        }

    def close(self) -> None:
        pass
