"""The simulation slice of a protocol: what the sim backend runs and what a calibration simulates.

A frozen :class:`SimSlice` holds every choice made: the scene, the beam (model and parameter set, ``sim.model:
auto`` already resolved from the measured table), the windows, twist and amplitude in SI, the integrator and
timestep plan, the plate gap, thermal drift, noise, seed and device clocks. It is made from a protocol in one
function, :func:`beambench.session.slices.sim_slice`; the sim backend builds its scene and devices from it and a
calibration simulates its ``model`` with its ``settings``, so a protocol's run and its calibration cannot simulate
different models.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from beambench.acquisition.clocks import DeviceClocks
from beambench.acquisition.protocol.schema import Release, ThermalDrift
from beambench.sim.selection import Plan
from beambench.sim.settings import SimSettings

__all__ = ["AUTO_TOLERANCE_MM", "SimSlice"]

AUTO_TOLERANCE_MM = 0.1  # sim.model: auto without sim.tolerance_mm (about the mocap's noise)


@dataclass(frozen=True)
class SimSlice:
    """One protocol's simulation, every choice made (SI units: s, deg, m)."""

    scene: str
    """The registered scene (the protocol's ``rig``)."""
    model: str
    """The beam model, ``auto`` already resolved."""
    params: str
    """The parameter set's name."""
    settings: SimSettings
    """Windows, twist, amplitude, integrator (the plan's, when there is one), fixed timestep, noise, seed."""
    plan: Plan | None = None
    """The measured plan (timestep per frequency; :mod:`beambench.sim.selection`), or None: the scene's policy."""
    tolerance_mm: float = AUTO_TOLERANCE_MM
    """The accuracy the plan was chosen for."""
    plate_gap_m: float | None = None
    """h' from the foot's unloaded position; None: the parameter set's."""
    thermal: ThermalDrift | None = None
    """The contact twin's thermal drift, or None: off."""
    release: Release = field(default_factory=Release)
    """The release test's load and markers."""
    segments: int = 1
    """Consecutive parts of the sweep computed in parallel (:mod:`beambench.backends.lookahead`)."""
    clocks: DeviceClocks = field(default_factory=DeviceClocks)
    """The simulated devices' clocks."""
    stage_amplitude_m: float | None = None
    """The stage amplitude the motor reports (scenes with a stage), else None."""

    @property
    def integrator(self) -> str:
        """The MuJoCo integrator (the plan's, else ``sim.integrator``)."""
        return self.settings.integrator or "implicitfast"

    @property
    def timestep(self) -> float | None:
        """The fixed ``sim.timestep``, or None: the plan's per frequency, else the scene's own."""
        h = self.settings.timestep
        return None if h is None or isinstance(h, tuple) else float(h)
