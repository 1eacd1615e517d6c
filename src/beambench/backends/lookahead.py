"""The sim rig's physics computed ahead of the run, on worker threads (:class:`Lookahead`).

Once armed, the runner announces what the run will do if nothing stops or pauses it (each step's command and the
clock waits after it; :class:`~beambench.acquisition.capabilities.Anticipates`). The sim rig turns that into a
script of scene calls — ``set_frequency`` at a rig time, ``advance_to`` a rig time: exactly the calls it would
make itself — and a worker thread makes them ahead of the run (MuJoCo releases the GIL, so the physics runs on
one core while the devices and the session file use the other), keeping each call's rows and the scene's state
after it. While the run does what was announced, the rig takes the rows from the worker: the same calls in the
same order, so the same data as without lookahead. At the first call that differs (an interrupted run, a
monitor's pause, the final idle) the rig stops the workers and continues from the state after the last call it
took.

Segments (``sim.segments: n`` > 1, the walker): the script is cut at n − 1 step commands into n parts computed
in parallel, each part after the first on its own copy of the scene, which first walks :data:`PRESETTLE_S` at
that step's frequency from the scene's rest state after ramping up (the walker needs ~3 s to walk steadily). Its rows
are stitched on: time continues, the markers' positions along the walking axis and the motor angle are offset so
they continue from the previous part's last row. What changes with segments: the state is not carried across a
cut — the gait's phase, the body's height and tilt jump there, at the start of a step's settle window — and
each part after the first starts at its first frequency already walking instead of ramping up from the previous
step's frequency. The per-step settle window is what makes the steps' speeds comparable either way (each step's
speed is a steady one measured after it).

Checked cuts (the contact rig, a scene that ``ChecksCuts``): its state forgets the past only where its regime is
robust, not in the lift-off band where a micrometre flips the label. So the part before a cut runs on past it step
by step beside the part after it (started from rest, ramped up, pre-settled), and the scene compares each such
step run both ways (:meth:`~beambench.sim.scenes.drive.ChecksCuts.same_regime`). At the first step that agrees the
caller switches parts, at the next step's command (the agreed step's rows are the carried ones); until then the
cut moves on, and a part that never agrees is run by the part before it (its stretch in one piece). Nothing is
shifted along a walking axis there; the motor angle continues by whole turns, so the stage still sits at the
crank's sine. The checks go to ``/general/sim_segments`` (``cut_checks``: where each cut was planned, where it was
taken, the steps compared).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from beambench.sim.engine.stepping import Trajectory
from beambench.sim.scenes.drive import DrivenScene

PRESETTLE_S = 3.5  # s a segment's own scene walks at its first frequency (after ramping up) before its rows are used
MAX_AHEAD = 16  # script calls the first segment may run ahead of the run (the later ones run freely)

Call = tuple[str, int, float]  # ("cmd", rig time ns, Hz) or ("adv", rig time ns, 0.0)


class SegmentScene(Protocol):
    """What a segment's worker calls on its scene: a :class:`DrivenScene` here, or one computed on a Dask worker
    (:class:`~beambench.backends.remote_scene.RemoteScene`)."""

    def set_frequency(self, hz: float) -> None: ...

    def advance_to(self, t_target: float) -> Trajectory: ...

    def snapshot(self) -> tuple: ...

    def presettle(self, hz: float, seconds: float, t_phys: float) -> dict[str, np.ndarray]: ...


@runtime_checkable
class ComputedElsewhere(Protocol):
    """A segment scene computed in another process (a Dask worker): ``cpu_s`` is the CPU time it spent there."""

    cpu_s: float


def script(schedule: list[tuple[float, list[float]]], now_ns: int, max_chunk_ns: int) -> list[Call]:
    """The scene calls the sim rig makes for ``schedule`` from rig time ``now_ns``: a command, then each wait
    advanced in chunks of at most ``max_chunk_ns`` (as :class:`~beambench.backends.sim_devices.SimClock.wait`)."""
    calls: list[Call] = []
    t = now_ns
    for hz, waits in schedule:
        calls.append(("cmd", t, float(hz)))
        for w in waits:
            if w <= 0:
                continue
            target = t + round(w * 1e9)
            while t < target:
                t = min(target, t + max_chunk_ns)
                calls.append(("adv", t, 0.0))
    return calls


def cut_points(
    calls: list[Call], segments: int, presettle_s: float, cost: Callable[[float], float] | None = None
) -> list[int]:
    """Indices of the step commands where the script is cut into ``segments`` parts of about equal physics cost
    (a later part also pre-settles ``presettle_s``); fewer cuts when there are too few commands. ``cost(hz)``: the
    physics' relative cost per rig second at a drive frequency (None: the same at every frequency)."""
    cmds = [i for i, c in enumerate(calls) if c[0] == "cmd" and i > 0]
    if segments <= 1 or not cmds:
        return []
    weight = cost or (lambda hz: 1.0)
    cum = np.zeros(len(calls))  # cost of the script up to each call
    hz, t, total = 0.0, calls[0][1], 0.0
    for i, (kind, t_ns, f) in enumerate(calls):
        if kind == "cmd":
            hz = f
        else:
            total += (t_ns - t) * 1e-9 * weight(hz)
            t = t_ns
        cum[i] = total
    mean_w = total / max((calls[-1][1] - calls[0][1]) * 1e-9, 1e-12)
    pre = presettle_s * mean_w
    part = (total + (segments - 1) * pre) / segments
    cuts: list[int] = []
    for j in range(1, segments):
        want = j * part - (j - 1) * pre
        best = min(cmds, key=lambda i: abs(cum[i] - want))
        if best not in cuts and (not cuts or best > cuts[-1]):
            cuts.append(best)
    return cuts


