"""The run's logic on an in-memory rig with a manual clock (tests/fake_rig.py): step timing, what the hub fans
out, monitor pauses and their limit, faults, sink failures and stop requests, exactly and without waiting."""

from __future__ import annotations

import pytest

from beambench.acquisition.capabilities import MotorLimits
from beambench.acquisition.hub import Hub
from beambench.acquisition.monitors import MocapLost
from beambench.acquisition.protocol.plan import Step, step_name
from beambench.acquisition.runner import Runner
from beambench.acquisition.step_control import StepStart
from beambench.acquisition.stop_signals import StopSignal
from beambench.acquisition.streams import LOADCELL, MOCAP, MOTOR
from fake_rig import LIMITS, NS, START_NS, FakeRig, RecordingSink

STEPS = [Step(0, 5.0, 0.5, 1.0), Step(1, 10.0, 0.5, 1.0), Step(2, 15.0, 0.3, 0.7)]


def _run(rig: FakeRig, steps=STEPS, monitors=(), sinks=None, critical=True, **kw):  # type: ignore[no-untyped-def]
    sink = RecordingSink()
    others = list(sinks or [])
    hub = Hub([sink, *others], critical=(sink,) if critical else ())
    hub.open([s.describe() for s in rig.streams])
    rig.open()
    monitors = list(monitors)
    for m in monitors:
        hub.sinks.append(m)
        m.open([s.describe() for s in rig.streams])
    result = Runner(rig, hub, steps, LIMITS, poll_s=0.1, monitors=monitors, **kw).run()
    return result, sink


def test_steps_run_in_order_for_exactly_their_windows_and_every_sample_reaches_the_sinks():
    rig = FakeRig()
    result, sink = _run(rig)
    assert result.status == "completed" and result.steps_done == 3
    t = 0.0
    for step in STEPS:  # each step: commanded at its start, settled after settle_s, ended after record_s
        rec = sink.steps[step.index]
        assert rec.status == "done" and rec.frequency_hz == step.frequency_hz
        assert (rec.t_start_ns - START_NS) / NS == pytest.approx(t)
        assert (rec.t_settled_ns - rec.t_start_ns) / NS == pytest.approx(step.settle_s)
        assert (rec.t_end_ns - rec.t_settled_ns) / NS == pytest.approx(step.record_s)
        t += step.duration_s
    commands = [(round(at, 9), what, hz) for at, what, hz in rig.motor.commands]
    assert commands[:4] == [
        (0.0, "arm", 0.0),
        (0.0, "frequency", 5.0),
        (1.5, "frequency", 10.0),
        (3.0, "frequency", 15.0),
    ]
    assert commands[4][1] == "idle" and rig.calls == ["open", "close"]  # idled by the runner, then closed
    # every sample up to the end of the run, exactly once (rate × duration + the sample at t = 0)
    total = sum(s.duration_s for s in STEPS)
    for stream, rate in ((MOCAP, rig.mocap.spec.rate_hz), (LOADCELL, rig.loadcell.spec.rate_hz)):
        assert sink.rows(stream) == round(total * rate) + 1, stream
    assert sink.rows(MOTOR) == round(total * rig.motor.spec.rate_hz) + 1
    assert sink.kinds()[:2] == ["start", "armed"] and sink.kinds()[-1] == "stop" and sink.closed
    assert "idle" in sink.kinds()


def test_a_mocap_gap_pauses_the_record_window_and_the_step_records_that_much_longer():
    """Mocap silent from 0.8 s to 1.3 s of rig time (inside step 0's record window, 0.5-1.5 s): the monitor
    (0.2 s timeout) pauses the window when the gap exceeds the timeout and resumes with the first frame; the
    window's clock stops meanwhile, and the polls that counted bad data before the pause are taken back."""
    rig = FakeRig(mocap={"silent": [(0.8, 1.3)]})
    result, sink = _run(rig, steps=[Step(0, 5.0, 0.5, 1.0)], monitors=[MocapLost(0.2)])
    assert result.status == "completed"
    kinds = sink.kinds()
    assert kinds.count("pause") == 1 and kinds.count("resume") == 1
    paused = next(t for k, t, _ in sink.events if k == "pause")
    resumed = next(t for k, t, _ in sink.events if k == "resume")
    frame_s = 1 / rig.mocap.spec.rate_hz  # the last frame came one period before the gap
    assert 0.8 - frame_s + 0.2 < paused <= 0.8 + 0.2 + 0.1 + 1e-9  # the first poll that sees a gap over the timeout
    assert 1.3 <= resumed <= 1.3 + 0.1 + 1e-9  # the first poll with good data again
    rec = sink.steps[0]
    recorded_s = (rec.t_end_ns - rec.t_settled_ns) / NS
    # 1 s of good data: the window ran 1 s plus the bad stretch (0.8 s → resumed), to poll granularity
    assert recorded_s == pytest.approx(1.0 + (resumed - 0.8), abs=0.1 + 1e-9)
    assert recorded_s > 1.0 + 0.5


