"""Contact events, ratios and regimes from synthetic force trains with a known truth."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.acquisition.forces.contact_events import (
    ContactParams,
    detect_contacts,
    hysteresis,
    regime_fraction,
    regime_label,
    summarize_contacts,
)
from beambench.analysis.contact import touchdown_velocity

FS = 1000.0


def force_train(f, every, duration=5.0, duty=0.3, peak=1.2, noise=0.01, seed=0, chatter=False):
    """Half-sine pulses during phase [0.1, 0.1 + duty) of every ``every``-th drive cycle, plus noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, duration, 1 / FS)
    cyc = np.floor(t * f)
    ph = t * f - cyc
    on = (cyc % every == 0) & (ph >= 0.1) & (ph < 0.1 + duty)
    fn = np.where(on, peak * np.sin(np.pi * (ph - 0.1) / duty), 0.0)
    if chatter:  # 1-2 ms dips to zero inside each contact (micro-chatter)
        dip = on & (np.abs(ph - 0.1 - duty / 2) < 1.5e-3 * f)
        fn[dip] = 0.0
    return t, fn + rng.normal(0, noise, len(t))


@pytest.mark.parametrize("f,every,label", [(20.0, 1, "1"), (26.0, 2, "1/2"), (38.0, 3, "1/3"), (44.0, 4, "1/4")])
def test_force_trains_give_their_ratio(f, every, label):
    t, fn = force_train(f, every)
    c = detect_contacts(t, fn, f)
    s = summarize_contacts(c, f)
    assert s.contacts_per_cycle == pytest.approx(1 / every, abs=0.02)
    assert s.contact_frequency_hz == pytest.approx(f / every, rel=0.03)
    assert s.regime == label
    assert regime_fraction(label) == pytest.approx(1 / every)


def test_half_rate_train_with_noise_dropouts_and_chatter():
    f = 30.0
    t, fn = force_train(f, 2, noise=0.03, chatter=True, seed=3)
    rng = np.random.default_rng(4)
    fn[rng.random(len(fn)) < 0.05] = np.nan  # 5 % lost samples
    keep = ~((t > 2.0) & (t < 2.05))  # and 50 ms missing entirely
    c = detect_contacts(t[keep], fn[keep], f)
    s = summarize_contacts(c, f)
    assert s.regime == "1/2"
    assert s.contacts_per_cycle == pytest.approx(0.5, abs=0.03)
    assert len(c.mask) == keep.sum()
    # without the flight filter the dips would double the count
    raw = detect_contacts(t[keep], fn[keep], f, ContactParams(min_flight_fraction=0.0))
    assert summarize_contacts(raw, f).contacts_per_cycle > 0.9


def test_no_contact_and_continuous_contact():
    t = np.arange(0, 3, 1 / FS)
    rng = np.random.default_rng(0)
    quiet = rng.normal(0, 0.004, len(t))
    c = detect_contacts(t, quiet, 15.0)
    s = summarize_contacts(c, 15.0)
    assert (s.n_contacts, s.regime, s.in_contact_fraction) == (0, "none", 0.0)
    pressed = 1.0 + 0.3 * np.sin(2 * np.pi * 12 * t) + rng.normal(0, 0.01, len(t))
    s = summarize_contacts(detect_contacts(t, pressed, 12.0), 12.0)
    assert s.regime == "continuous" and s.n_contacts == 0 and s.in_contact_fraction == pytest.approx(1.0)
    empty = detect_contacts(np.zeros(0), np.zeros(0), 10.0)
    assert summarize_contacts(empty, 10.0).regime == "none"


def test_rise_criterion_merges_flights_where_the_foot_stays_down():
    f = 20.0
    t, fn = force_train(f, 1, noise=0.0)
    tm = np.arange(0, 5, 1 / 360)
    flat = np.zeros_like(tm)  # the foot never rises: force gaps are not flights
    c = detect_contacts(t, fn, f, foot_t_s=tm, foot_height_m=flat)
    assert c.n_touchdowns <= 1 and summarize_contacts(c, f).regime == "continuous"
    assert c.in_contact_fraction > 0.95
    ph = (tm * f) % 1
    lifting = np.where((ph >= 0.1) & (ph < 0.4), 0.0, 0.3e-3 * np.sin(np.pi * ((ph - 0.4) % 1) / 0.7))
    c = detect_contacts(t, fn, f, foot_t_s=tm, foot_height_m=lifting)
    assert summarize_contacts(c, f).regime == "1"


def test_hysteresis_and_labels():
    x = np.array([0, 0.6, 1.2, 0.8, 0.4, 0.9, 1.1, 0.2, 0.6])
    assert hysteresis(x, on=1.0, off=0.5).tolist() == [False, False, True, True, False, False, True, False, False]
    assert regime_label(0.52, 0.2, 10) == "1/2"
    assert regime_label(0.41, 0.2, 10) == "irregular"
    assert regime_label(2.05, 0.9, 10) == "2"
    assert regime_label(0.0, 0.0, 0) == "none"


def test_touchdown_velocity_sign():
    t = np.arange(0, 1, 1 / 360)
    v = np.where(np.sin(2 * np.pi * 5 * t) > 0, 40.0, -40.0)
    td = np.array([0.08, 0.18])  # first half-cycle positive, second negative
    out = touchdown_velocity(td, t, v, 0.02)
    assert out[0] == pytest.approx(40.0) and out[1] == pytest.approx(-40.0)