def physics_time_after(calls: list[Call], t_phys: float, h: float) -> float:
    """The scene's physics time after ``calls`` from physics time ``t_phys`` (as ``DrivenScene.advance_to``)."""
    for kind, t_ns, _ in calls:
        if kind == "adv":
            n = int(np.ceil((t_ns * 1e-9 - t_phys) / h - 1e-9)) + 1
            if n > 0:
                t_phys += n * h
    return t_phys


Agree = Callable[[Trajectory, Trajectory, float], bool]  # (carried rows, restarted rows, Hz) of one step: same regime?


@dataclass
class _Segment:
    """One worker: script calls ``first``..``last − 1`` on ``scene`` (pre-settled first unless it is the rig's);
    with a cut check, then on past ``last`` until the next segment's cut is decided."""

    scene: SegmentScene
    first: int
    last: int
    presettle: tuple[float, float, float] | None = None  # (Hz, seconds, physics time to continue from)
    results: dict[int, tuple[Trajectory | None, tuple]] = field(default_factory=dict)
    done: int = 0  # calls made
    join_row: dict[str, np.ndarray] | None = None  # the pre-settle's last row (markers, theta)
    error: BaseException | None = None
    thread: threading.Thread | None = None
    cpu_s: float = 0.0  # the worker thread's CPU time (and a remote scene's worker's)
    # per segment before it (its index): the call from which the caller, taking that segment's rows, takes this
    # one's instead, or None: the cut was refused at every step of this stretch (that segment ran it)
    verdict: dict[int, int | None] = field(default_factory=dict)


