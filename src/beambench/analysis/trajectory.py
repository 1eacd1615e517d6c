"""Trajectories in the stage frame and their ellipses (paper Fig. 2c–g, 4a).

The stage frame has two in-plane axes: ``drive`` (the stage's direction of travel, from the principal axis of
the stage marker's motion) and ``up`` (away from the plate / against gravity). A trajectory is the position of
a marker relative to the stage marker, projected on (drive, up), in millimetres. "Counter-clockwise" means as
drawn with drive to the right and up to the top, i.e. positive rotation about ``drive × up``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AXES = {"x": 0, "y": 1, "z": 2}


def axis_vector(spec: str | np.ndarray) -> np.ndarray:
    """A unit vector from ``"x"``, ``"-y"``, ``"+z"`` … or any 3-vector."""
    if isinstance(spec, str):
        s = spec.strip().lower()
        sign = -1.0 if s.startswith("-") else 1.0
        name = s.lstrip("+-")
        if name not in AXES:
            raise ValueError(f"axis must be x, y or z with an optional sign, got {spec!r}")
        v = np.zeros(3)
        v[AXES[name]] = sign
        return v
    v = np.asarray(spec, np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not n > 0:
        raise ValueError("axis vector must be non-zero")
    return v / n


def _snap(v: np.ndarray) -> np.ndarray:
    """The signed world axis nearest to ``v``."""
    k = int(np.argmax(np.abs(v)))
    out = np.zeros(3)
    out[k] = np.sign(v[k]) or 1.0
    return out


@dataclass(frozen=True)
class StageFrame:
    """Orthonormal drive / up / normal (= drive × up) axes in world (mocap) coordinates."""

    drive: np.ndarray
    up: np.ndarray

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.drive, self.up)

    def project(self, rel_xyz: np.ndarray) -> np.ndarray:
        """(drive, up) components of vectors ``[n, 3]`` (same unit as the input)."""
        r = np.asarray(rel_xyz, np.float64)
        return np.stack([r @ self.drive, r @ self.up], axis=-1)

    def as_dict(self) -> dict[str, list[float]]:
        return {"drive": self.drive.tolist(), "up": self.up.tolist(), "normal": self.normal.tolist()}


def drive_axis(stage_xyz: np.ndarray) -> np.ndarray:
    """Unit vector of the stage's travel (principal axis), signed to point along its dominant world axis."""
    p = np.asarray(stage_xyz, np.float64)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 3:
        raise ValueError("need at least 3 valid stage positions to find the drive axis")
    c = p - p.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    d = vt[0]
    k = int(np.argmax(np.abs(d)))
    return d * np.sign(d[k])


def stage_frame(
    stage_xyz: np.ndarray,
    up: str | np.ndarray | None = None,
    *,
    hanging_xyz: np.ndarray | None = None,
) -> StageFrame:
    """Build the stage frame from the stage marker's motion.

    ``up``: a world axis (``"z"``, ``"-y"``, a vector) or None to guess: the world axis nearest to the
    direction from a marker hanging below the stage (``hanging_xyz``, the foot) to the stage when one axis
    clearly dominates it, else +z (MuJoCo's up; Motive's default is +y, so pass ``up`` for rig data).
    The up axis is made orthogonal to the drive axis.
    """
    d = drive_axis(stage_xyz)
    if up is not None:
        u = axis_vector(up)
    else:
        u = axis_vector("z")
        if hanging_xyz is not None and np.isfinite(hanging_xyz).any():
            s = np.nanmean(np.asarray(stage_xyz, float), axis=0)
            h = np.nanmean(np.asarray(hanging_xyz, float), axis=0)
            v = s - h
            v = v - (v @ d) * d
            mag = np.sort(np.abs(v))
            if mag[-1] > 1.2 * mag[-2]:  # one world axis clearly dominates: trust it
                u = _snap(v)
    u = u - (u @ d) * d
    n = np.linalg.norm(u)
    if n < 1e-6:
        raise ValueError("the up axis is parallel to the drive axis")
    return StageFrame(d, u / n)


