"""Load-cell calibration: raw counts of the four channels ↔ (normal, tangential) plate force.

The forward model used by simulated and emulated load cells is ``counts = tare + sensitivity @ [Fn, Ft]``
(``sensitivity`` is 4×2, counts per newton). Measurement goes the other way through a 2×4 ``matrix`` fitted by
least squares from known loads: ``[Fn, Ft] = matrix @ ((counts - tare) / gain)``.

Calibrating: :func:`tare_counts` takes the per-channel mean over time of unloaded samples (never a mean across
channels: each cell has its own offset), then :func:`fit_matrix` fits the matrix (and the forward sensitivity)
from the mean counts under known loads and reports the residuals; :func:`calibrate` does both.
``gain`` is the per-channel amplifier gain, set by the user and left as is by the fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from beambench.common.resources import shipped_dir

DEFAULT_PATH = shipped_dir("calibration") / "loadcells.yaml"


@dataclass
class LoadCellCalibration:
    """Per-channel tare (counts) and gain, the 2×4 counts→force matrix and the 4×2 force→counts sensitivity."""

    tare: np.ndarray = field(default_factory=lambda: np.zeros(4))
    gain: np.ndarray = field(default_factory=lambda: np.ones(4))
    matrix: np.ndarray = field(default_factory=lambda: np.zeros((2, 4)))
    sensitivity: np.ndarray = field(default_factory=lambda: np.zeros((4, 2)))
    source: str = ""

    def counts_from_force(self, force_nt: np.ndarray) -> np.ndarray:
        """Raw counts (float) for forces ``[..., 2]`` = (normal, tangential) in N."""
        return self.tare + np.asarray(force_nt) @ self.sensitivity.T

    def force_from_counts(self, counts: np.ndarray) -> np.ndarray:
        """(normal, tangential) force in N for raw counts ``[..., 4]``."""
        return ((np.asarray(counts, dtype=float) - self.tare) / self.gain) @ self.matrix.T

    def to_dict(self) -> dict:
        return {
            "tare_counts": self.tare.tolist(),
            "gain": self.gain.tolist(),
            "matrix_n_per_count": self.matrix.tolist(),
            "sensitivity_counts_per_n": self.sensitivity.tolist(),
            "source": self.source,
        }

    @classmethod
    def from_dict(cls, d: dict) -> LoadCellCalibration:
        return cls(
            tare=np.asarray(d["tare_counts"], float).reshape(4),
            gain=np.asarray(d.get("gain", [1, 1, 1, 1]), float).reshape(4),
            matrix=np.asarray(d["matrix_n_per_count"], float).reshape(2, 4),
            sensitivity=np.asarray(d["sensitivity_counts_per_n"], float).reshape(4, 2),
            source=str(d.get("source", "")),
        )

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_yaml())

    @classmethod
    def load(cls, path: str | Path = DEFAULT_PATH) -> LoadCellCalibration:
        from beambench.common.yaml_config import parse_yaml, read_text

        return cls.from_dict(parse_yaml(read_text(path), str(path)))  # kind and size checked before the read


def default_calibration() -> LoadCellCalibration:
    """The shipped calibration file if present, else a nominal plate (two cells per axis, 20k counts/N)."""
    if DEFAULT_PATH.exists():
        return LoadCellCalibration.load(DEFAULT_PATH)
    sens = np.array([[20000.0, 0.0], [20000.0, 0.0], [0.0, 20000.0], [0.0, 20000.0]])
    return LoadCellCalibration(
        tare=np.array([1200.0, -800.0, 450.0, -300.0]), matrix=np.linalg.pinv(sens), sensitivity=sens, source="nominal"
    )


def tare_counts(samples: np.ndarray) -> np.ndarray:
    """Per-channel zero offset: the mean over time (axis 0) of unloaded samples ``[n, 4]``."""
    x = np.asarray(samples, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 4 or len(x) == 0:
        raise ValueError(f"tare needs samples shaped [n>0, 4], got {x.shape}")
    return x.mean(axis=0)


@dataclass
class MatrixFit:
    """Result of :func:`fit_matrix`: the 2×4 matrix, the 4×2 sensitivity and how well they fit the loads."""

    matrix: np.ndarray  # 2×4, N per (count/gain)
    sensitivity: np.ndarray  # 4×2, counts per N
    loads: np.ndarray  # k×2 known (Fn, Ft), N
    fitted: np.ndarray  # k×2 matrix @ counts, N
    rank: int  # singular directions of the load counts used (2 for loads at one point, up to 4)
    singular_values: np.ndarray

    @property
    def residuals(self) -> np.ndarray:
        """Fitted minus known force per load, N (k×2)."""
        return self.fitted - self.loads

    @property
    def rms(self) -> np.ndarray:
        """Root-mean-square residual of (Fn, Ft), N."""
        return np.sqrt(np.mean(self.residuals**2, axis=0))


def fit_matrix(
    counts: np.ndarray, loads: np.ndarray, tare: np.ndarray, gain: np.ndarray | None = None, rcond: float = 1e-3
) -> MatrixFit:
    """Least-squares fit of ``[Fn, Ft] = matrix @ ((counts - tare) / gain)`` from ``k`` known loads.

    ``counts`` is ``[k, 4]`` (mean counts under each load), ``loads`` ``[k, 2]`` in N. The loads must span
    both axes (rank 2). Singular directions of the load counts weaker than ``rcond`` × the strongest are
    dropped (loads all applied at one point excite only two directions of the four channels; fitting the
    others would amplify noise). The forward sensitivity ``counts - tare = sensitivity @ F`` is fitted too.
    """
    x_raw = np.asarray(counts, dtype=np.float64) - np.asarray(tare, dtype=np.float64)
    f = np.asarray(loads, dtype=np.float64)
    if x_raw.ndim != 2 or x_raw.shape[1] != 4 or f.shape != (len(x_raw), 2):
        raise ValueError(f"need counts [k, 4] and loads [k, 2], got {x_raw.shape} and {f.shape}")
    if np.linalg.matrix_rank(f) < 2:
        raise ValueError("the loads must include both normal and tangential components (two independent loads)")
    g = np.ones(4) if gain is None else np.asarray(gain, dtype=np.float64).reshape(4)
    x = x_raw / g
    m_t, _, rank, sv = np.linalg.lstsq(x, f, rcond=rcond)
    s_t, *_ = np.linalg.lstsq(f, x_raw, rcond=None)
    return MatrixFit(m_t.T.copy(), s_t.T.copy(), f, x @ m_t, int(rank), sv)


def calibrate(
    tare_samples: np.ndarray,
    load_counts: np.ndarray,
    loads: np.ndarray,
    gain: np.ndarray | None = None,
    source: str = "",
    rcond: float = 1e-3,
) -> tuple[LoadCellCalibration, MatrixFit]:
    """Tare (per channel) from unloaded samples, then fit the matrix from mean counts under known loads."""
    tare = tare_counts(tare_samples)
    g = np.ones(4) if gain is None else np.asarray(gain, dtype=np.float64).reshape(4)
    fit = fit_matrix(load_counts, loads, tare, g, rcond)
    return LoadCellCalibration(tare=tare, gain=g, matrix=fit.matrix, sensitivity=fit.sensitivity, source=source), fit
