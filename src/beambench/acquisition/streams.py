"""The standard streams every backend produces, so sessions from sim, emulated and real rigs look alike.

Units: positions in metres (as Motive sends them), forces raw in load-cell counts (calibrated later),
motor in turns and turn/s (as the ODrive reports them). ``device_time`` is seconds on the device's clock.
"""

from __future__ import annotations

from beambench.acquisition.batch import ColumnSpec, Frame, StreamSpec
from beambench.acquisition.protocol.scenes import CONTACT, WALKER

MOCAP = "mocap"
LOADCELL = "loadcell"
MOTOR = "motor"

MOCAP_RATE_HZ = 360.0
LOADCELL_RATE_HZ = 1000.0
MOTOR_RATE_HZ = 100.0

# each scene declares its markers (beambench.acquisition.protocol.scenes); these two names are kept for their many readers
CONTACT_MARKERS = CONTACT.markers
WALKER_MARKERS = WALKER.markers
LOADCELL_CHANNELS = ("lc0", "lc1", "lc2", "lc3")


def mocap_spec(markers: tuple[str, ...], rate_hz: float = MOCAP_RATE_HZ, frame: Frame | None = None) -> StreamSpec:
    """Labeled marker positions per frame, with the Motive frame number and per-marker occlusion."""
    m = len(markers)
    return StreamSpec(
        MOCAP,
        rate_hz,
        {
            "data": ColumnSpec((m, 3), "float64", "m", markers, "marker positions (x, y, z)"),
            "frame": ColumnSpec((), "int64", "", (), "mocap frame number"),
            "occluded": ColumnSpec((m,), "bool", "", markers, "marker not seen in this frame"),
        },
        description="motion capture markers",
        frame=frame or Frame(),
    )


def loadcell_spec(rate_hz: float = LOADCELL_RATE_HZ) -> StreamSpec:
    """Four raw load-cell channels, the MCU sequence number and the mocap sync-edge counter."""
    return StreamSpec(
        LOADCELL,
        rate_hz,
        {
            "data": ColumnSpec((4,), "int32", "count", LOADCELL_CHANNELS, "raw ADC counts", plotted=True),
            "seq": ColumnSpec((), "int64", "", (), "MCU frame sequence number"),
            "sync_edges": ColumnSpec((), "int64", "", (), "mocap exposure pulses counted by the MCU"),
        },
        description="load-cell plate, raw counts",
    )


MOTOR_COLUMNS = {
    "position": ColumnSpec((), "float64", "turn", (), "encoder position estimate"),
    "velocity": ColumnSpec((), "float64", "turn/s", (), "encoder velocity estimate", plotted=True),
    "velocity_setpoint": ColumnSpec((), "float64", "turn/s", (), "commanded velocity", plotted=True),
    "iq_measured": ColumnSpec((), "float64", "A", (), "measured quadrature current", plotted=True),
    "bus_voltage": ColumnSpec((), "float64", "V", (), "DC bus voltage"),
    "axis_state": ColumnSpec((), "int32", "", (), "ODrive AxisState"),
    "axis_error": ColumnSpec((), "int64", "", (), "ODrive axis error bits"),
}


def motor_spec(rate_hz: float = MOTOR_RATE_HZ) -> StreamSpec:
    """Motor telemetry as the ODrive reports it."""
    return StreamSpec(MOTOR, rate_hz, dict(MOTOR_COLUMNS), description="motor telemetry")