def relative_trajectory(marker_xyz: np.ndarray, stage_xyz: np.ndarray, frame: StageFrame) -> np.ndarray:
    """Marker position relative to the stage marker on (drive, up), in mm (NaN where either is missing)."""
    return frame.project(np.asarray(marker_xyz, float) - np.asarray(stage_xyz, float)) * 1e3


# ------------------------------------------------------------------------------------------------ ellipses


@dataclass(frozen=True)
class Ellipse:
    """An ellipse in the (drive, up) plane: full axis lengths, tilt of the major axis from the drive axis.

    ``clockwise`` is None when unknown (a conic fit to unordered points) or degenerate (a line).
    """

    center: tuple[float, float]
    major: float
    minor: float
    tilt_deg: float
    clockwise: bool | None
    r2: float = float("nan")

    @property
    def ratio(self) -> float:
        return self.minor / self.major if self.major > 0 else float("nan")

    def points(self, n: int = 200) -> np.ndarray:
        """``n`` points around the ellipse in its sense of travel (counter-clockwise if unknown)."""
        s = np.linspace(0, 2 * np.pi, n)
        if self.clockwise:
            s = -s
        th = np.deg2rad(self.tilt_deg)
        rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        local = np.stack([self.major / 2 * np.cos(s), self.minor / 2 * np.sin(s)])
        return (rot @ local).T + np.asarray(self.center)


NAN_ELLIPSE = Ellipse((float("nan"), float("nan")), float("nan"), float("nan"), float("nan"), None)


def _tilt(direction: np.ndarray) -> float:
    """Angle (deg, in (−90, 90]) of an axis direction from the drive axis."""
    a = float(np.degrees(np.arctan2(direction[1], direction[0])))
    if a <= -90:
        a += 180
    elif a > 90:
        a -= 180
    return a


def fit_ellipse_harmonic(t_s: np.ndarray, xy: np.ndarray, frequency_hz: float, *, min_ratio: float = 1e-3) -> Ellipse:
    """The first-harmonic ellipse of a periodic path: ``xy(t) ≈ c + A·cos ωt + B·sin ωt``.

    Robust to noise and missing samples (least squares on what is there). Axes are the singular values of
    ``[A B]`` (×2 for full lengths); the sense of travel is the sign of ``A × B``. ``r2`` is the share of the
    path's variance the ellipse explains (1 for a perfect ellipse, lower for figure-8s and contact-flattened
    loops).
    """
    t = np.asarray(t_s, float)
    p = np.asarray(xy, float)
    ok = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
    t, p = t[ok], p[ok]
    if len(t) < 6 or not np.isfinite(frequency_hz) or frequency_hz <= 0:
        return NAN_ELLIPSE
    w = 2 * np.pi * frequency_hz * (t - t[0])
    a = np.column_stack([np.cos(w), np.sin(w), np.ones_like(w)])
    coef, *_ = np.linalg.lstsq(a, p, rcond=None)
    m = coef[:2].T  # columns A, B
    u, s, _ = np.linalg.svd(m)
    resid = p - a @ coef
    var = float(np.sum((p - p.mean(axis=0)) ** 2))
    r2 = 1.0 - float(np.sum(resid**2)) / var if var > 0 else float("nan")
    cross = float(np.linalg.det(m))
    cw: bool | None = None if s[0] <= 0 or s[1] / s[0] < min_ratio else bool(cross < 0)
    return Ellipse((float(coef[2, 0]), float(coef[2, 1])), float(2 * s[0]), float(2 * s[1]), _tilt(u[:, 0]), cw, r2)


