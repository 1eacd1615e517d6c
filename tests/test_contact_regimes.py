"""Contact regimes from the plate's normal force alone: the classifier (synthetic force trains with a known
truth) and the twin's regime map (short batched runs)."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.analysis.contact import ContactParams, force_regime
from beambench.sim.scenes.contact_sweep import REGIME_MAP_COLUMNS, regime_map, transitions

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
    assert transitions(f, lab) == {"continuous_below_hz": 16.0, "half_at_hz": 26.0, "third_at_hz": 38.0}
    tr = transitions([5, 10], ["1", "continuous"])
    assert tr["continuous_below_hz"] == 0.0 and np.isnan(tr["half_at_hz"])


def test_regime_map_columns_and_contact():
    df = regime_map([3.0, 30.0], settle_s=0.5, record_s=0.5, rig_overrides={"plate_gap": 0.0005})
    assert list(df.columns) == list(REGIME_MAP_COLUMNS)
    assert df.ok.all()
    assert set(df.regime) <= {"none", "continuous", "irregular", "1", "2", "3", "1/2", "1/3", "1/4"}
    assert (df.regime != "none").all()  # 0.5 mm below the unloaded foot: the sagging foot touches
    assert df.attrs["plate_gap_m"] == 0.0005
    far = regime_map([3.0], settle_s=0.3, record_s=0.3, rig_overrides={"plate_gap": 0.02})
    assert far.regime.tolist() == ["none"] and far.tangential_sign.tolist() == [0]
