"""What the live view shows for a rig, and its Rerun blueprint: made from the streams' own specs and the rig name.

:func:`layout_of` reads what a rig has (its markers, the force plate, the motor) from the :class:`StreamSpec`
list and the session's rig name; the columns a spec marks ``plotted`` go to the view, each in a panel of its own
unless one of the rig's panels below already shows it (so a new stream is shown with no entry here);
:func:`blueprint` lays it out: a 3-D view of the beam beside a column of
time series with one quantity per panel, each over a short window that scrolls with the time cursor and keeps
peaks (min/max aggregation), and a text panel with the step. Rerun draws no unit on a plot's axis, so the unit
is in each panel's title and in each series' legend name.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from beambench.acquisition.batch import StreamSpec
from beambench.acquisition.protocol.scenes import scene_or_unknown

TIMELINE = "session_time"
FORCE_WINDOW_S = 2.0  # 1 kHz plate forces: 2 s holds a few cycles of a slow step and stays readable at 40 Hz
LOADCELL_WINDOW_S = 2.0
DRIVE_WINDOW_S = 60.0  # the staircase of the last several steps
TRACK_WINDOW_S = 30.0  # the speed controller: several control windows of the walker's body speed
CURRENT_WINDOW_S = 10.0
BODY_WINDOW_S = 30.0
OTHER_WINDOW_S = 10.0  # a plotted column of a stream no panel below names
OTHER_COLORS = ((255, 140, 0), (90, 160, 255), (60, 200, 90), (230, 90, 140), (200, 120, 255), (150, 150, 150))


@dataclass(frozen=True)
class Series:
    """One plotted entity: its legend name (with the unit) and colour."""

    entity: str
    name: str
    color: tuple[int, int, int]


@dataclass(frozen=True)
class Panel:
    """One time-series panel: a title with the unit, its series and how many seconds back it shows."""

    title: str
    series: tuple[Series, ...]
    window_s: float


@dataclass(frozen=True)
class RigLayout:
    """What the view draws for one rig (marker names as the mocap stream labels them)."""

    rig: str
    markers: tuple[str, ...]
    up_axis: str
    forward_axis: str
    chains: tuple[tuple[str, ...], ...]  # beam line strips through markers (stage → tip → foot; body → each foot)
    trails: tuple[str, ...]  # markers with a short fading trail (the feet, else the tip)
    body: str | None  # the walker's body marker: long trail, position and speed panels
    plate: bool  # a force plate under the foot: plate box, force and load-cell panels
    loadcell_channels: tuple[str, ...]
    motor: bool
    mocap_rate_hz: float = 360.0
    track: bool = False  # a speed-tracking run (acquisition.control.speed_controller): target, measured, commanded
    plotted: frozenset[tuple[str, str]] = frozenset()  # (stream, column) the view receives: the specs' plotted ones
    others: tuple[Panel, ...] = ()  # a panel for each plotted column the rig's own panels do not show

    @property
    def panels(self) -> tuple[Panel, ...]:
        return (*self._rig_panels(), *self.others)

    def _rig_panels(self) -> list[Panel]:
        out: list[Panel] = []
        if self.motor:
            out.append(
                Panel(
                    "Drive frequency (Hz): motor velocity vs setpoint",
                    (
                        Series("motor/velocity_setpoint", "setpoint (turn/s)", (150, 150, 150)),
                        Series("motor/velocity", "measured (turn/s)", (255, 140, 0)),
                    ),
                    DRIVE_WINDOW_S,
                )
            )
        if self.body is not None:
            out.append(
                Panel("Body speed (mm/s)", (Series("body/speed", "speed (mm/s)", (60, 200, 90)),), BODY_WINDOW_S)
            )
            out.append(
                Panel("Body position (mm)", (Series("body/forward", "forward (mm)", (90, 160, 255)),), BODY_WINDOW_S)
            )
        if self.plate:
            out.append(
                Panel("Plate normal force (N)", (Series("force/normal", "normal (N)", (80, 200, 120)),), FORCE_WINDOW_S)
            )
            out.append(
                Panel(
                    "Plate tangential force (N)",
                    (Series("force/tangential", "tangential (N)", (230, 90, 140)),),
                    FORCE_WINDOW_S,
                )
            )
        if self.track:
            out.append(
                Panel(
                    "Speed tracking (mm/s): target vs measured",
                    (
                        Series("track/target_mm_s", "target (mm/s)", (150, 150, 150)),
                        Series("track/measured_mm_s", "measured (mm/s)", (60, 200, 90)),
                    ),
                    TRACK_WINDOW_S,
                )
            )
            out.append(
                Panel(
                    "Commanded drive frequency (Hz)",
                    (
                        Series("track/feedforward_hz", "map's frequency (Hz)", (150, 150, 150)),
                        Series("track/frequency_hz", "commanded (Hz)", (255, 140, 0)),
                    ),
                    TRACK_WINDOW_S,
                )
            )
        if self.motor:
            out.append(
                Panel("Motor current (A)", (Series("motor/iq_measured", "Iq (A)", (200, 120, 255)),), CURRENT_WINDOW_S)
            )
        return out

    @property
    def loadcell_panel(self) -> Panel | None:
        if not self.plate or not self.loadcell_channels:
            return None
        colors = [(100, 180, 255), (255, 180, 80), (120, 220, 120), (240, 110, 110)]
        series = tuple(
            Series(f"loadcell/{c}", f"{c} (counts)", colors[i % len(colors)])
            for i, c in enumerate(self.loadcell_channels)
        )
        return Panel("Load cells (raw counts)", series, LOADCELL_WINDOW_S)

    def logged(self, stream: str, column: str) -> bool:
        """Whether a stream's column goes to the view: one its spec marks ``plotted`` (the load cells' raw counts
        only over a plate)."""
        return (stream, column) in self.plotted

    def up_vector(self) -> np.ndarray:
        return axis_vector(self.up_axis)

    def forward_vector(self) -> np.ndarray:
        return axis_vector(self.forward_axis)


def axis_vector(axis: str) -> np.ndarray:
    """The unit vector of a signed axis name (``z``, ``-y``, ``+x``)."""
    v = np.zeros(3)
    v["xyz".index(axis.lstrip("+-"))] = -1.0 if axis.startswith("-") else 1.0
    return v


def layout_of(specs: list[StreamSpec], rig: str | None = None) -> RigLayout:
    """The layout for these streams on rig ``rig`` (a name of the scene catalogue; None or a name it does not
    know: a rig with no body and no plate flags).

    The rig's scene says what is drawn (:class:`beambench.acquisition.protocol.scenes.SceneInfo`): a scene that walks
    has its legs drawn from its body marker to each other marker and the view follows the body; otherwise the
    markers form one chain in the stream's order (stage → tip → foot). A load-cell stream is a plate under the foot
    where the scene has one (``plate``; the walker's sim streams a load cell but has no plate)."""
    by_name = {s.name: s for s in specs}
    mocap = by_name.get("mocap")
    markers = tuple(mocap.columns["data"].labels) if mocap is not None and "data" in mocap.columns else ()
    frame = mocap.frame if mocap is not None else None
    scene = scene_or_unknown(rig or "")
    body = scene.body_marker if scene.body_marker in markers else None
    chains: tuple[tuple[str, ...], ...]
    if body is not None:
        chains = tuple((body, m) for m in markers if m != body)
    else:
        chains = (markers,) if len(markers) > 1 else ()
    feet = tuple(m for m in markers if m.startswith("foot"))
    trails = feet + tuple(m for m in markers if m == "tip")
    loadcell = by_name.get("loadcell")
    plate = loadcell is not None and scene.plate
    channels = tuple(loadcell.columns["data"].labels) if loadcell is not None and "data" in loadcell.columns else ()
    plotted = frozenset(
        (s.name, key) for s in specs if s is not loadcell or plate for key, col in s.columns.items() if col.plotted
    )
    layout = RigLayout(
        rig=rig or "",
        markers=markers,
        up_axis=frame.up_axis if frame is not None else "z",
        forward_axis=frame.forward_axis if frame is not None else "x",
        chains=chains,
        trails=trails,
        body=body,
        plate=plate,
        loadcell_channels=channels,
        motor="motor" in by_name,
        mocap_rate_hz=mocap.rate_hz if mocap is not None and mocap.rate_hz > 0 else 360.0,
        track="track" in by_name,
        plotted=plotted,
    )
    return dataclasses.replace(layout, others=_other_panels(layout, specs))


def _entities(stream: str, column: str, labels: tuple[str, ...]) -> tuple[str, ...]:
    """The entities a plotted column is sent to (as :class:`beambench.sinks.viewer.sink.RerunSink` sends them):
    one per label, else one for the column."""
    return tuple(f"{stream}/{label}" for label in labels) if labels else (f"{stream}/{column}",)


def _other_panels(layout: RigLayout, specs: list[StreamSpec]) -> tuple[Panel, ...]:
    """A panel for each plotted column that none of the rig's own panels shows: titled with the stream's and the
    column's descriptions and the unit, a series per label."""
    panels = [*layout.panels, *([layout.loadcell_panel] if layout.loadcell_panel else [])]
    shown = {s.entity for p in panels for s in p.series}
    out: list[Panel] = []
    for spec in specs:
        for key, col in spec.columns.items():
            entities = _entities(spec.name, key, col.labels)
            if (spec.name, key) not in layout.plotted or set(entities) <= shown:
                continue
            unit = f" ({col.unit})" if col.unit else ""
            names = col.labels or (key,)
            series = tuple(
                Series(e, f"{n}{unit}", OTHER_COLORS[i % len(OTHER_COLORS)])
                for i, (e, n) in enumerate(zip(entities, names))
            )
            title = f"{spec.description or spec.name}: {col.description or key}{unit}"
            out.append(Panel(title, series, OTHER_WINDOW_S))
    return tuple(out)


@dataclass(frozen=True)
class Camera:
    """Where the 3-D view's eye starts (mm, the view's frame) and where the grid (the floor or plate level) lies."""

    position: tuple[float, float, float]
    look_target: tuple[float, float, float]
    grid_height_mm: float  # along the up axis
    grid_spacing_mm: float
    grid: bool = True  # the walker draws its own floor lines, fixed in the world, instead


def series_styles(layout: RigLayout) -> dict[str, rr.SeriesLines]:
    """Static line styles per plotted entity: legend name with unit, colour, min/max aggregation (peaks kept)."""
    panels = [*layout.panels, *([layout.loadcell_panel] if layout.loadcell_panel else [])]
    return {
        s.entity: rr.SeriesLines(colors=[s.color], names=[s.name], widths=[1.5], aggregation_policy="minmax")
        for p in panels
        for s in p.series
    }


def _window(seconds: float) -> rrb.VisibleTimeRange:
    return rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-seconds),
        end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0),
    )


