"""The sentences at the top of a report, each derived from what the report itself shows: the contact note from the
per-step table (the rows of ``steps.csv``), the completeness banner from the session's planned steps, its step
rows and its last event.

``contact_overview(table)`` sorts the steps by what the plate saw (touchdowns, continuous contact, contact
without a counted touchdown, none); ``contact_note`` says what the contact figures cannot show when no step has a
touchdown. ``run_completeness(a)`` compares the protocol's plan with the steps recorded, and ``completeness_note``
says when a report covers only part of the run.
"""

from __future__ import annotations

import html
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import yaml

from beambench.acquisition.protocol.backends import BACKEND_INFO
from beambench.acquisition.protocol.plan import plan
from beambench.acquisition.protocol.scenes import scene_or_unknown
from beambench.acquisition.protocol.schema import parse_protocol

if TYPE_CHECKING:
    from beambench.analysis.session_analysis import SessionAnalysis


@dataclass(frozen=True)
class ContactOverview:
    """The drive frequencies (Hz) of the steps of one contact session by what the plate's normal force showed
    (``steps.csv``: ``regime``, ``n_contacts``, ``in_contact_fraction``)."""

    touchdowns: list[float]  # at least one counted touchdown (the foot left the plate and came back)
    continuous: list[float]  # on the plate throughout the record window, no lift-off
    other_contact: list[float]  # in contact at times, but no touchdown counted (irregular, cut by the window)
    none: list[float]  # never above the contact threshold
    in_contact_fraction: tuple[float, float]  # lowest and highest over the steps with contact (NaN if none)

    @property
    def n_steps(self) -> int:
        return len(self.touchdowns) + len(self.continuous) + len(self.other_contact) + len(self.none)


def contact_overview(table: pd.DataFrame) -> ContactOverview | None:
    """The steps of a contact session's per-step table by what the plate saw; None without contact columns (no
    load-cell data, another rig) or rows."""
    if "regime" not in table or "n_contacts" not in table or not len(table):
        return None
    t = table[table["regime"].fillna("").astype(str) != ""]  # rows without a record window have no regime
    if not len(t):
        return None
    f = t["frequency_hz"].astype(float) if "frequency_hz" in t else pd.Series(np.nan, index=t.index)
    regime = t["regime"].astype(str)
    touched = t["n_contacts"].fillna(0).astype(float) > 0
    cont = ~touched & (regime == "continuous")
    none = ~touched & (regime == "none")
    other = ~touched & ~cont & ~none
    frac = t["in_contact_fraction"].astype(float) if "in_contact_fraction" in t else pd.Series(np.nan, index=t.index)
    frac = frac[~none & np.isfinite(frac)]
    span = (float(frac.min()), float(frac.max())) if len(frac) else (float("nan"), float("nan"))
    return ContactOverview(sorted(f[touched]), sorted(f[cont]), sorted(f[other]), sorted(f[none]), span)


def hz_list(freqs: list[float], most: int = 6) -> str:
    """``2, 3, 4 Hz``, or ``2–8 Hz, 7 steps`` for a longer list."""
    if not freqs:
        return ""
    if len(freqs) <= most:
        return ", ".join(f"{f:g}" for f in freqs) + " Hz"
    return f"{min(freqs):g}–{max(freqs):g} Hz, {len(freqs)} steps"


def contact_note(o: ContactOverview, backend: str = "") -> str | None:
    """What the contact figures cannot show, in plain words, when no step of the session has a touchdown; None when
    some step has one (the figures then speak for themselves)."""
    if o.touchdowns or not o.n_steps:
        return None
    info = BACKEND_INFO.get(backend)
    sim = info is not None and info.simulates  # the twin's physics: its sim: options apply (sim, emulated)
    if len(o.none) == o.n_steps:
        fix = (
            " Lower <code>sim.plate_gap_mm</code> or raise <code>amplitude_mm</code> to bring the foot onto the plate."
            if sim
            else " Bring the plate closer or raise <code>amplitude_mm</code>."
        )
        return (
            "<strong>No contact anywhere:</strong> the foot never touched the plate in any step (the normal force "
            "stayed below the contact threshold), so there are no contact regimes, touchdowns or contact forces to "
            "show." + fix
        )
    lo, hi = o.in_contact_fraction
    share = f"{lo:.2f}" if lo == hi else f"{lo:.2f}–{hi:.2f}"
    if len(o.continuous) == o.n_steps:
        fix = " The paper's beam lifts off above 18 Hz" + (
            "; in the twin a larger <code>sim.plate_gap_mm</code> also lifts it off." if sim else "."
        )
        return (
            f"<strong>Continuous contact in every step</strong> ({hz_list(o.continuous)}): the foot stayed on the "
            f"plate throughout each record window (in-contact fraction {share}, steps.csv: "
            "<code>in_contact_fraction</code>) and never lifted off, so there are no touchdowns: the contact "
            "frequency is 0 and there are no touchdown directions or velocities to show. The force traces show "
            "the contact force." + fix
        )
    parts = [
        f"{name} at {hz_list(fs)}"
        for name, fs in (
            ("continuous contact", o.continuous),
            ("contact without a counted lift-off", o.other_contact),
            ("no contact", o.none),
        )
        if fs
    ]
    return (
        "<strong>No touchdown in any step:</strong> "
        + "; ".join(parts)
        + ". The contact frequency is 0 throughout and there are no touchdown directions or velocities to show."
    )


