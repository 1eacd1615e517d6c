"""The flight rule of the contact events (a gap in the normal force counts as a flight when it lasts more than
``min_flight_fraction`` of a drive period) gives the same count at any sampling rate, also for a flight of exactly
the threshold's length: a flight is counted in whole samples against the threshold in samples, so the time stamps'
rounding (and jitter below half a sample) does not decide it."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.acquisition.forces.contact_events import ContactParams, detect_contacts

DRIVE_HZ = 25.0
THRESHOLD_S = ContactParams().min_flight_fraction / DRIVE_HZ  # 4 ms
WINDOW_S = 2.0


def square_contact(rate_hz: float, flight_s: float, offset: float = 0.3, jitter: float = 0.0) -> tuple:
    """The plate's normal force sampled at ``rate_hz``: 0.5 N on the plate, 0 N during one flight of ``flight_s``
    per drive period. The samples sit ``offset`` of an interval off the period's start (none on an edge); their
    time stamps carry ``jitter`` (a fraction of the interval, uniform ±) as a host's do."""
    n = np.arange(int(WINDOW_S * rate_hz)) + offset
    phase = (n / rate_hz * DRIVE_HZ) % 1.0
    fn = np.where(phase < 1.0 - flight_s * DRIVE_HZ, 0.5, 0.0)
    stamps = (n + np.random.default_rng(1).uniform(-jitter, jitter, len(n))) / rate_hz
    return stamps, fn


def counts(rates: tuple[float, ...], flight_s: float, jitter: float = 0.0) -> list[int]:
    return [detect_contacts(*square_contact(r, flight_s, jitter=jitter), DRIVE_HZ).n_touchdowns for r in rates]


EVERY_FLIGHT = round(WINDOW_S * DRIVE_HZ) - 1  # all but the flight cut by the window's start


@pytest.mark.parametrize("rates", [(1000.0, 2000.0), (500.0, 1250.0), (20000.0, 1000.0)])
@pytest.mark.parametrize(("share", "expected"), [(0.5, 0), (1.0, 0), (1.5, EVERY_FLIGHT)])
def test_a_flight_of_exactly_the_threshold_is_decided_alike_at_two_sampling_rates(rates, share, expected):
    """Rates where the 4 ms threshold is a whole number of samples: a flight of exactly 4 ms is not more than the
    threshold at either (in seconds, the time stamps' rounding counted some of them at 1 kHz and none at 2 kHz)."""
    assert counts(rates, share * THRESHOLD_S) == [expected, expected]


@pytest.mark.parametrize("rates", [(1000.0, 1600.0), (800.0, 3000.0)])
@pytest.mark.parametrize(("share", "expected"), [(0.5, 0), (0.75, 0), (1.3, EVERY_FLIGHT), (2.0, EVERY_FLIGHT)])
def test_flights_clear_of_the_threshold_count_alike_at_any_rate_and_with_jittered_stamps(rates, share, expected):
    """A flight more than a sample away from the threshold is decided alike at any rate, also with time stamps
    jittered by up to 0.2 of a sample interval (a flight's two ends: less than half a sample together)."""
    assert counts(rates, share * THRESHOLD_S) == [expected, expected]
    assert counts(rates, share * THRESHOLD_S, jitter=0.2) == [expected, expected]
    assert counts((1000.0,), THRESHOLD_S, jitter=0.2) == [0]  # exactly the threshold, jittered stamps: still not
