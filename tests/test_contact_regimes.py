"""Contact regimes from the plate's normal force alone: the classifier (synthetic force trains with a known
truth) and the twin's regime map (short batched runs)."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.acquisition.forces.contact_events import ContactParams, force_regime
from beambench.sim.scenes.contact_regimes import REGIME_MAP_COLUMNS, ContactTwin, regime_map, transitions
from beambench.sim.settings import SimSettings

FS = 1000.0


def chattering_contact(f: float, duration: float = 3.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A foot that stays down but whose soft contact chatters: force zero ~40 % of the samples in 1–3 ms
    gaps (as the twin's sole does at ~1000 switches per second), modulated at the drive frequency."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, duration, 1 / FS)
    fn = 0.15 + 0.1 * np.sin(2 * np.pi * f * t)
    k = 0
    while k < len(t):
        gap = int(rng.integers(1, 4))
        fn[k : k + gap] = 0.0
        k += gap + int(rng.integers(2, 5))
    return t, fn


@pytest.mark.parametrize("f", [6.0, 12.0, 17.0])
def test_chatter_while_the_foot_stays_down_is_continuous(f):
    t, fn = chattering_contact(f)
    s = force_regime(t, fn, f)
    assert s.regime == "continuous"
    assert s.contacts_per_cycle == 0.0
    # without merging the short off-plate gaps the same force would count hundreds of flights per cycle
    raw = force_regime(t, fn, f, ContactParams(min_flight_fraction=0.0))
    assert raw.regime != "continuous" and raw.contacts_per_cycle > 5


@pytest.mark.parametrize("every,label", [(1, "1"), (2, "1/2"), (3, "1/3")])
@pytest.mark.parametrize("sigma", [0.0, 0.003])
def test_subharmonic_bounces_with_and_without_noise(every, label, sigma):
    f = 30.0
    rng = np.random.default_rng(every)
    t = np.arange(0, 3.0, 1 / FS)
    cyc, ph = np.floor(t * f), t * f - np.floor(t * f)
    on = (cyc % every == 0) & (ph < 0.3)
    fn = np.where(on, 0.8 * np.sin(np.pi * ph / 0.3), 0.0) + rng.normal(0, sigma, len(t))
    s = force_regime(t, fn, f)
    assert s.regime == label
    assert s.contacts_per_cycle == pytest.approx(1 / every, abs=0.03)


def test_noise_alone_is_no_contact_and_thresholds_scale_with_it():
    t = np.arange(0, 2.0, 1 / FS)
    quiet = np.random.default_rng(1).normal(0, 0.01, len(t))  # 8σ = 80 mN > the 20 mN floor
    assert force_regime(t, quiet, 20.0).regime == "none"


def test_transitions_of_a_map():
    f = [10, 16, 18, 20, 26, 30, 38, 40]
    lab = ["continuous", "continuous", "1", "1", "1/2", "1/2", "1/3", "irregular"]
    # the continuous edge is the lowest step that is not continuous (the foot never leaves the plate below it)
    assert transitions(f, lab) == {"continuous_below_hz": 18.0, "half_at_hz": 26.0, "third_at_hz": 38.0}
    tr = transitions([5, 10], ["1", "continuous"])  # a map that does not start continuous has no edge
    assert tr["continuous_below_hz"] is None and tr["half_at_hz"] is None


def test_regime_map_columns_and_contact():
    df = regime_map(
        [3.0, 30.0], SimSettings(settle_s=0.5, record_s=0.5), ContactTwin(rig_overrides={"plate_gap": 0.0005})
    )
    assert list(df.columns) == list(REGIME_MAP_COLUMNS)
    assert df.ok.all()
    assert set(df.regime) <= {"none", "continuous", "irregular", "1", "2", "3", "1/2", "1/3", "1/4"}
    assert (df.regime != "none").all()  # 0.5 mm below the unloaded foot: the sagging foot touches
    assert df.attrs["plate_gap_m"] == 0.0005
    far = regime_map([3.0], SimSettings(settle_s=0.3, record_s=0.3), ContactTwin(rig_overrides={"plate_gap": 0.02}))
    assert far.regime.tolist() == ["none"] and far.tangential_sign.tolist() == [0]


# ------------------------------------------------------------------------- the twin: noise and the default set

WINDOW = SimSettings(settle_s=1.5, record_s=1.5)
SWEEP = [3.0, 6.0, 16.0, 20.0, 22.0, 28.0, 30.0, 32.0, 38.0, 40.0]  # continuous, 2, 1, 1/2, 1/3 on the default


@pytest.mark.slow
def test_same_physics_same_labels_with_and_without_noise():
    """Load-cell noise (15 counts per channel) and mocap noise (0.1 mm) must not change a single label: the
    regime comes from the normal force with a noise-scaled threshold, and the foot height is not used."""
    sim, twin = SimSettings(settle_s=1.5, record_s=1.5), ContactTwin(params="contact_paper")
    quiet = regime_map(SWEEP, sim.replace(noise=False), twin)
    noisy = regime_map(SWEEP, sim.replace(noise=True, seed=7), twin)
    assert quiet.ok.all() and noisy.ok.all()
    assert noisy.regime.tolist() == quiet.regime.tolist()
    assert np.allclose(noisy.contacts_per_cycle, quiet.contacts_per_cycle, atol=0.05)
    assert len(set(quiet.regime)) >= 4  # the sweep really spans several regimes


@pytest.mark.slow
def test_default_set_is_continuous_at_low_frequency_and_halves_in_the_mid_twenties():
    df = regime_map([3.0, 5.0, 22.0, 28.0, 30.0, 39.0], WINDOW, ContactTwin(params="contact_paper"))
    lab = dict(zip(df.frequency_hz, df.regime))
    assert lab[3.0] == lab[5.0] == "continuous"
    assert lab[22.0] == "1"
    assert lab[28.0] == lab[30.0] == "1/2"
    assert lab[39.0] == "1/3"
    # the paper's own PRB values never reach the plate at its 5.5 mm gap: its release-test fit is not a contact twin
    paper = regime_map([5.0, 28.0], SimSettings(settle_s=0.8, record_s=0.8), ContactTwin(params="paper"))
    assert paper.regime.tolist() == ["none", "none"]


@pytest.mark.slow
def test_physical_default_map_from_rest():
    """The shipped default (rod5g, ``physical``: the beam anchored to the release test, the load frame meeting the
    plate at its corner), each frequency from rest (settle 2 s, record 2 s), pinned from the calibrated map
    (docs/contact-twin.md): continuous at 5 and 12 Hz, one contact per cycle at 30 and 40 Hz (the paper's 1/3 is
    missed), the tangential force of the foot on the plate - at 12 Hz and + at 40 Hz."""
    freqs = [5.0, 12.0, 30.0, 40.0]
    df = regime_map(freqs, SimSettings(settle_s=2.0, record_s=2.0), ContactTwin(model="rod5g", params="physical"))
    lab, sign = dict(zip(freqs, df.regime)), dict(zip(freqs, df.tangential_sign))
    assert lab[5.0] == lab[12.0] == "continuous", lab
    assert lab[30.0] == lab[40.0] == "1", lab
    assert sign[12.0] == -1 and sign[40.0] == 1, sign


@pytest.mark.slow
def test_effective_stuck_set_keeps_the_foot_down_to_17_hz_where_a_sliding_sole_hops():
    """The effective, non-physical set ``contact_stuck`` (an earlier default: a sole that does not slide,
    friction 6) is continuous through 17 Hz,
    bounces once a cycle at 22 Hz and every other cycle at 30 Hz; the same beam with a sliding sole (friction
    1.5, the first calibration's value) loses the continuous contact at 12-16 Hz (the sole's sliding makes the
    force drop to zero twice a cycle; docs/contact-twin.md)."""
    freqs = [5.0, 12.0, 14.0, 16.0, 17.0, 22.0, 30.0]
    lab = dict(zip(freqs, regime_map(freqs, WINDOW, ContactTwin(params="contact_stuck")).regime))
    assert all(lab[f] == "continuous" for f in (5.0, 12.0, 14.0, 16.0, 17.0)), lab
    assert lab[22.0] == "1" and lab[30.0] == "1/2", lab
    sliding = regime_map(freqs[1:4], WINDOW, ContactTwin(params="contact_stuck", rig_overrides={"friction": 1.5}))
    assert "continuous" not in set(sliding.regime), sliding.regime.tolist()


# ------------------------------------------------------------------------------ gap, parameter sets, model: auto


def test_the_gap_comes_from_the_parameter_set_unless_the_protocol_sets_it():
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice

    base = "rig: contact\nsweep: {frequencies: [5]}\nsim: {model: %s, params: %s%s}\n"
    assert (
        build_scene(sim_slice(parse_protocol(base % ("prb3", "contact_paper", "")))).identity()["plate_gap_m"] == 0.0074
    )
    assert build_scene(sim_slice(parse_protocol(base % ("prb3", "paper", "")))).identity()["plate_gap_m"] == 0.0055
    over = build_scene(sim_slice(parse_protocol(base % ("prb3", "contact_paper", ", plate_gap_mm: 6.0"))))
    assert over.identity()["plate_gap_m"] == pytest.approx(0.006)


def test_auto_considers_every_model_with_a_contact_table_and_the_parameter_set():
    from beambench.acquisition.protocol.schema import parse_protocol
    from beambench.backends.sim import build_scene
    from beambench.session.slices import sim_slice
    from beambench.sim import selection as select
    from beambench.sim.models.params import has_params

    models = select.table_models("contact")
    assert "prb3" in models
    assert has_params("contact_paper", "prb3") and not has_params("contact_paper", "rod")
    assert has_params("paper", "rod")
    scene = build_scene(
        sim_slice(
            parse_protocol("rig: contact\nsweep: {frequencies: [5, 30]}\nsim: {model: auto, params: contact_paper}\n")
        )
    )
    ident = scene.identity()
    assert ident["selection"]["model"] in models and ident["plate_gap_m"] == 0.0074


SESSION = """
name: noise_check
rig: contact
backend: sim
sweep: {frequencies: [8, 14, 22, 28, 38]}
settle_s: 1.0
record_s: 1.5
amplitude_mm: 2.0
limits: {max_frequency_hz: 40, max_current_a: 10, max_amplitude_mm: 3}
sim: {model: prb3, params: contact_paper, twist_deg: 90, noise: %s, seed: 2}
"""


@pytest.mark.slow
def test_analyze_gives_the_same_regimes_with_sim_noise_on_and_off(tmp_path):
    """A real short session each way (``beambench run`` → ``beambench analyze``): load-cell and mocap noise
    must not change ``steps.csv``'s regime column (the old foot-rise filter turned 'continuous' into '1'/'2')."""
    import pandas as pd
    from typer.testing import CliRunner

    from beambench.cli import app

    runner = CliRunner()
    labels = {}
    for noise in ("true", "false"):
        proto = tmp_path / f"n_{noise}.yaml"
        proto.write_text(SESSION % noise)
        res = runner.invoke(app, ["run", str(proto), "--rerun", "off", "--out", str(tmp_path), "--name", noise])
        assert res.exit_code == 0, res.output
        res = runner.invoke(app, ["analyze", str(tmp_path / f"{noise}.h5"), "-q", "--figures", "none"])
        assert res.exit_code == 0, res.output
        labels[noise] = pd.read_csv(tmp_path / f"{noise}_report" / "steps.csv")["regime"].tolist()
    assert labels["true"] == labels["false"]
    assert labels["false"][0] == "continuous" and labels["false"][3] == "1/2"
