"""The speed map of a ``track:`` protocol, from where ``track.map`` says, checked against the segments' targets.

- ``<session>.h5``: a walker session, analysed here (its per-step body speed, standard error and regime);
- ``<report>/steps.csv``: what ``beambench analyze`` wrote for such a session (the same columns);
- ``twin``: this protocol's own ``sweep:`` is run first on the sim backend (the protocol's ``sim:`` section) into
  ``<session>_map.h5`` beside the session, and analysed.

Relative paths are taken from the current folder. Every problem is a one-line :class:`ConfigError`, raised before
the rig is built.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from beambench.acquisition.batch import StreamSpec
from beambench.acquisition.capabilities import Rig
from beambench.acquisition.control.speed_controller import TrackController, track_spec
from beambench.acquisition.control.speed_map import SpeedMap, SpeedMapError
from beambench.acquisition.control.tracking_control import SpeedTracking
from beambench.acquisition.hub import Hub
from beambench.acquisition.protocol.plan import Step, motor_limits
from beambench.acquisition.protocol.scenes import scene_info
from beambench.acquisition.protocol.schema import Protocol
from beambench.acquisition.runner import ProgressCallback, Runner
from beambench.acquisition.stop_signals import StopSignal
from beambench.common.yaml_config import ConfigError

if TYPE_CHECKING:  # a run reads a table only when its map is a steps.csv
    import pandas as pd

DEFAULT_MOCAP_LOST_S = 0.25  # with monitors.mocap_lost_s: null the controller still never drives blind longer

SPEED, STDERR, FREQ, REGIME = "body_speed_mm_s", "body_speed_stderr_mm_s", "frequency_hz", "regime"


def map_from_table(table: pd.DataFrame, source: str) -> SpeedMap:
    """A :class:`SpeedMap` from an analysis table (``steps.csv`` columns); steps not ``done`` are left out."""
    for col in (FREQ, SPEED):
        if col not in table.columns:
            raise ConfigError("<protocol>", "track.map", source, f"no {col} column (not a walker analysis)")
    if "status" in table.columns:
        table = table[table["status"].astype(str) == "done"]
    stderr = table[STDERR].to_numpy(float) if STDERR in table.columns else None
    regime = table[REGIME].fillna("").astype(str).tolist() if REGIME in table.columns else None
    try:
        return SpeedMap.from_points(
            table[FREQ].to_numpy(float), table[SPEED].to_numpy(float), stderr, regime, source=source
        )
    except (SpeedMapError, ValueError) as exc:
        raise ConfigError("<protocol>", "track.map", source, str(exc)) from None


def map_from_session(path: Path) -> SpeedMap:
    """Analyse a walker session and take its speed map."""
    from beambench.analysis.session_analysis import analyze_session
    from beambench.sinks.session_file.reader import read_session

    try:
        session = read_session(path)
        analysis = analyze_session(session)
    except (OSError, KeyError, ValueError, IndexError) as exc:
        raise ConfigError("<protocol>", "track.map", str(path), f"not a readable walker session ({exc})") from None
    return map_from_table(analysis.table, str(path))


def load_map(spec: str) -> SpeedMap:
    """The map named by ``track.map`` (a session or a ``steps.csv``; ``twin`` is :func:`twin_map`)."""
    path = Path(spec)
    if not path.is_file():
        raise ConfigError(
            "<protocol>", "track.map", spec, "no such file (a walker session .h5, its steps.csv, or twin)"
        )
    if path.suffix.lower() == ".csv":
        import pandas as pd

        try:
            table = pd.read_csv(path)
        except (OSError, ValueError) as exc:
            raise ConfigError("<protocol>", "track.map", spec, f"not a readable table ({exc})") from None
        return map_from_table(table, spec)
    if path.suffix.lower() in (".h5", ".hdf5"):
        return map_from_session(path)
    raise ConfigError("<protocol>", "track.map", spec, "expected a session .h5, a steps.csv, or twin")


# how the twin's sweep is run: (protocol, its text, session path, show progress) -> (status, message); the
# session runner passes its own (beambench.session.run), which imports this module
TwinRunner = Callable[[Protocol, str, Path, bool], tuple[str, str]]


def map_sweep(protocol: Protocol) -> tuple[Protocol, str]:
    """The sweep a ``map: twin`` protocol runs first (its own ``sweep:`` on the sim backend), and its text."""
    sweep = protocol.model_copy(update={"track": None, "backend": "sim"})
    text = yaml.safe_dump(sweep.model_dump(mode="json", exclude={"track"}, exclude_none=True), sort_keys=False)
    return sweep, text


def map_path(session_path: Path) -> Path:
    """Where a ``map: twin`` run writes its map: ``<session>_map.h5`` beside the session (numbered if taken)."""
    path = session_path.with_name(f"{session_path.stem}_map.h5")
    k = 1
    while path.exists():
        path = session_path.with_name(f"{session_path.stem}_map_{k}.h5")
        k += 1
    return path


def twin_map(
    protocol: Protocol, session_path: Path, run_twin: TwinRunner, show_progress: bool = True
) -> tuple[SpeedMap, Path]:
    """Run the protocol's sweep on the sim (its ``sim:`` section) into ``<session>_map.h5`` with ``run_twin``;
    its speed map. The map's session is kept (a later protocol's ``track.map: <that file>`` reuses it without the
    sweep); a run never reuses one by itself."""
    sweep, text = map_sweep(protocol)
    path = map_path(session_path)
    status, message = run_twin(sweep, text, path, show_progress)
    if status != "completed":
        raise ConfigError("<protocol>", "track.map", "twin", f"the twin's sweep {status}: {message}")
    return map_from_session(path), path


def check_reach(protocol: Protocol, speed_map: SpeedMap, file: str = "<protocol>") -> None:
    """Refuse (one line) the first segment whose target the map cannot reach below the frequency limit."""
    assert protocol.track is not None
    targets = [s.speed_mm_s for s in protocol.track.segments]
    bad = speed_map.check_targets(targets, protocol.limits.max_frequency_hz)
    if bad is not None:
        i, reason = bad
        raise ConfigError(file, f"track.segments[{i}].speed_mm_s", targets[i], reason)


def map_summary(speed_map: SpeedMap, max_frequency_hz: float = np.inf) -> dict[str, object]:
    """What ``/general/track_map`` records: the map's points and the bands used."""
    return {
        "source": speed_map.source,
        "frequencies_hz": list(speed_map.freqs_hz),
        "speeds_mm_s": list(speed_map.speeds_mm_s),
        "irregular": list(speed_map.irregular),
        "bands": [b.describe() for b in speed_map.bands(max_frequency_hz)],
    }


