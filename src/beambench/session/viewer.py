"""The real Rerun viewer, started headless for pictures: open an ``.rrd``, read its state, take screenshots.

``rerun --headless`` runs the native viewer (the same UI and renderer) without an OS window, so it needs no
display and no Xvfb; it needs a Vulkan adapter: a GPU, or on a machine without one Mesa's software rasteriser
lavapipe (Debian: ``apt-get install mesa-vulkan-drivers libvulkan1``). It is controlled through Rerun's
``ViewerClient`` (state, blueprint, time cursor, screenshots of the window or of one view).
"""

from __future__ import annotations

import os
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from beambench.common.vulkan import vulkan_devices
from beambench.sinks.viewer.spawn import LOOPBACK, rerun_binary, viewer_reason

LAVAPIPE_ICD = Path("/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")
WINDOW = (1600, 900)
START_TIMEOUT_S = 30.0
LOAD_TIMEOUT_S = 60.0
SETTLE_TIMEOUT_S = 20.0
SETTLE_PAUSE_S = 0.3


class ViewerUnavailable(RuntimeError):
    """The viewer cannot run here (no binary, no Vulkan adapter); the message says what is missing."""


def vulkan_available() -> bool:
    """Whether the Vulkan loader finds a device to render with (lavapipe counts): asked of the loader, wherever
    it and its drivers are installed (:func:`beambench.common.vulkan.vulkan_devices`)."""
    return vulkan_devices().usable


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _startable_viewer() -> Path:
    """The viewer binary, once this machine can run it headless; else :class:`ViewerUnavailable` saying why."""
    binary = rerun_binary()
    if binary is None:
        raise ViewerUnavailable("the rerun viewer binary was not found (it ships with the rerun-sdk wheel)")
    vulkan = vulkan_devices()
    if not vulkan.usable:
        raise ViewerUnavailable(
            f"the Rerun viewer needs a Vulkan driver: {vulkan.error}; on Debian/Ubuntu `apt-get install "
            "mesa-vulkan-drivers libvulkan1` (Mesa's software renderer; no GPU or display needed)"
        )
    return binary


