"""Documentation pictures match what a fresh clone shows: each PNG in docs/img was made by
``python docs/make_figures.py`` from the shipped protocols and parameter sets and with the drawing code as they are
now (the hash of those files stored in the PNG equals the hash of the shipped files), and every picture a page
shows exists."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _make_figures():
    spec = importlib.util.spec_from_file_location("make_figures", DOCS / "make_figures.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]


def test_every_picture_was_made_from_the_shipped_defaults() -> None:
    mf = _make_figures()
    pngs = sorted(p.name for p in (DOCS / "img").glob("*.png"))
    assert pngs, "docs/img has no pictures"
    assert set(pngs) == set(mf.PICTURES), "docs/img and make_figures.PICTURES must list the same pictures"
    stale = [n for n in pngs if mf.read_stamp(DOCS / "img" / n) != mf.inputs_hash(n)]
    assert not stale, f"made from other inputs than the shipped ones: {stale}; run `python docs/make_figures.py`"


def test_the_hash_follows_the_shipped_inputs(tmp_path: Path) -> None:
    """The stamp is sensitive to the protocol and to the parameter set it names (so the check above can fail)."""
    mf = _make_figures()
    files = mf.shipped_inputs("contact_sweep")
    names = [str(f.relative_to(ROOT)) for f in files]
    assert "protocols/contact_sweep.yaml" in names
    assert any(n.startswith("sim_backend/") for n in names), names
    assert mf.inputs_hash("live_view_contact.png") != mf.inputs_hash("live_view_walker.png")
    assert mf.inputs_hash("report_forces.png") != mf.inputs_hash("tracking.png")


def test_the_hash_follows_the_code_that_draws_the_picture(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A report figure's stamp covers its module and the beambench.analysis modules it imports when it runs, so a
    change to how a picture is drawn makes it stale as a change of protocol does."""
    mf = _make_figures()
    names = {f"{f.parent.name}/{f.name}" for f in mf.drawing_code("report_forces.png")}
    assert {"figures/forces.py", "figures/style.py", "figures/registry.py", "analysis/path_shape.py"} <= names
    assert "analysis/session_analysis.py" not in names  # imported for type checking only
    assert "contact_frequency.py" in {f.name for f in mf.drawing_code("report_contact_frequency.png")}
    # same protocol, other drawing code: other stamps
    assert mf.inputs_hash("report_forces.png") != mf.inputs_hash("report_trajectories.png")
    assert mf.inputs_hash("report_forces.png") != mf.inputs_hash("live_view_contact.png")
    # one byte more in a drawing module changes the stamp
    copy = tmp_path / "figures" / "forces.py"
    copy.parent.mkdir()
    copy.write_bytes(next(f for f in mf.drawing_code("report_forces.png") if f.name == "forces.py").read_bytes())
    monkeypatch.setattr(mf, "drawing_code", lambda name: [copy])
    before = mf.inputs_hash("report_forces.png")
    copy.write_bytes(copy.read_bytes() + b"# a change\n")
    assert mf.inputs_hash("report_forces.png") != before


@pytest.mark.parametrize("page", _pages(), ids=lambda p: p.name)
def test_every_picture_a_page_shows_exists_and_every_picture_is_shown(page: Path) -> None:
    text = page.read_text(encoding="utf-8")
    for ref in re.findall(r"\]\(((?:docs/)?img/[^)\s]+\.png)\)", text):
        assert (page.parent / ref).is_file(), f"{page.name} shows {ref}, which does not exist"


def test_no_picture_is_unreferenced() -> None:
    shown = "".join(p.read_text(encoding="utf-8") for p in _pages())
    unused = [p.name for p in (DOCS / "img").glob("*.png") if f"img/{p.name}" not in shown]
    assert not unused, f"pictures no page shows: {unused}"