class Lookahead:
    """Makes a script of scene calls on worker threads ahead of the caller, who takes the results in order with
    :meth:`expects` and :meth:`take`. ``clones`` makes the later segments' scenes (rest state, like the rig's)."""

    def __init__(
        self,
        scene: DrivenScene,
        calls: list[Call],
        cuts: list[int] | None = None,
        clones: list[SegmentScene] | None = None,
        presettle_s: float = PRESETTLE_S,
        walk_axis: int | None = 0,
        agree: Agree | None = None,
    ) -> None:
        self.calls = calls
        self.walk_axis = walk_axis
        self.agree = agree
        self.checks: list[
            dict[str, Any]
        ] = []  # each cut's check: where it was asked, where it went, the steps compared
        self.next = 0  # the next call the caller expects
        self.start = scene.snapshot()  # the state before the first call
        self.last_snap: tuple | None = None
        self.offset: dict[str, float] = {"x": 0.0, "theta": 0.0}  # added to the rows of the segment in use
        self._cv = threading.Condition()
        self._stop = False
        cuts = list(cuts or [])
        clones = list(clones or [])
        if len(clones) < len(cuts):
            raise ValueError("lookahead: one scene copy per cut")
        bounds = [0, *cuts, len(calls)]
        self.segments: list[_Segment] = []
        h = float(scene.physics.timestep)
        for j in range(len(bounds) - 1):
            a, b = bounds[j], bounds[j + 1]
            if j == 0:
                seg = _Segment(scene, a, b)
            else:
                t_phys = physics_time_after(calls[:a], float(scene.physics.time), h)
                seg = _Segment(clones[j - 1], a, b, (calls[a][2], presettle_s, t_phys))
                if agree is None:
                    seg.verdict[j - 1] = a
            self.segments.append(seg)
        self._seg = 0  # the segment the caller takes from
        self._pending_join: tuple[_Segment, int] | None = None  # the segment just switched to, from which call
        self.cuts_taken: list[int] = []  # the calls where the caller switched to the next segment
        for seg in self.segments:
            seg.thread = threading.Thread(target=self._work, args=(seg,), name="sim-lookahead", daemon=True)
            seg.thread.start()

    # --- worker -----------------------------------------------------------------------------------------
    def _work(self, seg: _Segment) -> None:
        c0 = time.thread_time()
        try:
            if seg.presettle is not None:
                seg.join_row = seg.scene.presettle(*seg.presettle)
            bounded = seg is self.segments[0]
            for i in range(seg.first, seg.last):
                if not self._call(seg, i, bounded, c0):
                    return
            if self.agree is not None:
                self._check_cuts(seg, c0)
        except BaseException as exc:  # handed to the caller in take()
            with self._cv:
                seg.error = exc
                self._cv.notify_all()

    def _call(self, seg: _Segment, i: int, bounded: bool, c0: float) -> bool:
        """Make script call ``i`` on ``seg``'s scene and keep its rows and state; False once stopped."""
        with self._cv:
            while bounded and not self._stop and i - self.next >= MAX_AHEAD:
                self._cv.wait()
            if self._stop:
                return False
        kind, t_ns, hz = self.calls[i]
        if kind == "cmd":
            seg.scene.set_frequency(hz)
            out = None
        else:
            out = seg.scene.advance_to(t_ns * 1e-9)
        snap = seg.scene.snapshot()
        with self._cv:
            seg.results[i] = (out, snap)
            seg.done = i + 1
            seg.cpu_s = time.thread_time() - c0 + (seg.scene.cpu_s if isinstance(seg.scene, ComputedElsewhere) else 0.0)
            self._cv.notify_all()
        return True

    def _step_end(self, i: int) -> int:
        """The index of the first command after call ``i`` (the end of the step that call ``i`` starts)."""
        return next((j for j in range(i + 1, len(self.calls)) if self.calls[j][0] == "cmd"), len(self.calls))

    def _rows(self, seg: _Segment, a: int, b: int) -> Trajectory | None:
        parts = [seg.results[j][0] for j in range(a, b) if j in seg.results and seg.results[j][0] is not None]
        return Trajectory.concat([p for p in parts if p is not None]) if parts else None

    def _check_cuts(self, seg: _Segment, c0: float) -> None:
        """Past its own stretch, ``seg`` runs on step by step beside the next segment (which started from rest at
        the cut): the first step on which both give the same regime (``agree``) is where the caller switches, at
        the step after it. A segment that never agrees is merged: ``seg`` runs its stretch and checks the next."""
        me = self.segments.index(seg)
        k = me + 1
        i = seg.last
        asked = i
        compared: list[float] = []
        while k < len(self.segments):
            nxt = self.segments[k]
            e = self._step_end(i)
            for j in range(i, e):
                if not self._call(seg, j, False, c0):
                    return
            with self._cv:
                while nxt.done < e and nxt.error is None and not self._stop:
                    self._cv.wait()
                if self._stop:
                    return
            a, b = self._rows(seg, i, e), self._rows(nxt, i, e) if nxt.error is None else None
            hz = self.calls[i][2]
            compared.append(hz)
            if a is not None and b is not None and self.agree is not None and self.agree(a, b, hz):
                with self._cv:
                    nxt.verdict[me] = e
                    self.checks.append({"asked_s": self._t(asked), "cut_s": self._t(e), "steps_compared_hz": compared})
                    self._cv.notify_all()
                return
            i = e
            if i >= nxt.last:  # refused at every step of its stretch: run it here, check the next cut
                with self._cv:
                    nxt.verdict[me] = None
                    self.checks.append({"asked_s": self._t(asked), "cut_s": None, "steps_compared_hz": compared})
                    self._cv.notify_all()
                k, asked, compared = k + 1, i, []

    def _t(self, i: int) -> float | None:
        return round(self.calls[i][1] * 1e-9, 9) if i < len(self.calls) else None

    def _owner(self, i: int) -> _Segment:
        """The segment whose rows call ``i`` takes (waits for a cut's check); called with the lock held."""
        k = self._seg + 1
        while k < len(self.segments):
            seg, nxt = self.segments[self._seg], self.segments[k]
            if i < nxt.first:
                break
            if self._seg not in nxt.verdict:  # its check is still running
                if seg.error is not None:
                    raise seg.error
                self._cv.wait()
                continue
            at = nxt.verdict[self._seg]
            if at is None:  # refused: the current segment ran that stretch too
                k += 1
                continue
            if i < at:
                break
            self._seg = k
            self._pending_join = (nxt, at)
            self.cuts_taken.append(at)
            k += 1
        return self.segments[self._seg]

    def _join_row(self, seg: _Segment, at: int) -> dict[str, np.ndarray] | None:
        """The row that ``seg``'s rows from call ``at`` on continue (its pre-settle's last, or its row before
        ``at``); drops its rows before ``at`` (never taken). Called with the lock held, once ``seg`` made call ``at``."""
        row: dict[str, np.ndarray] | None = seg.join_row
        if at != seg.first or row is None:
            prev = self._rows(seg, at - 1, at)
            row = {k: prev.channels[k][-1] for k in ("markers", "theta")} if prev is not None else None
        for j in [j for j in seg.results if j < at]:
            del seg.results[j]
        return row

    # --- caller -----------------------------------------------------------------------------------------
    def expects(self, kind: str, t_ns: int, hz: float = 0.0) -> bool:
        """Is ``(kind, t_ns, hz)`` the next call of the script?"""
        return self.next < len(self.calls) and self.calls[self.next] == (kind, t_ns, float(hz))

    def take(self, last_rows: Trajectory | None) -> Trajectory | None:
        """The next call's rows (None for a command), waiting for its worker. ``last_rows``: the rows taken so far
        (their last row is where a new segment's rows are stitched on)."""
        i = self.next
        with self._cv:
            self._pending_join = None
            seg = self._owner(i)
            while seg.done <= i and seg.error is None:
                self._cv.wait()
            if seg.error is not None and seg.done <= i:
                raise seg.error
            join = self._join_row(*self._pending_join) if self._pending_join is not None else None
            out, snap = seg.results.pop(i)
            self.last_snap = snap
            self.next = i + 1
            self._cv.notify_all()
        if join is not None and last_rows is not None and len(last_rows):
            self.offset = self._offset_to(last_rows, join)
        return None if out is None else shifted(out, self.offset, self.walk_axis)

    def _offset_to(self, last: Trajectory, row: dict[str, np.ndarray]) -> dict[str, float]:
        """Offsets continuing ``last``'s final row with ``row``: along the walking axis (none without one) and the
        motor angle; without a walking axis by whole turns only, so the crank's phase stays the stage's."""
        dtheta = float(last.channels["theta"][-1] - row["theta"])
        if self.walk_axis is None:
            return {"x": 0.0, "theta": 2 * np.pi * round(dtheta / (2 * np.pi))}
        ax = self.walk_axis
        return {"x": float(last.channels["markers"][-1, 0, ax] - row["markers"][0, ax]), "theta": dtheta}

    @property
    def scene(self) -> SegmentScene:
        """The scene whose state follows the last call taken."""
        return self.segments[self._seg].scene

    @property
    def cut_times_ns(self) -> list[int]:
        """Where the caller switched segments so far (all planned cuts while none is checked)."""
        if self.agree is None:
            return [self.calls[s.first][1] for s in self.segments[1:]]
        return [self.calls[i][1] for i in self.cuts_taken if i < len(self.calls)]

    def stop(self) -> tuple | None:
        """Stop every worker; the state after the last call taken (None: none taken — then :attr:`start`)."""
        with self._cv:
            self._stop = True
            self._cv.notify_all()
        for seg in self.segments:
            if seg.thread is not None:
                seg.thread.join()
        return self.last_snap