def test_steps_are_counted_from_1_in_words_with_their_index_beside_them():
    """One numbering wherever a person reads a step: the run's events (step, pause, resume) and the live step panel
    count from 1 (``step 2 of 3``) and show the plan's index (``index 1``, as ``/steps`` and steps.csv hold it)."""
    rig = FakeRig(mocap={"silent": [(2.3, 2.8)]})  # inside step 2's record window (2.0-3.0 s)
    result, sink = _run(rig, monitors=[MocapLost(0.2)])
    assert result.status == "completed"
    said = [(k, m) for k, _, m in sink.events if k in ("step", "pause", "resume")]
    assert [m for k, m in said if k == "step"] == [
        "step 1 of 3 (index 0): 5 Hz",
        "step 2 of 3 (index 1): 10 Hz",
        "step 3 of 3 (index 2): 15 Hz",
    ]
    assert [m.split(":")[0] for k, m in said if k in ("pause", "resume")] == ["step 2 of 3 (index 1)"] * 2
    assert step_name(49, 80, "Step") == "Step 50 of 80 (index 49)"  # the live panel's heading (sinks/viewer/step.py)
    assert step_name(4, None, "segment") == "segment 5 (index 4)"


def test_a_pause_longer_than_the_limit_stops_the_run_as_a_fault_with_the_motor_idled():
    rig = FakeRig(mocap={"silent": [(0.7, 99.0)]})
    result, sink = _run(
        rig, steps=[Step(0, 5.0, 0.5, 1.0), Step(1, 6.0, 0.5, 1.0)], monitors=[MocapLost(0.2)], max_pause_s=1.0
    )
    assert result.status == "fault" and "max_pause_s" in result.message and result.steps_done == 0
    assert sink.steps[0].status == "fault" and 1 not in sink.steps
    stopped_at = (sink.steps[0].t_end_ns - START_NS) / NS
    assert 0.7 + 0.2 + 1.0 < stopped_at <= 0.7 + 0.2 + 1.0 + 0.3  # timeout, then the pause limit, in polls
    idle_at = next(at for at, what, _ in rig.motor.commands if what == "idle")
    assert idle_at == pytest.approx(stopped_at) and rig.calls[-1] == "close"


def test_a_device_fault_mid_step_idles_the_motor_and_marks_the_step():
    rig = FakeRig(motor_fault_at_s=2.05)  # during step 1's settle window (1.5-2.0 s is settle: 2.05 is record)
    result, sink = _run(rig)
    assert result.status == "fault" and "failed at 2.05 s" in result.message and result.steps_done == 1
    assert sink.steps[0].status == "done" and sink.steps[1].status == "fault" and 2 not in sink.steps
    assert (sink.steps[1].t_end_ns - START_NS) / NS == pytest.approx(2.1)  # the poll that found it
    whats = [what for _, what, _ in rig.motor.commands]
    assert whats[-2:] == ["idle", "idle"]  # the runner's idle, then the rig's on close
    assert sink.kinds()[-1] == "fault"


def test_a_critical_sink_that_fails_stops_the_run_and_a_viewer_that_fails_does_not():
    class BrokenViewer(RecordingSink):
        label = "viewer"

        def write(self, batch):  # type: ignore[no-untyped-def]
            raise RuntimeError("viewer gone")

    rig = FakeRig()
    result, sink = _run(rig, sinks=[BrokenViewer()])
    assert result.status == "completed" and len(sink.steps) == 3  # the viewer dropped, the run went on
    rig = FakeRig()
    failing = RecordingSink(fail_on=lambda b: (b.host_time_ns[-1] - START_NS) / NS > 2.0)
    hub = Hub([failing], critical=(failing,))
    hub.open([s.describe() for s in rig.streams])
    rig.open()
    result = Runner(rig, hub, STEPS, LIMITS, poll_s=0.1).run()
    assert result.status == "failed" and "no space left on device" in result.message
    assert failing.steps[1].status == "failed" and rig.motor.commands[-2][1] == "idle" and failing.closed


def test_a_stop_request_between_polls_interrupts_the_run_at_the_next_poll():
    stop = StopSignal()
    rig = FakeRig()

    def progress(index: int, hz: float, waited: float) -> None:
        if index == 1 and rig.clock.now_ns() - START_NS >= 2.2 * NS:
            stop.request()

    result, sink = _run(rig, stop=stop, on_progress=progress)
    assert result.status == "interrupted" and result.steps_done == 1
    assert sink.steps[1].status == "aborted"
    assert (sink.steps[1].t_end_ns - START_NS) / NS == pytest.approx(2.2)  # no poll after the request
    assert [w for _, w, _ in rig.motor.commands].count("frequency") == 2


