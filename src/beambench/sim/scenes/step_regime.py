"""One step of the contact rig classified as ``beambench analyze`` classifies a session's step: its record window
(:class:`StepWindow`), the :class:`Classifier` (the load cells' and the mocap's view, optional noise), and whether
two runs of one step land in the same regime (:func:`steps_agree`, the check at a cut between parallel segments)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from beambench.acquisition.forces.contact_events import ContactParams, force_contacts
from beambench.acquisition.forces.loadcell_calibration import default_calibration
from beambench.acquisition.streams import CONTACT_MARKERS, LOADCELL_RATE_HZ, MOCAP_RATE_HZ
from beambench.sim.engine.stepping import Trajectory
from beambench.sim.settings import SimSettings

LOADCELL_NOISE_COUNTS = 15.0  # per raw channel, as the sim backend's load cells (sim.noise: true)
MOCAP_NOISE_M = 1e-4  # per axis, as the sim backend's mocap


@dataclass(frozen=True)
class StepWindow:
    """One step's record window: rows every ``timestep`` s from ``t0`` of the plate's normal and tangential
    force of the foot (N) and the foot's x (m)."""

    frequency_hz: float
    timestep: float
    t0: float
    normal: np.ndarray
    tangential: np.ndarray
    foot_x: np.ndarray


@dataclass
class Classifier:
    """Classifies step windows as the analysis classifies a session's steps: the force box-averaged over the
    load cells' sample period, optional load-cell and mocap noise (drawn from ``rng`` in step order)."""

    noise: bool = False
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    contact: ContactParams = field(default_factory=ContactParams)
    cal: Any = field(default_factory=default_calibration)

    @classmethod
    def of(cls, sim: SimSettings, contact: ContactParams | None) -> Classifier:
        return cls(sim.noise, np.random.default_rng(sim.seed), contact or ContactParams())

    def classify(self, w: StepWindow) -> dict:
        """One step's regime row (:func:`force_contacts` on the load cells' view; the foot's x track as the
        mocap sees it for the touchdown direction)."""
        f, h = w.frequency_hz, w.timestep
        force = self._loadcells(w.normal, w.tangential, h)
        box = 1.0 / LOADCELL_RATE_HZ
        t = w.t0 + (np.arange(len(force)) + 1) * box  # each sample at the end of its averaging interval
        c, summ = force_contacts(t, force[:, 0], float(f), self.contact)
        ft_in = force[c.mask, 1]
        mean_ft = float(np.mean(ft_in)) if len(ft_in) else np.nan
        # foot track as the mocap sees it (360 Hz, optional noise), velocity by central differences
        step = max(1, round(1.0 / (MOCAP_RATE_HZ * h)))
        xm = w.foot_x[::step].astype(float)
        tm = w.t0 + np.arange(len(xm)) * step * h
        if self.noise:
            xm = xm + self.rng.normal(0.0, MOCAP_NOISE_M, xm.shape)
        v = np.gradient(xm, tm) if len(xm) > 1 else np.zeros_like(xm)
        win = 0.1 / f
        td_v = [
            float(np.mean(v[(tm >= td - win) & (tm <= td)]))
            for td in c.touchdown_s
            if np.any((tm >= td - win) & (tm <= td))
        ]
        med = float(np.median(td_v)) if td_v else np.nan
        return {
            "contacts_per_cycle": summ.contacts_per_cycle,
            "regime": summ.regime,
            "tangential_sign": sign(mean_ft),
            "touchdown_direction": sign(med),
            "in_contact_fraction": summ.in_contact_fraction,
            "n_contacts": summ.n_contacts,
            "mean_tangential_n": mean_ft,
            "peak_normal_n": float(force[:, 0].max()) if len(force) else np.nan,
        }

    def _loadcells(self, normal: np.ndarray, tang: np.ndarray, h: float) -> np.ndarray:
        """(normal, tangential) box-averaged over the load cells' sample period, with their noise if asked."""
        every = max(1, round((1.0 / LOADCELL_RATE_HZ) / h))
        nb = len(normal) // every
        force = np.column_stack(
            [
                normal[: nb * every].reshape(nb, every).mean(axis=1),
                tang[: nb * every].reshape(nb, every).mean(axis=1),
            ]
        )
        if self.noise:
            counts = self.cal.counts_from_force(force)
            counts = np.round(counts + self.rng.normal(0.0, LOADCELL_NOISE_COUNTS, counts.shape))
            force = self.cal.force_from_counts(counts)
        return np.asarray(force)


CUT_CONTACT_FRACTION = 0.03  # in-contact fractions this close count as one regime at a cut (the convergence criterion)


def steps_agree(a: Trajectory, b: Trajectory, frequency_hz: float, settle_fraction: float = 1 / 3) -> bool:
    """Do two runs of one step (rows of :class:`ContactRigSim`, e.g. the state carried from the sweep and the
    same step started from rest) land in the same regime? Both classified as :func:`stepped_regime_map` does
    (noise off) after the step's first ``settle_fraction``: the same label and in-contact fractions within
    :data:`CUT_CONTACT_FRACTION`. Where a tiny change of state flips the label (the lift-off band), they differ."""
    rows = []
    for tr in (a, b):
        t0 = float(tr.t[0]) + settle_fraction * float(tr.t[-1] - tr.t[0])
        keep = tr.t > t0
        if keep.sum() < 2:
            return False
        h = float(np.median(np.diff(tr.t[keep])))
        f = tr.channels["force_nt"][keep]
        if not np.isfinite(f).all():
            return False
        foot_x = tr.channels["markers"][keep, CONTACT_MARKERS.index("foot"), 0]
        w = StepWindow(frequency_hz, h, float(tr.t[keep][0]) - h, f[:, 0], f[:, 1], foot_x)
        rows.append(Classifier().classify(w))
    return bool(
        rows[0]["regime"] == rows[1]["regime"]
        and abs(rows[0]["in_contact_fraction"] - rows[1]["in_contact_fraction"]) <= CUT_CONTACT_FRACTION
    )


def sign(x: float) -> int:
    return 0 if not np.isfinite(x) or x == 0 else int(np.sign(x))
