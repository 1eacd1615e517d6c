"""A protocol as a plan: the pure list of steps a run will execute, and its dry-run summary (no I/O)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from beambench.acquisition.capabilities import MotorLimits
from beambench.acquisition.protocol.schema import ConfigError, Protocol, format_name
from beambench.common.names import check_name


@dataclass(frozen=True)
class Step:
    """Drive at ``frequency_hz``: wait ``settle_s`` for transients to decay, then record ``record_s``.

    ``direction``: the sweep branch (``up``/``down``); ``kind``: ``sweep`` or ``reference``; ``repeat``: which pass
    of this frequency and branch it is (0, 1, …; for reference steps, the reference's count)."""

    index: int
    frequency_hz: float
    settle_s: float
    record_s: float
    direction: str = "up"
    kind: str = "sweep"
    repeat: int = 0

    @property
    def duration_s(self) -> float:
        return self.settle_s + self.record_s


def step_name(index: int, total: int | None = None, word: str = "step") -> str:
    """A step as words name it, one convention everywhere a person reads one (events, the live step panel, the
    progress line, the report): counted from 1, with the plan's index (0-based, as ``/steps`` and ``steps.csv``
    hold it) beside it: ``step 51 of 80 (index 50)``; without ``total``: ``step 51 (index 50)``."""
    of = f" of {total}" if total else ""
    return f"{word} {index + 1}{of} (index {index})"


def _branches(protocol: Protocol) -> list[tuple[float, str]]:
    """One pass of the sweep: (frequency, direction) in order (``both``: up, then down without the turn twice)."""
    assert protocol.sweep is not None  # the model requires one without track:
    f = protocol.sweep.values()
    d = protocol.sweep.direction
    if d == "down":
        return [(x, "down") for x in reversed(f)]
    up = [(x, "up") for x in f]
    return up + [(x, "down") for x in reversed(f[:-1])] if d == "both" else up


def _sweep_steps(protocol: Protocol) -> list[tuple[float, str, int]]:
    """(frequency, direction, repeat) of every sweep step, the repeats interleaved or in blocks."""
    assert protocol.sweep is not None
    one, k = _branches(protocol), protocol.sweep.repeats
    if protocol.sweep.repeat_order == "blocks":
        return [(f, d, r) for f, d in one for r in range(k)]
    return [(f, d, r) for r in range(k) for f, d in one]


def plan(protocol: Protocol) -> list[Step]:
    """The steps of a protocol, in order: the sweep (direction, repeats) with reference steps first, after every
    ``reference.every_steps`` sweep steps, and last. With ``track:`` one step per segment: its frequency (0 here) is
    chosen by the speed controller during the run, the settle window is ``track.settle_s``, the record window the
    rest."""
    if protocol.track is not None:
        settle = protocol.track.settle_s
        return [Step(i, 0.0, settle, seg.hold_s - settle) for i, seg in enumerate(protocol.track.segments)]
    ref = protocol.reference
    out: list[tuple[float, str, str, int]] = []
    n_ref = 0
    sweep = _sweep_steps(protocol)
    for j, (f, d, r) in enumerate(sweep):
        if ref is not None and j % ref.every_steps == 0:
            out.append((ref.frequency_hz, d, "reference", n_ref))
            n_ref += 1
        out.append((f, d, "sweep", r))
    if ref is not None:
        out.append((ref.frequency_hz, sweep[-1][1], "reference", n_ref))
    return [Step(i, f, protocol.settle_s, protocol.record_s, d, kind, r) for i, (f, d, kind, r) in enumerate(out)]


def motor_limits(protocol: Protocol) -> MotorLimits:
    return MotorLimits(
        max_frequency_hz=protocol.limits.max_frequency_hz,
        max_current_a=protocol.limits.max_current_a,
        amplitude_mm=protocol.amplitude_mm,
    )


def check_limits(protocol: Protocol, file: str = "<protocol>") -> None:
    """Raise :class:`ConfigError` for the first commanded value over a limit; called before anything moves."""
    for field, value, reason in protocol.limit_violations():
        raise ConfigError(file, field, value, reason)


def summary(protocol: Protocol, backend: str) -> dict[str, object]:
    """What a dry run prints: steps, total duration, max frequency and limits."""
    steps = plan(protocol)
    freqs = [s.frequency_hz for s in steps]
    return {
        "protocol": protocol.name,
        "rig": protocol.rig,
        "backend": backend,
        "steps": len(steps),
        "frequencies_hz": freqs,
        "directions": [s.direction for s in steps],
        "reference_steps": sum(s.kind == "reference" for s in steps),
        "settle_s": protocol.track.settle_s if protocol.track else protocol.settle_s,
        "record_s": protocol.record_s,
        "total_duration_s": sum(s.duration_s for s in steps),
        "max_frequency_hz": max(freqs),
        "amplitude_mm": protocol.amplitude_mm,
        "release_load_g": protocol.release.load_g,
        "limits": protocol.limits.model_dump(),
        "targets_mm_s": [seg.speed_mm_s for seg in protocol.track.segments] if protocol.track else None,
    }


def session_path(
    protocol: Protocol, backend: str, out_dir: Path, name: str | None = None, now: datetime | None = None
) -> Path:
    """``<out>/<name>.h5`` from ``--name`` or the protocol's template; never an existing file.

    The name is checked (no control characters or NUL, no path separators, <= 200 bytes, not ``.``/``..``) and
    ``out_dir`` must be a folder (or creatable). The file itself is created exclusively by the session writer,
    so even a race cannot overwrite a session.
    """
    now = now or datetime.now()
    field = "--name"
    if name is None:
        field = "output.name"
        try:
            name = format_name(
                protocol.output.name, protocol.name, protocol.rig, backend, now.strftime("%Y%m%d-%H%M%S")
            )
        except ValueError as exc:
            raise ConfigError("<protocol>", field, protocol.output.name, str(exc)) from None
    name = name.removesuffix(".h5")
    try:
        check_name(name, "the session name")
        check_name(name + "_99999.rrd", "the session name")  # room for the suffixes added below
    except ValueError as exc:
        raise ConfigError("<cli>" if field == "--name" else "<protocol>", field, name, str(exc)) from None
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError("<cli>", "--out", str(out_dir), "is a file, not a folder")
    existing = next((p for p in (out_dir, *out_dir.absolute().parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise ConfigError("<cli>", "--out", str(out_dir), f"{existing} is a file, not a folder")
    if existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        raise ConfigError("<cli>", "--out", str(out_dir), f"cannot write in {existing} (permission denied)")
    path = out_dir / f"{name}.h5"
    k = 1
    while os.path.lexists(path) or os.path.lexists(path.with_suffix(".rrd")):  # a dangling symlink is taken too
        path = out_dir / f"{name}_{k}.h5"
        k += 1
        if k > 99999:
            raise ConfigError("<cli>", field, name, "too many sessions of that name in --out")
    return path
