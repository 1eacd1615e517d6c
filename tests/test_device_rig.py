"""The hardware rig is a motor plus a mapping of named streams: building, checking, health, silence timeouts,
identity and closing loop over the registered streams, so a new device stream is one registration
(``@device_stream``) and nothing else in the rig. Built from the shipped rig file without opening any device."""

from __future__ import annotations

import pytest

from beambench.acquisition.batch import Batch, ColumnSpec, StreamSpec
from beambench.acquisition.capabilities import DeviceFault
from beambench.acquisition.protocol.schema import LoadCellWiring
from beambench.backends.hardware import DeviceRig, build_device_rig
from beambench.devices.streams import DEVICE_STREAMS, device_stream

MARKERS = ("stage", "tip", "foot")


class Thermometer:
    """A toy device stream: the plate's temperature."""

    name = "plate_temperature"

    def __init__(self, port: str) -> None:
        self.port, self.stopped, self.fault = port, False, ""
        self.silence_timeout_s = 2.0

    def describe(self) -> StreamSpec:
        return StreamSpec(self.name, 10.0, {"data": ColumnSpec((), "float64", "K", (), "plate temperature")})

    def start(self) -> None:
        pass

    def read(self) -> Batch:
        return self.describe().empty_batch()

    def stop(self) -> None:
        self.stopped = True

    def check(self) -> None:
        if self.fault:
            raise DeviceFault(f"{self.name}: {self.fault}")

    def identity(self) -> dict[str, str]:
        return {"device": "thermometer", "port": self.port}

    def health(self) -> dict[str, int]:
        return {"received": 7}


@pytest.fixture
def thermometer():
    made: list[Thermometer] = []

    with DEVICE_STREAMS.restoring("thermometer"):

        @device_stream("thermometer", section="loadcell")
        def _make(ctx):  # type: ignore[no-untyped-def]
            made.append(Thermometer(ctx.section.port + "-temp"))
            return made[-1]

        yield made


def test_the_hardware_rig_is_its_motor_and_its_registered_streams():
    rig = build_device_rig(MARKERS)
    try:
        assert list(rig.named) == list(DEVICE_STREAMS) == ["mocap", "loadcells"]
        assert [s.name for s in rig.streams] == ["motor", "mocap", "loadcell"]
        assert rig.mocap is rig.named["mocap"] and rig.mocap.describe().columns["data"].labels == MARKERS
        assert set(rig.identity()) == {"backend", "motor", "mocap", "loadcells", "rig_file"}
        with pytest.raises(AttributeError, match="no attribute or stream 'thermometer'"):
            rig.thermometer  # noqa: B018
    finally:
        rig.close()


def test_a_registered_stream_is_built_identified_and_closed_with_the_others(thermometer):
    rig = build_device_rig(MARKERS)
    try:
        (t,) = thermometer
        assert rig.thermometer is t and rig.streams[-1] is t
        assert rig.identity()["thermometer"] == {"device": "thermometer", "port": t.port}
        assert rig.silence_timeouts()["plate_temperature"] == 2.0
        assert rig.device_health()["plate_temperature"] == {"received": 7}
    finally:
        rig.close()
    assert t.stopped


def test_check_and_close_loop_over_every_named_stream():
    a, b = Thermometer("a"), Thermometer("b")
    rig = DeviceRig(_Motor(), {"first": a, "second": b}, "test")
    rig.check()
    b.fault = "sensor unplugged"
    with pytest.raises(DeviceFault, match="sensor unplugged"):
        rig.check()
    assert rig.identity() == {
        "backend": "test",
        "motor": "_Motor",
        "first": {"device": "thermometer", "port": "a"},
        "second": {"device": "thermometer", "port": "b"},
    }
    rig.close()
    assert a.stopped and b.stopped and rig.motor.idled


def test_a_stream_name_registered_twice_is_refused():
    with pytest.raises(ValueError, match="registered twice"):
        device_stream("mocap", section="natnet")(lambda ctx: None)  # type: ignore[arg-type,return-value]


def test_a_stream_is_wired_by_a_section_of_the_rig_file_or_brings_its_own():
    with pytest.raises(ValueError, match="has no section 'laser'"):
        device_stream("laser")(lambda ctx: None)  # type: ignore[arg-type,return-value]
    with pytest.raises(ValueError, match="already has a section 'loadcell'"):
        device_stream("scale", section="loadcell", wiring=LoadCellWiring)(lambda ctx: None)  # type: ignore[arg-type,return-value]
    assert set(DEVICE_STREAMS) == {"mocap", "loadcells"}


class _Motor:
    name = "motor"
    idled = False

    def idle(self) -> None:
        self.idled = True

    def check(self) -> None:
        pass

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass


def test_the_emulated_rig_takes_the_injections_its_registered_peers_name():
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.backends.emulated import build_emulated_rig, injections
    from beambench.session.slices import sim_slice

    assert set(injections()) == {s for stream in DEVICE_STREAMS.values() for s in stream.injections}
    assert {"mocap_drop", "loadcell_crc"} <= set(injections())
    sim = sim_slice(parse_protocol("name: x\nsweep: {frequencies: [5]}\n"))
    with pytest.raises(ValueError, match=r"unknown injections \['mocap_dorp'\]"):
        build_emulated_rig(sim, inject={"mocap_dorp": 0.1})