def computed(look: Lookahead) -> tuple[float, int]:
    """(seconds of rig time whose rows are computed, over every segment; step commands whose rows up to the next
    command, or the segment's end, are all computed). A later segment's pre-settle is not counted."""
    seconds, steps = 0.0, 0
    calls = look.calls
    with look._cv:
        done = [(seg.first, min(seg.done, seg.last)) for seg in look.segments]  # not a checked cut's overlap
    for (first, upto), seg in zip(done, look.segments):
        if upto <= first:
            continue
        seconds += (calls[upto - 1][1] - calls[first][1]) * 1e-9
        cmds = [i for i in range(first, seg.last) if calls[i][0] == "cmd"]
        ends = [*cmds[1:], seg.last]
        steps += sum(1 for end in ends if end <= upto)
    return seconds, steps


def shifted(tr: Trajectory, offset: dict[str, float], axis: int | None) -> Trajectory:
    """``tr`` with ``offset["x"]`` added to every marker along ``axis`` and ``offset["theta"]`` to the motor angle."""
    if not offset["x"] and not offset["theta"]:
        return tr
    ch = dict(tr.channels)
    if offset["x"] and "markers" in ch:
        m = ch["markers"].copy()
        m[..., axis] += offset["x"]
        ch["markers"] = m
    if offset["theta"] and "theta" in ch:
        ch["theta"] = ch["theta"] + offset["theta"]
    return Trajectory(tr.t, ch)


def info(look: Lookahead) -> dict[str, Any]:
    """What the lookahead did, for the session's ``/general`` (segments: where the script was cut)."""
    return {
        "segments": len(look.segments),
        "cut_times_s": [round(t * 1e-9, 9) for t in look.cut_times_ns],
        "presettle_s": PRESETTLE_S if len(look.segments) > 1 else 0.0,
        "calls_taken": look.next,
        "calls_planned": len(look.calls),
        "worker_cpu_s": [round(seg.cpu_s, 2) for seg in look.segments],
        **({"cut_checks": look.checks} if look.agree is not None else {}),
    }
