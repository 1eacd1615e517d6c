"""The 3-D scene of the live view, drawn from the mocap stream (millimetres, the stream's frame).

Per mocap frame: each marker (labelled points) and the beam as a line strip through them (stage → tip → foot;
the walker's legs body → each foot). Every :data:`TRAIL_EVERY_S` of session time: a short trail of each foot
(the tip without a foot) fading into the past, and on the walker the body's long trail, a floor patch under it
with cross lines fixed in the world, its forward position and speed. On a plate rig, the plate is a box at the
foot's median height while the plate reads a contact (normal force above :data:`CONTACT_N`), redrawn when that
height moves.

The walker walks metres: its 3-D view looks from :data:`FOLLOW_ENTITY`, a frame that follows the body over the
floor (a ``Transform3D`` translation, :data:`BODY_SERIES_HZ` times a second: the body's mean position over the
last :data:`FOLLOW_S` on the floor plane). Everything is logged in the world (the stream's frame); the view
shows it relative to that frame, so the eye stays at the walker and the floor, its lines and the body's trail
slide past underneath.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import rerun as rr

from beambench.sinks.viewer.layout import TIMELINE, Camera, RigLayout

SendColumns = Callable[[str, str, np.ndarray, np.ndarray], None]

TRAIL_S = 0.3  # the fading foot/tip trail: a few drive periods above ~10 Hz
TRAIL_SEGMENTS = 6
TRAIL_EVERY_S = 0.1  # a saved file gets the trails 10 times a second (a viewer: every batch)
BODY_TRAIL_S = 20.0
BODY_TRAIL_STEP_S = 0.2  # spacing of the body trail's points
BODY_TRAIL_EVERY_S = 0.2  # a saved file redraws the body trail five times a second
FLOOR_EVERY_S = 1.0  # and the floor patch under the body once a second
FLOOR_HALF_MM = (600.0, 200.0)  # the floor patch's half size along forward and sideways
FLOOR_LINES_MM = 50.0  # spacing of the floor's cross lines (fixed in the world: they slide past a walking body)
FOLLOW_ENTITY = "mocap/follow"  # the walker's view frame: follows the body over the floor
FOLLOW_S = 0.5  # the follow frame is the body's mean floor position over this span (its swing stays visible)
EYE_DISTANCE = 1.0  # the eye's distance from the scene's centre in scene diagonals: its bounding sphere fits a 60° cone
MIN_EXTENT_MM = {False: 60.0, True: 220.0}  # the smallest scene diagonal framed (contact rig, walker)
REFRAME_SHARE = 0.15  # the scene outgrows its framing when it leaves the box by this share of its diagonal
BODY_SERIES_HZ = 30.0  # body position and speed samples per second
SPEED_WINDOW_S = 0.5  # speed: forward displacement over this span
CONTACT_N = 0.02  # normal force that counts as a contact for the plate's height (ContactParams.floor_n)
PLATE_MOVE_MM = 0.25
PLATE_MATCH_S = 3.0  # mocap frames wait this long for the plate's force of the same time
BEAM_COLOR = (250, 205, 90)
MARKER_COLORS = {
    "stage": (120, 160, 255),
    "tip": (255, 170, 40),
    "foot": (255, 70, 70),
    "body": (60, 200, 90),
    "foot_left": (255, 90, 90),
    "foot_right": (90, 200, 255),
}


class Scene3D:
    """Draws the mocap stream of one rig; ``live`` redraws trails every batch, a saved file at a fixed rate."""

    def __init__(self, rec: rr.RecordingStream, layout: RigLayout, send: SendColumns, live: bool) -> None:
        self.rec, self.layout, self.send, self.live = rec, layout, send, live
        walker = layout.body is not None
        self.radius = 6.0 if walker else 1.6  # mm
        self.index = {m: j for j, m in enumerate(layout.markers)}
        self.up = layout.up_vector()
        self.fwd = layout.forward_vector()
        self._hist_t = np.zeros(0)
        self._hist_p = np.zeros((0, len(layout.markers), 3), np.float32)
        # kept: the trails, the speed window, and mocap frames the plate's force has not covered yet (the streams
        # arrive in their own batches, up to a poll apart)
        self._keep_s = max(TRAIL_S, SPEED_WINDOW_S, PLATE_MATCH_S, BODY_TRAIL_S if walker else 0.0) + 0.5
        self._next_trail = -np.inf
        self._next_body = -np.inf
        self._next_floor = -np.inf
        # frames per trail segment: TRAIL_S of frames at the mocap's rate over TRAIL_SEGMENTS pieces
        self._seg = max(2, round(TRAIL_S * layout.mocap_rate_hz / TRAIL_SEGMENTS))
        self._next_series = -np.inf
        self._contacts: list[tuple[float, float]] = []  # recent (start, end) s of normal force > CONTACT_N
        self._plate_heights: list[np.ndarray] = []
        self._plate_mm: float | None = None
        self._lo: np.ndarray | None = None  # the scene's extent so far (mm; the walker's: in the follow frame)
        self._hi: np.ndarray | None = None
        self._next_follow = -np.inf
        self._last_follow: np.ndarray | None = None
        self._follow_logged: np.ndarray | None = None  # the follow frame last sent (mm)
        self._force_until = -np.inf  # the plate's force has been seen up to this time
        self._plate_until = -np.inf  # mocap frames up to this time were matched with it

    def log_static(self) -> None:
        """Marker styles (colour, radius, label shown) and beam colour, once."""
        for m in self.layout.markers:
            color = MARKER_COLORS.get(m, (230, 230, 230))
            self.rec.log(
                f"mocap/{m}",
                rr.Points3D.from_fields(radii=[self.radius], colors=[color], labels=[m], show_labels=True),
                static=True,
            )
        fade = [int(40 + 215 * (k + 1) / TRAIL_SEGMENTS) for k in range(TRAIL_SEGMENTS)]  # oldest piece faintest
        for m in self.layout.trails:
            color = MARKER_COLORS.get(m, (255, 200, 0))
            self.rec.log(
                f"mocap/trail/{m}",
                rr.LineStrips3D.from_fields(radii=[self.radius * 0.3], colors=[(*color, a) for a in fade]),
                static=True,
            )
        for chain in self.layout.chains:
            self.rec.log(
                _beam_entity(chain),
                rr.LineStrips3D.from_fields(radii=[self.radius * 0.45], colors=[BEAM_COLOR]),
                static=True,
            )

    def extent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The box (mm) holding every marker seen so far, in the view's frame: the stream's on a contact rig,
        the follow frame on the walker (the body's trail, the floor and its lines are background and may reach
        past the view)."""
        return None if self._lo is None or self._hi is None else (self._lo, self._hi)

    def _grow(self, pos_mm: np.ndarray) -> None:
        pts = pos_mm.reshape(-1, 3)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if not len(pts):
            return
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        self._lo = lo if self._lo is None else np.minimum(self._lo, lo)
        self._hi = hi if self._hi is None else np.maximum(self._hi, hi)

    def camera(self, lo: np.ndarray, hi: np.ndarray) -> Camera:
        """An eye outside the box ``lo``…``hi`` (mm, the view's frame) seeing all of it: aimed at its centre from
        a distance of :data:`EYE_DISTANCE` × its diagonal (outside the box; the box's bounding sphere fits a 60°
        view cone), above and to the side, the grid at the box's lowest level (the walker has its own floor
        lines, fixed in the world, instead). On the walker the frame follows the body over the floor only: a body
        that falls through the floor or folds its legs cannot pull the eye into itself."""
        centre = (lo + hi) / 2
        side = np.cross(self.up, self.fwd)
        walker = self.layout.body is not None
        diagonal = max(float(np.linalg.norm(hi - lo)), MIN_EXTENT_MM[walker])
        if walker:  # behind and to the side, above: both legs apart, the trail running back past the eye
            direction = -0.9 * side + 0.9 * self.up - 0.8 * self.fwd
        else:
            direction = -1.0 * side + 0.35 * self.up + 0.45 * self.fwd
        eye = centre + EYE_DISTANCE * diagonal * direction / np.linalg.norm(direction)
        spacing = 100.0 if walker else 10.0
        return Camera(_vec(eye), _vec(centre), float(min(lo @ self.up, hi @ self.up)), spacing, grid=not walker)

    def outgrown(self, framed: tuple[np.ndarray, np.ndarray]) -> bool:
        """Whether the scene has left the box a camera was framed on by more than :data:`REFRAME_SHARE` of the
        diagonal it was framed with (at least :data:`MIN_EXTENT_MM`; then the view is framed anew)."""
        box = self.extent()
        if box is None:
            return False
        diagonal = max(float(np.linalg.norm(framed[1] - framed[0])), MIN_EXTENT_MM[self.layout.body is not None])
        margin = REFRAME_SHARE * diagonal  # of the diagonal the eye was framed on
        return bool(np.any(box[0] < framed[0] - margin) or np.any(box[1] > framed[1] + margin))

    def contacts(self, t: np.ndarray, normal_n: np.ndarray) -> None:
        """The plate's force: remember when it read a contact (for the plate's height from the foot)."""
        on = normal_n > CONTACT_N
        if on.any():
            edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                self._contacts.append((float(t[a]), float(t[b - 1])))
            self._contacts = self._contacts[-4000:]
        self._force_until = max(self._force_until, float(t[-1]))
        if self.layout.plate:
            self._plate()

    def write(self, t: np.ndarray, pos_mm: np.ndarray) -> None:
        """One mocap batch: ``t`` (n,) session seconds, ``pos_mm`` (n, markers, 3)."""
        self._hist_t = np.concatenate([self._hist_t, t])
        self._hist_p = np.concatenate([self._hist_p, pos_mm])
        keep = self._hist_t >= self._hist_t[-1] - self._keep_s
        self._hist_t, self._hist_p = self._hist_t[keep], self._hist_p[keep]
        if self.layout.body is not None:
            follow = self._follow(len(t))
            ticks = _ticks(t, self._next_follow, 1.0 / BODY_SERIES_HZ)
            if ticks:
                self._next_follow = float(t[ticks[-1]]) + 1.0 / BODY_SERIES_HZ
                self.send(FOLLOW_ENTITY, "translations", t[ticks], follow[ticks])
            # the frame in force at each frame (the last one logged at or before it), as the viewer places it
            shown = np.empty_like(follow)
            shown[:] = self._follow_logged if self._follow_logged is not None else follow[0]
            for a, b in zip(ticks, [*ticks[1:], len(t)], strict=True):
                shown[a:b] = follow[a]
            if ticks:
                self._follow_logged = follow[ticks[-1]]
            self._grow(pos_mm - shown[:, None, :])
        else:
            self._grow(pos_mm)
        for m, j in self.index.items():
            self.send(f"mocap/{m}", "points", t, pos_mm[:, j, :])
        for chain in self.layout.chains:
            strips = pos_mm[:, [self.index[m] for m in chain], :]
            self.send(_beam_entity(chain), "strips", t, strips)
        self._trails(t)
        if self.layout.body is not None:
            self._body_series(t)
        if self.layout.plate:
            self._plate()

    def _follow(self, n: int) -> np.ndarray:
        """The follow frame at the history's last ``n`` frames (n, 3): the body's mean position over the
        :data:`FOLLOW_S` before each, on the floor plane (its height along the up axis taken out; occluded
        frames skipped, and before any frame was seen, the origin)."""
        body = self._hist_p[:, self.index[self.layout.body or ""], :].astype(float)
        seen = np.all(np.isfinite(body), axis=1)
        body = np.where(seen[:, None], body, 0.0)
        flat = body - np.outer(body @ self.up, self.up)
        sums = np.concatenate([np.zeros((1, 3)), np.cumsum(flat, axis=0)])
        counts = np.concatenate([[0], np.cumsum(seen)])
        at = np.arange(len(self._hist_t) - n, len(self._hist_t))
        start = np.searchsorted(self._hist_t, self._hist_t[at] - FOLLOW_S, side="right")
        got = counts[at + 1] - counts[start]
        mean = (sums[at + 1] - sums[start]) / np.maximum(got, 1)[:, None]
        if not np.all(got > 0):  # nothing seen in the span: hold the last position that was
            for k in np.flatnonzero(got == 0):
                mean[k] = mean[k - 1] if k > 0 else (self._last_follow if self._last_follow is not None else 0.0)
        self._last_follow = mean[-1].copy()
        return mean

    def _trails(self, t: np.ndarray) -> None:
        """The fading trails (one column of rows per batch) and, on the walker, the body's trail and floor."""
        due = [len(t) - 1] if self.live else _ticks(t, self._next_trail, TRAIL_EVERY_S)
        if not due:
            return
        self._next_trail = float(t[due[-1]]) + TRAIL_EVERY_S
        span = TRAIL_SEGMENTS * self._seg
        at = len(self._hist_t) - len(t) + np.asarray(due)  # the due frames' places in the history
        at = at[at >= span]
        if len(at):
            offsets = np.arange(TRAIL_SEGMENTS)[:, None] * self._seg + np.arange(self._seg + 1)[None, :]
            frames = (at - span)[:, None, None] + offsets[None]  # (rows, segments, points): pieces overlap by one
            for m in self.layout.trails:
                self.send(f"mocap/trail/{m}", "segments", self._hist_t[at], self._hist_p[frames, self.index[m], :])
        body = self.layout.body
        if body is None:
            return
        for i in due:
            tk = float(t[i])
            if self.live or tk >= self._next_body:
                self.rec.set_time(TIMELINE, duration=tk)
                self._body_trail(tk, self.index[body], floor=self.live or tk >= self._next_floor)
                self._next_body = tk + BODY_TRAIL_EVERY_S
                if tk >= self._next_floor:
                    self._next_floor = tk + FLOOR_EVERY_S

    def _body_trail(self, tk: float, j: int, floor: bool) -> None:
        sel = (self._hist_t > tk - BODY_TRAIL_S) & (self._hist_t <= tk)
        path = self._hist_p[sel, j, :][:: max(1, int(np.sum(sel) * BODY_TRAIL_STEP_S / BODY_TRAIL_S))]
        if len(path) < 2:
            return
        level = self._floor_mm()  # the trail lies on the floor, just above the floor patch
        below = path - np.outer(path @ self.up - (level + 0.5), self.up)
        self.rec.log("mocap/body_trail", rr.LineStrips3D([below], colors=[(60, 200, 90, 200)], radii=1.5))
        if not floor:
            return
        side = np.cross(self.up, self.fwd)
        # centred on the body, snapped to the lines' spacing: a redraw extends the floor, nothing on it moves
        ahead = round(float(below[-1] @ self.fwd) / FLOOR_LINES_MM) * FLOOR_LINES_MM
        across = round(float(below[-1] @ side) / FLOOR_LINES_MM) * FLOOR_LINES_MM
        centre = ahead * self.fwd + across * side + (level - 1.0) * self.up
        half = np.abs(self.fwd) * FLOOR_HALF_MM[0] + np.abs(side) * FLOOR_HALF_MM[1] + np.abs(self.up) * 1.0
        self.rec.log(
            "mocap/floor",
            rr.Boxes3D(centers=[centre], half_sizes=[half], colors=[(120, 120, 120, 90)], fill_mode="solid"),
        )
        marks = np.arange(-FLOOR_HALF_MM[0], FLOOR_HALF_MM[0] + 1e-6, FLOOR_LINES_MM)
        top = centre + self.up * 1.5
        lines = [
            [top + a * self.fwd - FLOOR_HALF_MM[1] * side, top + a * self.fwd + FLOOR_HALF_MM[1] * side] for a in marks
        ]
        lines += [
            [top - FLOOR_HALF_MM[0] * self.fwd + b * side, top + FLOOR_HALF_MM[0] * self.fwd + b * side]
            for b in (-FLOOR_HALF_MM[1], 0.0, FLOOR_HALF_MM[1])
        ]
        self.rec.log("mocap/floor_lines", rr.LineStrips3D(np.asarray(lines), colors=[(200, 200, 200, 140)], radii=0.8))

    def _floor_mm(self) -> float:
        feet = [self.index[m] for m in self.layout.trails]
        return float(np.min(self._hist_p[:, feet, :] @ self.up)) if feet else 0.0

    def _body_series(self, t: np.ndarray) -> None:
        times = t[_ticks(t, self._next_series, 1.0 / BODY_SERIES_HZ)]
        if not len(times):
            return
        self._next_series = float(times[-1]) + 1.0 / BODY_SERIES_HZ
        j = self.index[self.layout.body or ""]
        forward = self._hist_p[:, j, :] @ self.fwd
        x_now = np.interp(times, self._hist_t, forward)
        x_then = np.interp(times - SPEED_WINDOW_S, self._hist_t, forward)
        span = np.minimum(SPEED_WINDOW_S, times - self._hist_t[0])
        ok = span > 0.05
        self.send("body/forward", "scalars", times, x_now)
        if ok.any():
            self.send("body/speed", "scalars", times[ok], (x_now[ok] - x_then[ok]) / span[ok])

    def _plate(self) -> None:
        """Mocap frames the force now covers: the foot's heights while the plate reads a contact."""
        if "foot" not in self.index or not len(self._hist_t):
            return
        upto = min(self._force_until, float(self._hist_t[-1]))
        sel = (self._hist_t > self._plate_until) & (self._hist_t <= upto)
        if not sel.any() or not self._contacts:
            self._plate_until = max(self._plate_until, upto)
            return
        self._plate_until = upto
        t, pos_mm = self._hist_t[sel], self._hist_p[sel]
        starts = np.array([c[0] for c in self._contacts])
        ends = np.array([c[1] for c in self._contacts])
        k = np.searchsorted(starts, t, side="right") - 1
        touching = (k >= 0) & (t <= ends[np.maximum(k, 0)] + 1e-4)
        if not touching.any():
            return
        foot = pos_mm[touching, self.index["foot"], :]
        self._plate_heights = [*self._plate_heights, foot @ self.up][-50:]
        height = float(np.median(np.concatenate(self._plate_heights)))
        if self._plate_mm is not None and abs(height - self._plate_mm) < PLATE_MOVE_MM:
            return
        self._plate_mm = height
        thick = 2.0
        at = np.median(foot, axis=0)
        centre = at - self.up * (float(at @ self.up) - height + thick / 2)
        half = (1 - np.abs(self.up)) * 25.0 + np.abs(self.up) * thick / 2
        self.rec.set_time(TIMELINE, duration=float(t[touching][0]))
        self.rec.log(
            "mocap/plate",
            rr.Boxes3D(
                centers=[centre],
                half_sizes=[half],
                colors=[(150, 95, 60, 170)],
                fill_mode="solid",
            ),
        )


def _beam_entity(chain: tuple[str, ...]) -> str:
    return f"mocap/beam/{chain[-1]}"


def _ticks(t: np.ndarray, next_t: float, every: float) -> list[int]:
    """The frames (indices into ``t``) at which a drawing falls due: one per ``every`` seconds, from ``next_t``."""
    out: list[int] = []
    for i, x in enumerate(t):
        if x >= next_t:
            out.append(i)
            next_t = float(x) + every
    return out


def _vec(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])