class Ramp:
    """A closed-loop step control for the test: each poll 1 Hz more than the last, up to the step's frequency; a
    step above 12 Hz is refused before anything moves."""

    closed_loop = True

    def __init__(self) -> None:
        self.hz = 0.0
        self.ticks: list[tuple[int, float]] = []

    def check(self, steps: list[Step], limits: MotorLimits) -> None:
        from beambench.acquisition.capabilities import DeviceFault

        for s in steps:
            if s.frequency_hz > 12.0:
                raise DeviceFault(f"step {s.index}: {s.frequency_hz:g} Hz is more than this control drives")

    def start(self, step: Step, now_ns: int) -> StepStart:
        return StepStart(step.frequency_hz, None, f"ramp to {step.frequency_hz:g} Hz")

    def tick(self, step: Step, now_ns: int) -> float:
        self.hz = min(self.hz + 1.0, step.frequency_hz)
        self.ticks.append((now_ns, self.hz))
        return self.hz


def test_a_step_control_chooses_the_frequency_after_every_poll_and_only_changes_are_commanded():
    """Speed tracking's shape: the ordinary runner asks its step control after every poll of the settle and record
    windows; a step's start commands nothing when the control says so; nothing is scheduled ahead."""
    rig = FakeRig()
    control = Ramp()
    steps = [Step(0, 3.0, 0.2, 0.3), Step(1, 5.0, 0.2, 0.3)]
    result, sink = _run(rig, steps=steps, control=control)
    assert result.status == "completed" and result.steps_done == 2
    assert [round((t - START_NS) / NS, 9) for t, _ in control.ticks] == pytest.approx([0.1 * k for k in range(1, 11)])
    frequencies = [(round(at, 9), hz) for at, what, hz in rig.motor.commands if what == "frequency"]
    assert frequencies == [(0.1, 1.0), (0.2, 2.0), (0.3, 3.0), (0.6, 4.0), (0.7, 5.0)]  # held ticks: no command
    assert sink.steps[1].frequency_hz == 5.0 and "ramp to 5 Hz" in [m for _, _, m in sink.events]
    runner = Runner(rig, Hub([]), steps, LIMITS, control=control)
    assert runner.schedule() == []


def test_a_step_its_control_refuses_stops_the_run_before_the_motor_is_armed():
    rig = FakeRig()
    result, sink = _run(rig, steps=[Step(0, 5.0, 0.2, 0.3), Step(1, 15.0, 0.2, 0.3)], control=Ramp())
    assert result.status == "fault" and "step 1: 15 Hz is more than this control drives" in result.message
    assert [what for _, what, _ in rig.motor.commands] == ["idle", "idle"] and not sink.steps


def test_a_step_that_ran_to_its_end_stays_done_when_a_sink_fails_on_its_row():
    """The critical sink fails writing step 0's ``done`` row (a full disk): the run stops there, motor idle, and
    the step keeps its ``done`` (its windows ran whole); the shutdown does not close it again as ``failed``."""

    class FailsOnTheDoneRow(RecordingSink):
        def step(self, record):  # type: ignore[no-untyped-def]
            super().step(record)
            if record.status == "done":
                raise OSError("no space left on device")

    rig = FakeRig()
    sink = FailsOnTheDoneRow()
    hub = Hub([sink], critical=(sink,))
    hub.open([s.describe() for s in rig.streams])
    rig.open()
    result = Runner(rig, hub, STEPS, LIMITS, poll_s=0.1).run()
    assert result.status == "failed" and "no space left on device" in result.message
    assert list(sink.steps) == [0] and sink.steps[0].status == "done", sink.steps
    assert sink.steps[0].t_end_ns is not None and rig.motor.commands[-2][1] == "idle" and sink.closed


@pytest.mark.parametrize("limited", [True, False], ids=["memory-limited", "no-limit"])
def test_an_extension_error_left_unset_is_out_of_memory_only_under_a_memory_limit(limited):
    """Under an address-space limit numpy can fail an allocation without setting its error ("SystemError: error
    return without exception set", seen in the mocap decode): the run ends as out of memory with the motor idled,
    as the command line says it. Without a limit the same error is a bug: raised, after the motor is idled."""
    import resource

    from beambench.common.unfinished import left_unfinished

    rig = FakeRig()
    read = rig.mocap.read

    def read_until_it_breaks():  # type: ignore[no-untyped-def]
        if rig.clock.now_ns() - START_NS >= 1.2 * NS:
            raise SystemError("error return without exception set")
        return read()

    rig.mocap.read = read_until_it_breaks  # type: ignore[method-assign]
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if limited:  # a limit far above anything this process maps: only its presence matters
        resource.setrlimit(resource.RLIMIT_AS, (1 << 44 if hard == resource.RLIM_INFINITY else hard, hard))
    try:
        if limited:
            result, sink = _run(rig)
            assert result.status == "error" and "out of memory" in result.message, result
            assert "without exception set" in result.message and sink.steps[0].status != "done"
            assert "memory: the process ran out of it" in left_unfinished()  # the command line ends past exit handlers
        else:
            with pytest.raises(SystemError):
                _run(rig)
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    idle_at = next(at for at, what, _ in rig.motor.commands if what == "idle")
    assert idle_at == pytest.approx(1.2, abs=0.11)  # the poll that hit it