@dataclass
class Tracking:
    """What a ``track:`` run adds to a session: the controller (a hub sink), its stream and the map's record."""

    protocol: Protocol
    controller: TrackController
    spec: StreamSpec
    map_info: dict[str, object]

    def runner(
        self, rig: Rig, hub: Hub, steps: list[Step], on_progress: ProgressCallback | None, stop: StopSignal
    ) -> Runner:
        """The ordinary runner with speed tracking as its step control, polling every ``control_s``."""
        assert self.protocol.track is not None
        max_pause_s = self.protocol.monitors.max_pause_s
        targets = [s.speed_mm_s for s in self.protocol.track.segments]
        return Runner(
            rig,
            hub,
            steps,
            motor_limits(self.protocol),
            self.controller.c.control_s,
            on_progress,
            max_pause_s=max_pause_s,
            stop=stop,
            control=SpeedTracking(self.controller, targets, hub, max_pause_s),
        )


def track_setup(protocol: Protocol, session_path: Path, run_twin: TwinRunner, show_progress: bool = True) -> Tracking:
    """Resolve and check the map (``twin``: run its sweep first with ``run_twin``), then build the controller: all
    before the rig is built, so a target out of reach moves nothing."""
    track = protocol.track
    assert track is not None
    if track.map == "twin":
        speed_map, _ = twin_map(protocol, session_path, run_twin, show_progress)
    else:
        speed_map = load_map(track.map)
    check_reach(protocol, speed_map)
    lost_s = protocol.monitors.mocap_lost_s or DEFAULT_MOCAP_LOST_S
    body = scene_info(protocol.rig).body_marker
    assert body is not None  # the protocol model refuses track: on a rig whose scene does not walk
    controller = TrackController(speed_map, track.control, protocol.limits.max_frequency_hz, lost_s, body)
    info = map_summary(speed_map, protocol.limits.max_frequency_hz)
    return Tracking(protocol, controller, track_spec(track.control.control_s), info)
