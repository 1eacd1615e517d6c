"""Stage frame, ellipse fits and sense of travel on paths with a known truth."""

from __future__ import annotations

import numpy as np
import pytest

from beambench.analysis.trajectory import (
    area_per_cycle,
    axis_vector,
    drive_axis,
    fit_ellipse_harmonic,
    fit_ellipse_points,
    mean_path,
    relative_trajectory,
    stage_frame,
)


def ellipse_path(t, f, major, minor, tilt_deg, clockwise, center=(0.4, -0.2)):
    w = 2 * np.pi * f * t
    s = -1.0 if clockwise else 1.0
    loc = np.stack([major / 2 * np.cos(w), s * minor / 2 * np.sin(w)])
    th = np.deg2rad(tilt_deg)
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    return (rot @ loc).T + np.asarray(center)


@pytest.mark.parametrize("clockwise", [True, False])
@pytest.mark.parametrize("tilt", [-35.0, 0.0, 20.0, 80.0])
def test_harmonic_ellipse_recovers_axes_tilt_and_sense_with_noise_and_dropouts(clockwise, tilt):
    rng = np.random.default_rng(7)
    f = 17.0
    t = np.arange(0, 5, 1 / 360)
    xy = ellipse_path(t, f, 3.0, 1.0, tilt, clockwise) + rng.normal(0, 0.05, (len(t), 2))
    xy[rng.random(len(t)) < 0.15] = np.nan  # 15 % dropped frames
    e = fit_ellipse_harmonic(t, xy, f)
    assert e.major == pytest.approx(3.0, rel=0.02)
    assert e.minor == pytest.approx(1.0, rel=0.03)
    assert (e.tilt_deg - tilt + 90) % 180 - 90 == pytest.approx(0.0, abs=1.0)
    assert e.clockwise is clockwise
    assert e.center == pytest.approx((0.4, -0.2), abs=0.01)
    assert e.r2 > 0.99
    # the path's signed area agrees: −π·a·b per cycle when clockwise
    area = area_per_cycle(t, xy, f)
    assert np.sign(area) == (-1 if clockwise else 1)
    assert abs(area) == pytest.approx(np.pi * 1.5 * 0.5, rel=0.1)


def test_a_line_has_no_sense_and_a_figure_eight_a_poor_fit():
    t = np.arange(0, 2, 1 / 360)
    line = np.stack([np.sin(2 * np.pi * 10 * t), 0.2 * np.sin(2 * np.pi * 10 * t)], 1)
    e = fit_ellipse_harmonic(t, line, 10.0)
    assert e.clockwise is None and e.minor == pytest.approx(0.0, abs=1e-9)
    assert e.tilt_deg == pytest.approx(np.degrees(np.arctan(0.2)), abs=0.01)
    eight = np.stack([np.sin(2 * np.pi * 10 * t), np.sin(4 * np.pi * 10 * t)], 1)
    assert fit_ellipse_harmonic(t, eight, 10.0).r2 < 0.6
    assert abs(area_per_cycle(t, eight, 10.0)) < 0.02


def test_conic_fit_on_unordered_points():
    rng = np.random.default_rng(3)
    t = rng.uniform(0, 1, 400)
    xy = ellipse_path(t, 1.0, 4.0, 1.5, 30.0, True) + rng.normal(0, 0.01, (400, 2))
    e = fit_ellipse_points(xy)
    assert e.major == pytest.approx(4.0, rel=0.02)
    assert e.minor == pytest.approx(1.5, rel=0.03)
    assert e.tilt_deg == pytest.approx(30.0, abs=1.0)
    ordered = ellipse_path(np.linspace(0, 1, 100), 1.0, 4.0, 1.5, 30.0, True)
    assert fit_ellipse_points(ordered).clockwise is True


def test_stage_frame_from_stage_motion_and_hanging_foot():
    rng = np.random.default_rng(1)
    t = np.arange(0, 2, 1 / 360)
    d_true = np.array([0.0, -1.0, 0.2]) / np.linalg.norm([0.0, -1.0, 0.2])  # mostly along −y
    stage = np.array([0.1, 0.2, 0.5]) + np.outer(0.002 * np.sin(2 * np.pi * 5 * t), d_true)
    stage += rng.normal(0, 1e-5, stage.shape)
    d = drive_axis(stage)
    assert abs(d @ d_true) > 0.9999
    assert d[1] > 0  # signed along its dominant world axis (+y)
    foot = stage + np.array([0.05, 0.0, -0.07])  # hangs below: up is +z
    fr = stage_frame(stage, hanging_xyz=foot)
    assert fr.up @ axis_vector("z") > 0.98 and abs(fr.up @ fr.drive) < 1e-12
    motive = stage_frame(stage[:, [0, 2, 1]] * [1, 1, 1], hanging_xyz=foot[:, [0, 2, 1]])  # a y-up world
    assert motive.up @ axis_vector("y") > 0.98
    fr2 = stage_frame(stage, "-x")
    assert fr2.up @ axis_vector("-x") > 0.99
    # relative trajectory: a foot fixed 1 mm "up" and 2 mm along drive from the stage, in mm
    rel = relative_trajectory(stage + 1e-3 * fr.up + 2e-3 * fr.drive, stage, fr)
    assert np.allclose(rel, [2.0, 1.0])
    with pytest.raises(ValueError):
        axis_vector("w")


def test_mean_path_keeps_the_shape_and_sense():
    rng = np.random.default_rng(5)
    f = 18.0  # 360/18 = 20 frames per cycle: only 20 distinct phases
    t = np.arange(0, 3, 1 / 360)
    xy = ellipse_path(t, f, 3.0, 1.0, 0.0, True, center=(0, 0)) + rng.normal(0, 0.1, (len(t), 2))
    mp = mean_path(t, xy, 1 / f)
    assert np.allclose(mp[0], mp[-1])
    assert np.max(np.abs(mp[:, 0])) == pytest.approx(1.5, rel=0.1)
    x, y = mp[:, 0], mp[:, 1]
    assert 0.5 * np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]) < 0  # clockwise survives the averaging