class HeadlessViewer:
    """``with HeadlessViewer() as v: v.open(rrd); v.screenshot(png, at=140)`` — one viewer process, ended on
    exit."""

    def __init__(self, rrd: Path | None = None, window: tuple[int, int] = WINDOW) -> None:
        self.rrd, self.window = rrd, window
        self.port = _free_port()
        self._proc: subprocess.Popen[bytes] | None = None
        self._log: Any = None
        self._tmp = tempfile.TemporaryDirectory(prefix="beambench-viewer-")
        self.client: Any = None

    def __enter__(self) -> HeadlessViewer:
        try:
            self._start()
        except BaseException:
            self.__exit__(None, None, None)  # undo what started: the process, its log, the temporary folder
            raise
        return self

    def _start(self) -> None:
        binary = _startable_viewer()
        # RUST_LOG: the viewer shows its info and warning log lines as toasts over the views (in screenshots too)
        env = dict(os.environ, XDG_RUNTIME_DIR=self._tmp.name, MESA_VK_WSI_DEBUG="noshm", RUST_LOG="error")
        if "VK_ICD_FILENAMES" not in env and LAVAPIPE_ICD.exists() and not Path("/dev/dri").exists():
            env["VK_ICD_FILENAMES"] = str(LAVAPIPE_ICD)  # no GPU: the software rasteriser, not a search of all
        os.chmod(self._tmp.name, 0o700)
        args = [str(binary), "--headless", "--bind", LOOPBACK, "--port", str(self.port), "--hide-welcome-screen"]
        args += ["--window-size", f"{self.window[0]}x{self.window[1]}", "--renderer", "vulkan"]
        if self.rrd is not None:  # loaded whole (``open`` registers a file and fetches its chunks on demand)
            args.append(str(self.rrd))
        self._log = open(Path(self._tmp.name) / "viewer.log", "wb")  # noqa: SIM115 (closed in __exit__)
        self._proc = subprocess.Popen(args, env=env, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)
        self._connect()

    def _connect(self) -> None:
        from rerun.experimental import ViewerClient

        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if self._proc is not None and self._proc.poll() is not None:
                raise ViewerUnavailable(
                    f"the Rerun viewer exited at start: {self._last_log_line()} (it needs a working Vulkan driver)"
                )
            try:
                self.client = ViewerClient(f"rerun+http://127.0.0.1:{self.port}/proxy")
                self.client.get_state()
                return
            except Exception as exc:
                if time.monotonic() > deadline:
                    raise ViewerUnavailable(
                        f"the Rerun viewer did not answer in {START_TIMEOUT_S:g} s ({exc})"
                    ) from exc
                time.sleep(0.2)

    def _last_log_line(self) -> str:
        """The viewer's reason: its panic line if it panicked, else its last line of output."""
        return viewer_reason((Path(self._tmp.name) / "viewer.log").read_bytes()) or "no output"

    def open(self, rrd: Path | None = None) -> Any:
        """Open a recording (None: the one given at start); wait until it is loaded and its views exist.
        Returns the viewer's state."""
        if rrd is not None:
            self.client.open(str(rrd))
        deadline = time.monotonic() + LOAD_TIMEOUT_S
        while True:
            state = self.client.get_state()
            if not state.loading and state.views and state.recordings:
                return state
            if time.monotonic() > deadline:
                raise ViewerUnavailable(f"{rrd or self.rrd}: the viewer did not finish loading in {LOAD_TIMEOUT_S:g} s")
            time.sleep(0.2)

    def screenshot(self, path: Path, at: float | None = None, view_id: str | None = None) -> bytes:
        """A PNG of the window (or of one view) with the time cursor at ``at`` seconds, paused, written to
        ``path`` and returned: taken once two frames in a row are the same (the viewer fetches and draws the
        data around a new cursor over a few frames)."""
        if at is not None:
            self.client.set_time("session_time", duration=float(at), play_state="paused")
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        png = self.client.take_screenshot(view_id=view_id)
        while time.monotonic() < deadline:
            time.sleep(SETTLE_PAUSE_S)
            again = self.client.take_screenshot(view_id=view_id)
            if again == png:
                break
            png = again
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(png)
        return bytes(png)

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(timeout=5)
        self._proc = None
        if self._log is not None:
            self._log.close()
        self._tmp.cleanup()


def session_screenshot(session: Path, png: Path, at: float | None = None, rrd: Path | None = None) -> float:
    """Replay ``session`` into an ``.rrd`` (``rrd``, else a temporary one), open it in the headless viewer and
    save a picture of the window at ``at`` seconds of session time (default: the end of the first step).
    Returns the time shown. Raises :class:`ViewerUnavailable` (what is missing) or ``ValueError`` (``at``
    outside the session)."""
    from beambench.session.replay import replay_session
    from beambench.sinks.session_file.reader import read_session

    steps = read_session(session).steps
    t0 = int(steps["t_start_ns"].min()) if len(steps) else 0
    end_s = (int(steps["t_end_ns"].max()) - t0) * 1e-9 if len(steps) else 0.0
    if at is None:
        at = (int(steps["t_end_ns"].iloc[0]) - t0) * 1e-9 if len(steps) else 0.0
    if not 0.0 <= at <= max(end_s, 0.0) + 1.0:
        raise ValueError(f"--at {at:g} s is outside the session (0 to {end_s:g} s)")
    with HeadlessViewer():  # fail in a second, not after the replay, where the viewer cannot run
        pass
    with tempfile.TemporaryDirectory(prefix="beambench-view-") as tmp:
        path = rrd or Path(tmp) / f"{session.stem}.rrd"
        replay_session(session, "save", path)
        with HeadlessViewer(path) as viewer:
            viewer.open()
            viewer.screenshot(png, at=at)
    return at
