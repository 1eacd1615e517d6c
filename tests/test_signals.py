"""Every stop signal stops a run: at random moments, many times, from a Python parent process, on the sim and
the emulated backend — SIGINT, SIGTERM, SIGHUP (a closed terminal), SIGQUIT and the others the runner takes
(:data:`beambench.acquisition.stop_signals.STOP_SIGNALS`).

A signal handler only sets a flag; the runner acts on it at its next poll, idles the motor, then saves. Every
interrupted run must exit 3 (EXIT_STOPPED) without a traceback and with one line on stderr naming the signal, leave
a cleanly closed session (it opens without SWMR) whose last event is ``interrupted`` after an ``idle``, whose last
step is not ``running``, and whose motor telemetry ends at setpoint 0. On the emulated backend also: the last
Set_Axis_State on the CAN bus (``--can-log``) requests IDLE, the emulated ODrive's last heartbeat says IDLE, and
``/general/devices`` holds the drivers' counters.

The default run makes one run per signal on the sim and one each of SIGINT, SIGTERM and SIGHUP on the emulated rig;
the soak tier (``pytest --soak``, ``make soak``, CI) the other 24 at other random moments.
``BEAMBENCH_SIGNAL_RUNS`` multiplies the number of runs of both (soak loops run it at 5-10).

Starting ``python -m beambench.cli`` costs seconds of imports per run, so most runs are forked from a "zygote"
process that imported beambench once: each child is ``beambench.cli.main()`` with the run's argv and Python's
default SIGINT behaviour (``KeyboardInterrupt``), exactly what a fresh interpreter has. A few runs use plain
``subprocess.Popen`` of ``python -m beambench.cli run`` as a cross-check (and on the emulated backend).
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import threading
from collections.abc import Iterator
from pathlib import Path

import h5py
import pytest

from beambench.acquisition.stop_signals import signal_name
from beambench.sinks.session_file.reader import read_session
from conftest import last_requested_state, pause, random_moment, wait_until

# Long enough that no run can finish before its signal (200 steps x 0.5 s of rig time).
ENDLESS = """
name: endless
sweep: {start: 2, stop: 40, step: 0.19}
settle_s: 0.2
record_s: 0.3
sim: {seed: 5}
"""

ZYGOTE = textwrap.dedent(
    """
    import json, os, signal, sys
    import beambench.cli, beambench.session.run  # the expensive imports, once
    import beambench.backends.sim, beambench.backends.emulated  # (what a run imports on first use)
    for line in sys.stdin:
        req = json.loads(line)
        pid = os.fork()
        if pid == 0:
            from beambench.acquisition.stop_signals import STOP_SIGNALS
            for s in STOP_SIGNALS:  # as in a fresh interpreter started from a terminal (whatever started pytest)
                signal.signal(s, signal.SIG_DFL)
            signal.signal(signal.SIGINT, signal.default_int_handler)
            fd = os.open(req["log"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
            os.dup2(fd, 1); os.dup2(fd, 2)
            sys.argv = ["beambench", *req["argv"]]
            code = 1
            try:
                beambench.cli.main()
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 1
            except BaseException:
                import traceback; traceback.print_exc(); code = 99
            sys.stdout.flush(); sys.stderr.flush()
            os._exit(code)
        print(json.dumps({"pid": pid}), flush=True)
        _, status = os.waitpid(pid, 0)
        print(json.dumps({"status": os.waitstatus_to_exitcode(status)}), flush=True)
    """
)


def _env() -> dict[str, str]:
    src = str(Path(__file__).resolve().parents[1] / "src")
    return dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=os.environ.get("PYTHONPATH") or src)


def _wait_for_file(path: Path, alive, timeout: float = 60.0) -> None:
    """Wait until ``path`` exists; fail at once if the process that writes it (``alive``) is gone."""
    wait_until(lambda: path.exists() or not alive(), timeout, f"{path}")
    assert path.exists(), f"{path} never appeared"


# The lanes of _signal_runs check their files from three threads of this process. One CI run (h5py 3.16,
# HDF5 2.0) had an h5py id freed during another HDF5 call ("Can't get property list (no VOL object wrap
# context?)" in ObjectID.__dealloc__), after which every HDF5 call of the process failed; not reproduced by
# three threads reading sessions (240 s, and 90 s with frequent cyclic GC). The product uses h5py from one thread; the
# harness now does too: one lane at a time, with cyclic GC paused while it reads.
_H5_LANE = threading.Lock()


@contextlib.contextmanager
def _one_h5py_reader() -> Iterator[None]:
    with _H5_LANE:
        was = gc.isenabled()
        gc.disable()
        try:
            yield
        finally:
            if was:
                gc.enable()


SCALE = max(1, int(os.environ.get("BEAMBENCH_SIGNAL_RUNS", "1")))


def _check_interrupted(
    path: Path, code: int, log: str, motor_state_idle: bool = False, sig: int | None = None, can_log: Path | None = None
) -> None:
    assert code == 3, f"exit {code}: {log[-2000:]}"
    assert "Traceback" not in log and "Exception ignored" not in log, log[-2000:]
    said = [line for line in log.replace("\r", "\n").splitlines() if "beambench:" in line]
    assert len(said) == 1 and "run interrupted" in said[0], log[-2000:]
    if sig is not None:
        assert signal_name(sig) in said[0], said
    with h5py.File(path, "r"):  # a plain (non-SWMR) open works only on a cleanly closed file
        pass
    s = read_session(path)
    kinds = list(s.events["kind"])
    assert kinds[-1] == "interrupted", kinds
    assert "idle" in kinds[:-1], kinds
    if len(s.steps):
        assert s.steps["status"].iloc[-1] != "running", s.steps
    motor = s.streams["motor"]
    if len(motor):
        assert motor.columns["velocity_setpoint"][-1] == 0.0
        if motor_state_idle:
            assert motor.columns["axis_state"][-1] == 1  # ODrive AXIS_STATE_IDLE
    if motor_state_idle:  # the emulated rig: its drivers' counters, and the bus itself
        assert "devices" in kinds and "motor" in s.general.get("devices", {}), (kinds, list(s.general))
    if can_log is not None:
        assert last_requested_state(can_log) in (None, 1), "the last Set_Axis_State did not request IDLE"


class Zygote:
    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-c", ZYGOTE],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=_env(),
            start_new_session=True,
        )

    def run(self, argv: list[str], log: Path) -> int:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"argv": argv, "log": str(log)}) + "\n")
        self.proc.stdin.flush()
        return int(json.loads(self.proc.stdout.readline())["pid"])

    def status(self) -> int:
        assert self.proc.stdout is not None
        return json.loads(self.proc.stdout.readline())["status"]

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait(timeout=30)
        if self.proc.stdout:
            self.proc.stdout.close()


def _default_dispositions() -> None:
    from beambench.acquisition.stop_signals import STOP_SIGNALS

    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_DFL)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


class Zygotes:
    """One zygote per lane, started on first use and kept for every test of this module in this worker: starting
    one costs the imports (~1.7 s of CPU), and 13 signals x up to 3 lanes started 28 of them. A zygote only forks:
    each run still starts from the same freshly imported state."""

    def __init__(self) -> None:
        self._lanes: dict[int, Zygote] = {}
        self._lock = threading.Lock()

    def lane(self, k: int) -> Zygote:
        with self._lock:
            if k not in self._lanes:
                self._lanes[k] = Zygote()
            return self._lanes[k]

    def close(self) -> None:
        for z in self._lanes.values():
            z.close()


@pytest.fixture(scope="module")
def zygotes() -> Iterator[Zygotes]:
    pool = Zygotes()
    yield pool
    pool.close()


def _signal_runs(
    tmp_path: Path, zygotes: Zygotes, sig: int, n: int, seed: int, lanes: int = 3, backend: str = "sim"
) -> list[str]:
    """``n`` runs, each sent ``sig`` once at a random moment after its session file appears; failures listed."""
    emulated = backend == "emulated"
    proto = tmp_path / "endless.yaml"
    proto.write_text(ENDLESS)
    rng = random.Random(seed)
    delays = [rng.choice([0.0, rng.uniform(0, 0.3), rng.uniform(0, 1.0)]) for _ in range(n)]
    doubles = [rng.random() < 0.3 for _ in range(n)]  # a second signal right after the first (during shutdown)
    failures: list[str] = []

    def lane(k: int) -> None:
        z = zygotes.lane(k)
        for i in range(k, n, lanes):
            name = f"r{i}"
            path, log = tmp_path / f"{name}.h5", tmp_path / f"{name}.log"
            argv = ["run", str(proto), "--out", str(tmp_path), "--name", name, "--rerun", "off", "-b", backend]
            can_log = tmp_path / f"{name}.asc" if emulated else None
            if can_log is not None:
                argv += ["--can-log", str(can_log)]
            pid = z.run(argv, log)
            status_read = False
            try:
                _wait_for_file(path, lambda pid=pid: _pid_alive(pid))
                pause(delays[i], "the random moment the signal is sent at")
                os.kill(pid, sig)
                if doubles[i]:
                    random_moment(rng, 0, 0.05, "the second signal's moment, during the shutdown")
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, sig)
                code = z.status()
                status_read = True
                with _one_h5py_reader():
                    _check_interrupted(path, code, log.read_text(), emulated, sig, can_log)
            except Exception as exc:  # collect every failure, so one report shows how many failed
                failures.append(f"run {i} (delay {delays[i]:.2f} s, double={doubles[i]}): {exc}")
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
                if not status_read:
                    code = z.status()
                    failures[-1] += f" [exit {code}: {log.read_text()[-300:] if log.exists() else ''}]"

    threads = [threading.Thread(target=lane, args=(k,)) for k in range(lanes)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return failures


def _sig(name: str) -> int:
    if name.startswith("SIGRTMIN+"):
        return int(signal.SIGRTMIN) + int(name.split("+")[1])
    return int(getattr(signal, name))


# (signal, runs on the sim, runs on the emulated backend): the hang-up and quit signals as often as
# SIGINT/SIGTERM, the rarer ones a few times each. The default run makes the first run of each signal on the sim and
# of EMULATED_DEFAULT on the emulated rig; the soak tier (--soak, CI) the others, at other random moments.
SIGNAL_RUNS = [
    ("SIGINT", 6, 1),
    ("SIGTERM", 6, 1),
    ("SIGHUP", 6, 2),
    ("SIGQUIT", 6, 2),
    ("SIGUSR1", 1, 1),
    ("SIGUSR2", 1, 0),
    ("SIGALRM", 1, 0),
    ("SIGXCPU", 1, 0),
    ("SIGVTALRM", 1, 0),
    ("SIGPROF", 1, 0),
    ("SIGIO", 1, 0),
    ("SIGPWR", 1, 0),
    ("SIGRTMIN+3", 1, 0),
]
# the emulated ODrive in the default run: Ctrl-C, kill's default and a closed terminal (the others run on the sim
# there, and on the emulated rig in the soak tier)
EMULATED_DEFAULT = ("SIGINT", "SIGTERM", "SIGHUP")
SIM_FIRST = [(name, 1) for name, sim, _ in SIGNAL_RUNS if sim]
SIM_MORE = [(name, sim - 1) for name, sim, _ in SIGNAL_RUNS if sim > 1]
EMULATED_FIRST = [(name, 1) for name, _, emulated in SIGNAL_RUNS if emulated and name in EMULATED_DEFAULT]
EMULATED_MORE = [
    (name, emulated - (name in EMULATED_DEFAULT))
    for name, _, emulated in SIGNAL_RUNS
    if emulated - (name in EMULATED_DEFAULT) > 0
]


def _ids(runs: list[tuple[str, int]]) -> list[str]:
    return [name for name, _ in runs]


def _assert_runs(tmp_path: Path, zygotes: Zygotes, name: str, n: int, seed: int, backend: str = "sim") -> None:
    sig, n = _sig(name), n * SCALE
    lanes = min(3 if backend == "sim" else 2, n)
    failures = _signal_runs(tmp_path, zygotes, sig, n, seed=sig * 1000 + seed, lanes=lanes, backend=backend)
    assert not failures, f"{len(failures)} of {n} runs not stopped cleanly:\n" + "\n".join(failures)


@pytest.mark.slow
@pytest.mark.parametrize(("name", "n"), SIM_FIRST, ids=_ids(SIM_FIRST))
def test_every_signal_at_a_random_moment_stops_the_run_idles_and_saves(tmp_path, zygotes, name, n):
    _assert_runs(tmp_path, zygotes, name, n, seed=13)


@pytest.mark.soak
@pytest.mark.parametrize(("name", "n"), SIM_MORE, ids=_ids(SIM_MORE))
def test_every_signal_at_more_random_moments_stops_the_run_idles_and_saves(tmp_path, zygotes, name, n):
    _assert_runs(tmp_path, zygotes, name, n, seed=14)


@pytest.mark.slow
@pytest.mark.parametrize(("name", "n"), EMULATED_FIRST, ids=_ids(EMULATED_FIRST))
def test_every_signal_on_the_emulated_rig_leaves_the_odrive_idle(tmp_path, zygotes, name, n):
    _assert_runs(tmp_path, zygotes, name, n, seed=17, backend="emulated")


@pytest.mark.soak
@pytest.mark.parametrize(("name", "n"), EMULATED_MORE, ids=_ids(EMULATED_MORE))
def test_every_signal_at_more_moments_on_the_emulated_rig_leaves_the_odrive_idle(tmp_path, zygotes, name, n):
    _assert_runs(tmp_path, zygotes, name, n, seed=18, backend="emulated")


def test_the_runner_takes_every_signal_that_ends_a_process_by_default():
    """The list the README gives; and a signal ignored on purpose (nohup's SIGHUP) stays ignored."""
    from beambench.acquisition.stop_signals import STOP_SIGNALS, stop_on_signals

    for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGUSR1", "SIGUSR2", "SIGALRM", "SIGXCPU"):
        assert getattr(signal, name) in STOP_SIGNALS
    for name in ("SIGKILL", "SIGSTOP", "SIGSEGV", "SIGPIPE", "SIGCHLD", "SIGWINCH"):
        assert getattr(signal, name) not in STOP_SIGNALS
    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    usr1 = signal.signal(signal.SIGUSR1, signal.SIG_DFL)
    quit_before = signal.signal(signal.SIGQUIT, signal.SIG_IGN)  # as in a shell's background job: taken anyway
    try:
        with stop_on_signals() as stop:
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGQUIT) not in (signal.SIG_DFL, signal.SIG_IGN)
            os.kill(os.getpid(), signal.SIGUSR1)
            assert stop.wait(2.0) and stop.signum == signal.SIGUSR1
        assert signal.getsignal(signal.SIGQUIT) is signal.SIG_IGN  # restored
    finally:
        signal.signal(signal.SIGHUP, before)
        signal.signal(signal.SIGUSR1, usr1)
        signal.signal(signal.SIGQUIT, quit_before)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("backend", "sig"),
    [
        ("sim", signal.SIGHUP),
        ("emulated", signal.SIGINT),
        pytest.param("emulated", signal.SIGQUIT, marks=pytest.mark.soak),
    ],
    ids=["sim-SIGHUP", "emulated-SIGINT", "emulated-SIGQUIT"],
)
def test_python_m_beambench_run_stops_on_a_signal(tmp_path, backend, sig):
    """The plain interpreter (not forked): ``python -m beambench.cli run`` with SIGINT restored to its default."""
    proto = tmp_path / "endless.yaml"
    proto.write_text(ENDLESS)
    path = tmp_path / "p.h5"
    argv = ["run", str(proto), "--out", str(tmp_path), "--name", "p", "--rerun", "off", "--backend", backend]
    proc = subprocess.Popen(
        [sys.executable, "-m", "beambench.cli", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=_env(),
        start_new_session=True,
        preexec_fn=_default_dispositions,  # a shell's background job ignores SIGINT and SIGQUIT, nohup SIGHUP
    )
    try:
        _wait_for_file(path, lambda: proc.poll() is None, timeout=120)
        random_moment(random.Random(hash(backend) + sig), 0.2, 1.5, "the moment the signal is sent at")
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    _check_interrupted(
        path, proc.returncode, out.decode(errors="replace"), motor_state_idle=backend == "emulated", sig=sig
    )


# --- in-process: the flag, from any state, and a signal during the shutdown ---------------------------
def _sim_runner(tmp_path: Path, stop=None, on_progress=None):
    from beambench.acquisition.hub import Hub
    from beambench.acquisition.protocol.plan import motor_limits, plan
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.acquisition.runner import Runner
    from beambench.backends.sim import SimRig
    from beambench.session.slices import sim_slice
    from beambench.sinks.session_file.writer import SessionWriter

    protocol = parse_protocol(ENDLESS)
    rig = SimRig(sim_slice(protocol))
    rig.open()
    writer = SessionWriter(tmp_path / "s.h5", {"protocol": ENDLESS})
    hub = Hub([writer], critical=(writer,))
    hub.open([s.describe() for s in rig.streams])
    runner = Runner(rig, hub, plan(protocol), motor_limits(protocol), poll_s=0.1, stop=stop, on_progress=on_progress)
    return rig, runner


def test_a_stop_requested_before_the_run_starts_idles_and_saves(tmp_path):
    from beambench.acquisition.stop_signals import StopSignal

    stop = StopSignal()
    stop.request(signal.SIGTERM)
    _, runner = _sim_runner(tmp_path, stop=stop)
    result = runner.run()
    assert result.status == "interrupted" and "SIGTERM" in result.message
    assert result.steps_done == 0
    s = read_session(tmp_path / "s.h5")
    assert list(s.events["kind"])[-2:] == ["idle", "interrupted"]


def test_a_real_sigint_mid_step_and_another_during_the_idle_still_idle_and_save(tmp_path):
    """SIGINT from inside the run (mid settle), then a second SIGINT while the motor is being idled."""
    calls = []

    def progress(index, freq, waited):
        calls.append(index)
        if len(calls) == 7:
            os.kill(os.getpid(), signal.SIGINT)

    rig, runner = _sim_runner(tmp_path, on_progress=progress)
    idle = rig.motor.idle

    def idle_with_a_second_ctrl_c():
        count = runner.stop.count
        os.kill(os.getpid(), signal.SIGINT)  # delivered while we are inside the shutdown
        wait_until(lambda: runner.stop.count > count, what="the run's handler to take the second SIGINT")
        idle()

    rig.motor.idle = idle_with_a_second_ctrl_c
    before = signal.getsignal(signal.SIGINT)  # default_int_handler, or SIG_IGN under a shell's background job
    result = runner.run()  # no KeyboardInterrupt may escape
    assert result.status == "interrupted" and "SIGINT" in result.message
    assert runner.stop.count >= 2  # (rig.close() idles again: one more)
    assert signal.getsignal(signal.SIGINT) is before  # handlers restored
    s = read_session(tmp_path / "s.h5")
    kinds = list(s.events["kind"])
    assert kinds[-2:] == ["idle", "interrupted"]
    assert s.streams["motor"].columns["velocity_setpoint"][-1] == 0.0
    assert s.steps["status"].iloc[-1] == "aborted"