def contact_notes(analyses: list[SessionAnalysis]) -> list[str]:
    """The contact note of each session that has one (its label named when the report shows several)."""
    notes = []
    for a in analyses:
        o = contact_overview(a.table) if scene_or_unknown(a.rig).plate else None
        text = contact_note(o, a.backend) if o is not None else None
        if text:
            who = "" if len(analyses) == 1 else f"<em>{html.escape(a.label)}:</em> "
            notes.append(f"<p class='note'>{who}{text}</p>")
    return notes


# ------------------------------------------------------------------------------------------- completeness


@dataclass(frozen=True)
class RunCompleteness:
    """How much of its protocol a session holds: the planned steps' frequencies by index, the indices recorded
    to their end (status ``done``), those cut short, and the run's last event (kind and message)."""

    planned: dict[int, float]
    done: list[int]
    cut_short: list[int]
    ending_kind: str
    ending_message: str

    @property
    def missing(self) -> list[int]:
        """Planned steps with no complete record window (cut short, or never started)."""
        return sorted(set(self.planned) - set(self.done))

    @property
    def complete(self) -> bool:
        return not self.missing and self.ending_kind in ("stop", "")


def planned_steps(general: dict[str, object]) -> dict[int, float]:
    """Step index → drive frequency of the protocol stored in the session (``/general/protocol``); empty if it
    cannot be read (a track session, an older file)."""
    text = general.get("protocol")
    if not isinstance(text, str) or not text.strip():
        return {}
    try:
        steps = plan(parse_protocol(text))
    except (ValueError, TypeError, yaml.YAMLError):
        return {}
    return {s.index: float(s.frequency_hz) for s in steps}


def run_completeness(a: SessionAnalysis) -> RunCompleteness:
    """The session's planned steps against those it recorded, and its last event."""
    t = a.table
    status = t["status"].astype(str) if "status" in t else pd.Series("done", index=t.index)
    index = t["step"].astype(int) if "step" in t else pd.Series(range(len(t)), index=t.index)
    done = sorted(index[status == "done"])
    cut = sorted(index[status != "done"])
    planned = planned_steps(a.general)
    if not planned:  # no readable plan: the recorded steps are the plan
        planned = {int(i): float(f) for i, f in zip(index, t.get("frequency_hz", pd.Series(np.nan, index=t.index)))}
    kind, message = a.ending if a.ending is not None else ("", "")
    return RunCompleteness(planned, done, cut, kind, message)


def _steps_text(indices: list[int], freq: dict[int, float], most: int = 8) -> str:
    """Steps counted from 1 with their index (steps.csv's ``step``) and frequency, as every step is named
    (:func:`~beambench.acquisition.protocol.plan.step_name`): ``step 13 (index 12, 13 Hz)``, ``steps 13 (index 12,
    13 Hz), 14 (index 13, 14 Hz)``, or ``28 steps, 13–40 (index 12–39, 13–40 Hz)`` for many."""
    if len(indices) <= most:
        word = "step" if len(indices) == 1 else "steps"
        hz = {i: f", {freq[i]:g} Hz" if freq.get(i, 0) > 0 else "" for i in indices}
        return f"{word} " + ", ".join(f"{i + 1} (index {i}{hz[i]})" for i in indices)
    fs = [freq[i] for i in indices if freq.get(i, 0) > 0]
    span = f", {min(fs):g}–{max(fs):g} Hz" if fs else ""
    return f"{len(indices)} steps, {indices[0] + 1}–{indices[-1] + 1} (index {indices[0]}–{indices[-1]}{span})"


ENDINGS = ("interrupted", "fault", "failed", "error")  # the runner's closing events of a run that ended early


def completeness_note(c: RunCompleteness) -> str | None:
    """A banner when the session holds less than its protocol planned, or its run did not end normally."""
    if c.complete:
        return None
    if c.ending_kind in ENDINGS:
        how = f": {html.escape(c.ending_message or c.ending_kind)}"
    elif c.ending_kind == "":
        how = " (the session has no closing event: the run was killed or crashed)"
    else:
        how = ""
    text = (
        f"<strong>The run ended early{how}.</strong> This report covers {len(c.done)} of the {len(c.planned)} planned "
        "steps."
    )
    cut = [i for i in c.cut_short if i in c.missing]
    never = [i for i in c.missing if i not in cut]
    if cut:
        text += f" Cut short (steps.csv holds the part recorded): {_steps_text(cut, c.planned)}."
    if never:
        text += f" Never run: {_steps_text(never, c.planned)}."
    return text


def completeness_notes(analyses: list[SessionAnalysis]) -> list[str]:
    """The completeness banner of each session that needs one."""
    notes = []
    for a in analyses:
        text = completeness_note(run_completeness(a))
        if text:
            who = "" if len(analyses) == 1 else f"<em>{html.escape(a.label)}:</em> "
            notes.append(f"<p class='warn'>{who}{text}</p>")
    return notes
