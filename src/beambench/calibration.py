"""Load-cell calibration: raw counts of the four channels ↔ (normal, tangential) plate force.

The forward model used by simulated and emulated load cells is ``counts = tare + sensitivity @ [Fn, Ft]``
(``sensitivity`` is 4×2, counts per newton). Measurement goes the other way through a 2×4 ``matrix`` fitted by
least squares from known loads: ``[Fn, Ft] = matrix @ ((counts - tare) / gain)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

DEFAULT_PATH = Path(__file__).resolve().parents[2] / "calibration" / "loadcells.yaml"


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
    def from_dict(cls, d: dict) -> "LoadCellCalibration":
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
    def load(cls, path: str | Path = DEFAULT_PATH) -> "LoadCellCalibration":
        return cls.from_dict(yaml.safe_load(Path(path).read_text()))


def default_calibration() -> LoadCellCalibration:
    """The shipped calibration file if present, else a nominal plate (two cells per axis, 20k counts/N)."""
    if DEFAULT_PATH.exists():
        return LoadCellCalibration.load(DEFAULT_PATH)
    sens = np.array([[20000.0, 0.0], [20000.0, 0.0], [0.0, 20000.0], [0.0, 20000.0]])
    return LoadCellCalibration(
        tare=np.array([1200.0, -800.0, 450.0, -300.0]), matrix=np.linalg.pinv(sens), sensitivity=sens, source="nominal"
    )
