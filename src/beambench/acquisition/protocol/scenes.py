"""What each scene is, as the acquisition layer needs to know it: names, markers, the options it takes.

A scene is a rig the simulator can build (the contact rig, the walker, the release test, the free beam). Its
description — a :class:`SceneInfo` — lives here, below the simulator, because the protocol model (``rig:``,
:data:`beambench.acquisition.protocol.schema.RigKind`), the standard streams (marker names) and the hardware backend read
it without importing MuJoCo. Everything a scene *does* — how it is built for a run, its batched sweep engine — is
registered in its own module in :mod:`beambench.sim.scenes` against the same :class:`SceneInfo`; adding a scene is
one :func:`declare` line here plus its module there and that module's line in the package's import list
(docs/extending.md). The rest of the code asks a scene's flags, never its name.

``options`` are the scene-specific knobs: the ``sim:`` fields of a protocol and the parameters of a sweep point
that only this scene builds. Any other scene refuses them with one line (:func:`foreign_option`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from beambench.common.registry import Registry

__all__ = [
    "CONTACT",
    "FREE_BEAM",
    "RELEASE",
    "SCENES",
    "WALKER",
    "SceneInfo",
    "batched_names",
    "declare",
    "foreign_option",
    "runnable_names",
    "runnable_scenes",
    "scene_info",
    "scene_or_unknown",
]


@dataclass(frozen=True)
class SceneInfo:
    """One scene's description; every flag replaces an ``if rig == ...`` somewhere."""

    name: str
    summary: str
    markers: tuple[str, ...] = ()  # the sim scene's mocap markers, in stream order
    bench_markers: tuple[str, ...] | None = None  # labelled on the bench (rig.yaml natnet.markers), if not markers
    # option → what the other scenes lack (the end of "the <other> scene ..."), for the refusal's one line
    options: Mapping[str, str] = field(default_factory=dict)
    runnable: bool = True  # a protocol's ``rig:`` (``beambench run``); else a sweep-only scene
    driven: bool = True  # its steps drive at f > 0 Hz (the release test's one step is 0 Hz)
    plate: bool = False  # a load-cell plate under the foot: the loadcell stream measures a contact
    stage: bool = False  # a crank-driven stage: the protocol's amplitude_mm is the stage amplitude
    timing_table: str | None = None  # its measured model/timestep table in sim_backend/ (sim.model: auto, timesteps)
    batched: bool = False  # a batched engine: sweepable by ``beambench sweep``
    own_motor: bool = False  # drives its own motor (the rig file's ``walker:`` section), not the lab's crank
    body_marker: str | None = None  # the marker on a free body its legs carry: it walks (speed, paths relative to it)
    free_decay: bool = False  # its session is one free decay after a load is let go (fitted as a 2nd-order system)

    @property
    def measured_table(self) -> bool:
        """A measured model/timestep table: ``sim.model: auto`` and per-frequency timesteps apply."""
        return self.timing_table is not None

    @property
    def walks(self) -> bool:
        """A free body walks on the beams: its speed is the result, the feet's paths are relative to it."""
        return self.body_marker is not None

    @property
    def wired_markers(self) -> tuple[str, ...]:
        """The marker names a hardware run labels (the bench's wiring)."""
        return self.bench_markers if self.bench_markers is not None else self.markers


SCENES: Registry[SceneInfo] = Registry("scene", verb="declared")
"""Every declared scene by name, in declaration order (read it through the functions below)."""


def declare(info: SceneInfo) -> SceneInfo:
    """Add a scene to the catalogue (a name is declared once)."""
    return SCENES.add(info.name, info)


def scene_info(name: str) -> SceneInfo:
    """The scene called ``name``; the catalogue's KeyError (``UnknownName``) naming the declared scenes otherwise."""
    return SCENES[name]


def scene_or_unknown(name: str) -> SceneInfo:
    """The scene called ``name``, or for a name this catalogue lacks (a session from another version) a scene
    with every flag off that no protocol may name: code asking its flags then treats it as nothing special."""
    return SCENES.get(name) or SceneInfo(name, "a rig this version's scene catalogue does not know", runnable=False)


def runnable_scenes() -> tuple[SceneInfo, ...]:
    """The scenes a protocol's ``rig:`` may name (a session's rig), in declaration order."""
    return tuple(s for s in SCENES.values() if s.runnable)


def runnable_names() -> tuple[str, ...]:
    """The scenes a protocol's ``rig:`` may name, in declaration order."""
    return tuple(s.name for s in SCENES.values() if s.runnable)


def batched_names() -> tuple[str, ...]:
    """The scenes a sweep file's ``scene:`` may name (those with a batched engine)."""
    return tuple(s.name for s in SCENES.values() if s.batched)


def foreign_option(scene: str, given: Iterable[str], where: str) -> tuple[str, str] | None:
    """The first of ``given`` that is another scene's option, with the reason ``scene`` refuses it, else None.

    ``where`` names the field that picks the scene in the message (``rig`` in a protocol, ``scene`` in a sweep)."""
    own = scene_info(scene).options
    for option in sorted(given):
        if option in own:
            continue
        owners = [s for s in SCENES.values() if option in s.options]
        if owners:
            names = " or ".join(s.name for s in owners)
            return option, f"applies to {where}: {names} only (the {scene} scene {owners[0].options[option]})"
    return None


FREE_BEAM = declare(
    SceneInfo(
        "free_beam",
        "the beam shaken at one end with nothing under its tip (sweeps and the fidelity ladder)",
        runnable=False,
        batched=True,
        timing_table="ladder_table.csv",  # the fidelity ladder's measurements
    )
)
CONTACT = declare(
    SceneInfo(
        "contact",
        "the lab's contact rig: crank-driven stage, twisted beam, foot over a load-cell plate",
        markers=("stage", "tip", "foot"),
        options={
            "plate_gap_mm": "has no plate",
            "tolerance_mm": "has no measured table",
            "gap_mm": "has no plate",
            "thermal_drift": "has no thermal-drift model",
            "segments": "does not settle into a steady gait",
        },
        plate=True,
        stage=True,
        timing_table="contact_table.csv",
        batched=True,
    )
)
WALKER = declare(
    SceneInfo(
        "walker",
        "the free walker: a body on two twisted-beam legs, driven by its own motor",
        markers=("body", "foot_left", "foot_right"),
        options={"segments": "does not settle into a steady gait"},
        own_motor=True,
        body_marker="body",
    )
)
RELEASE = declare(
    SceneInfo(
        "release",
        "the release test: a load hung at the tip is let go; no drive",
        markers=("stage", "tip1", "tip2", "tip3"),
        bench_markers=CONTACT.markers,  # on the bench the release test is wired like the contact rig
        driven=False,
        free_decay=True,
    )
)