def _time_series(p: Panel) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        origin="/",
        contents=[f"/{s.entity}" for s in p.series],
        name=p.title,
        time_ranges=[_window(p.window_s)],
        plot_legend=rrb.PlotLegend(corner="LeftTop", visible=True),
    )


FOLLOW_ORIGIN = "/mocap/follow"  # the walker's view frame (:data:`beambench.sinks.viewer.scene.FOLLOW_ENTITY`)


def spatial_view(layout: RigLayout, camera: Camera | None) -> rrb.Spatial3DView:
    """The 3-D view: markers, beam, trails (and plate or floor), the eye framed on the beam. The walker's is seen
    from the frame that follows its body (everything under ``/mocap`` is drawn relative to it)."""
    if layout.body is not None:
        what = "body and legs, followed over the floor, body trail"
    else:
        what = " → ".join(layout.chains[0]) if layout.chains else "markers"
        what += ", plate (brown)" if layout.plate else ""
    kwargs: dict[str, object] = {}
    if camera is not None:
        up = layout.up_vector()
        kwargs["eye_controls"] = rrb.EyeControls3D(
            kind="Orbital",
            position=camera.position,
            look_target=camera.look_target,
            eye_up=tuple(up),
        )
        kwargs["line_grid"] = rrb.LineGrid3D(
            visible=camera.grid,
            spacing=camera.grid_spacing_mm,
            plane=rr.components.Plane3D(tuple(up), distance=camera.grid_height_mm),
            color=[90, 90, 90, 110],
        )
    origin = FOLLOW_ORIGIN if layout.body is not None else "/mocap"
    return rrb.Spatial3DView(
        origin=origin,
        contents="/mocap/**",
        name=f"Beam: {what} (mm)",
        **kwargs,  # type: ignore[arg-type]
    )


def blueprint(layout: RigLayout, camera: Camera | None = None, live: bool = True) -> rrb.Blueprint:
    """The rig's layout. ``live``: the time panel follows the newest data; a saved recording opens paused at its
    start, which is the first step's start (the user scrubs to a step; a finished file has no "newest")."""
    lower: list[rrb.View] = [rrb.TextLogView(origin="/events", name="Events")]
    loadcells = layout.loadcell_panel
    if loadcells is not None:
        lower.insert(0, _time_series(loadcells))
    left = rrb.Vertical(
        spatial_view(layout, camera),
        rrb.Horizontal(
            rrb.TextDocumentView(origin="/step", name="Step (drive frequency, Hz)"),
            rrb.Tabs(*lower),
            column_shares=[2, 3],
        ),
        row_shares=[3, 1],
    )
    right = rrb.Vertical(*[_time_series(p) for p in layout.panels])
    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[3, 2]),
        rrb.TimePanel(timeline=TIMELINE, play_state="following" if live else "paused", state="collapsed"),
        collapse_panels=True,
    )