def fit_ellipse_points(xy: np.ndarray) -> Ellipse:
    """Direct least-squares conic fit of an ellipse to points (Fitzgibbon–Pilu–Fisher, Halíř–Flusser form).

    For paths without timing. The sense of travel comes from the signed area of the ordered points.
    """
    p = np.asarray(xy, float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 6:
        return NAN_ELLIPSE
    mu = p.mean(axis=0)
    sc = float(np.std(p - mu)) or 1.0
    x, y = ((p - mu) / sc).T
    d1 = np.column_stack([x * x, x * y, y * y])
    d2 = np.column_stack([x, y, np.ones_like(x)])
    s1, s2, s3 = d1.T @ d1, d1.T @ d2, d2.T @ d2
    try:
        t = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        return NAN_ELLIPSE
    m = s1 + s2 @ t
    m = np.array([m[2] / 2, -m[1], m[0] / 2])
    _, vecs = np.linalg.eig(m)
    vecs = np.real(vecs)
    cond = 4 * vecs[0] * vecs[2] - vecs[1] ** 2
    good = np.flatnonzero(cond > 0)
    if len(good) == 0:
        return NAN_ELLIPSE
    a1 = vecs[:, good[0]]
    a, b, c = a1
    d, e, f = t @ a1
    # centre and axes of a·x² + b·xy + c·y² + d·x + e·y + f = 0
    mat = np.array([[a, b / 2], [b / 2, c]])
    try:
        c0 = np.linalg.solve(2 * mat, [-d, -e])
    except np.linalg.LinAlgError:
        return NAN_ELLIPSE
    k = -(a * c0[0] ** 2 + b * c0[0] * c0[1] + c * c0[1] ** 2 + d * c0[0] + e * c0[1] + f)
    ev, evec = np.linalg.eigh(mat / k)
    if np.any(ev <= 0):
        return NAN_ELLIPSE
    semi = 1 / np.sqrt(ev)  # ascending eigenvalues → descending semi-axes
    major_dir = evec[:, 0]
    centre = c0 * sc + mu
    area = signed_area(p)
    cw = None if area == 0 else bool(area < 0)
    return Ellipse(
        (float(centre[0]), float(centre[1])), float(2 * semi[0] * sc), float(2 * semi[1] * sc), _tilt(major_dir), cw
    )


def signed_area(xy: np.ndarray) -> float:
    """Shoelace area enclosed by an ordered path (positive = counter-clockwise), skipping missing points."""
    p = np.asarray(xy, float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 3:
        return 0.0
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def area_per_cycle(t_s: np.ndarray, xy: np.ndarray, frequency_hz: float) -> float:
    """Mean signed area swept per drive cycle (mm² if ``xy`` is in mm); ≈ 0 for lines and figure-8s."""
    t = np.asarray(t_s, float)
    p = np.asarray(xy, float)
    ok = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
    t, p = t[ok], p[ok]
    if len(t) < 3 or not frequency_hz > 0:
        return float("nan")
    cycles = (t[-1] - t[0]) * frequency_hz
    if cycles < 1:
        return float("nan")
    x, y = p[:, 0] - p[:, 0].mean(), p[:, 1] - p[:, 1].mean()
    open_area = 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))
    return open_area / cycles


def mean_path(t_s: np.ndarray, xy: np.ndarray, period_s: float, bins: int | None = None) -> np.ndarray:
    """Phase-averaged path over one period (``[bins', 2]``, closed): the repeating shape without the noise.

    Samples are folded by ``t mod period`` into ``bins`` phase bins (default: ~20 samples per bin, 12–60
    bins), lightly smoothed around the loop; bins without samples (a frame rate commensurate with the
    period) are skipped. Use the contact period (k drive periods in a 1/k regime) to keep figure-8s intact.
    """
    t = np.asarray(t_s, float)
    p = np.asarray(xy, float)
    ok = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
    t, p = t[ok], p[ok]
    if len(t) < 3 or not period_s > 0:
        return np.zeros((0, 2))
    if bins is None:
        bins = int(np.clip(len(t) // 20, 12, 60))
    ph = np.mod(t - t[0], period_s) / period_s
    b = np.minimum((ph * bins).astype(int), bins - 1)
    cnt = np.bincount(b, minlength=bins).astype(float)
    sx = np.bincount(b, p[:, 0], minlength=bins)
    sy = np.bincount(b, p[:, 1], minlength=bins)

    # circular [1, 2, 1] smoothing of the sums (weights follow the sample counts)
    def kern(v):
        return np.roll(v, 1) + 2 * v + np.roll(v, -1)

    have = cnt > 0
    cnt, sx, sy = kern(cnt), kern(sx), kern(sy)
    out = np.column_stack([sx[have] / cnt[have], sy[have] / cnt[have]])
    return np.vstack([out, out[:1]]) if len(out) else out
