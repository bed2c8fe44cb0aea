"""The held yaw rate: a robust rate of the recent measured pairs, its lag, and the tracker holding it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.sim.field import checkerboard_texture
from common.sim.ground import nadir_camera_pose, render_ground_view
from common.yaw import Provenance, YawSettings, YawTracker, make_patch_grid
from common.yaw.held import MeasuredPair, held_rate, with_measured_pair
from common.yaw.honest import PriorSource, make_prior

gaps = st.lists(st.floats(0.002, 0.12), min_size=1, max_size=12)


def _window(rate: float, dts: list[float], start_s: float = 1.0) -> tuple[MeasuredPair, ...]:
    window: tuple[MeasuredPair, ...] = ()
    t = start_s
    for dt in dts:
        t += dt
        window = with_measured_pair(window, MeasuredPair(t, dt, rate * dt), window_s=10.0)
    return window


@settings(max_examples=100, deadline=None)
@given(rate=st.floats(-5.0, 5.0), dts=gaps)
def test_a_constant_rate_is_held_exactly_whatever_the_gaps(rate: float, dts: list[float]) -> None:
    held = held_rate(_window(rate, dts))
    assert held is not None
    assert held.rate_rad_s == pytest.approx(rate, abs=1e-9)
    assert held.spread_rad_s == pytest.approx(0.0, abs=1e-9)
    assert 0.0 <= held.lag_s <= sum(dts)


@settings(max_examples=100, deadline=None)
@given(
    rate=st.floats(-3.0, 3.0),
    accel=st.floats(-20.0, 20.0),
    dts=st.lists(st.floats(0.01, 0.1), min_size=3, max_size=10),
)
def test_a_steadily_changing_rate_is_carried_to_the_newest_stamp(
    rate: float, accel: float, dts: list[float]
) -> None:
    """Yaw = rate t + accel t^2 / 2: each pair's rate is the rate at its midpoint, the line through them is
    exact, and the held rate is the one at the newest pair's midpoint (not the window's average, a few pairs
    ago)."""
    window: tuple[MeasuredPair, ...] = ()
    t = 0.0
    for dt in dts:
        yaw0, t = rate * t + accel * t * t / 2.0, t + dt
        yaw1 = rate * t + accel * t * t / 2.0
        window = with_measured_pair(window, MeasuredPair(t, dt, yaw1 - yaw0), window_s=10.0)
    held = held_rate(window)
    assert held is not None
    assert held.rate_rad_s == pytest.approx(rate + accel * (t - dts[-1] / 2.0), abs=1e-6)
    assert held.trend_rad_s2 == pytest.approx(accel, abs=1e-6)
    assert held.spread_rad_s == pytest.approx(0.0, abs=1e-6)


@settings(max_examples=100, deadline=None)
@given(rate=st.floats(-2.0, 2.0), error=st.floats(-0.1, 0.1), short=st.floats(0.002, 0.02))
def test_held_rate_is_not_one_delta_over_one_gap(rate: float, error: float, short: float) -> None:
    """Issue 26: the last pair over a short gap with a small delta error (0.1 rad over 5 ms = 20 rad/s) was
    held as the rate; after four 50 ms pairs of the true rate it cannot move the held rate at all."""
    window = _window(rate, [0.05, 0.05, 0.05, 0.05])
    last = window[-1].stop_s
    window = with_measured_pair(window, MeasuredPair(last + short, short, rate * short + error))
    held = held_rate(window)
    assert held is not None and held.trend_rad_s2 == pytest.approx(0.0, abs=1e-9)
    assert held.rate_rad_s == pytest.approx(rate, abs=1e-9)


def test_old_pairs_leave_the_window_and_the_lag_is_the_weighted_midpoint() -> None:
    window = _window(1.0, [0.05] * 20, start_s=0.0)  # pairs ending 0.05 .. 1.0 s
    kept = with_measured_pair(window, MeasuredPair(1.05, 0.05, 0.05), window_s=0.2)
    assert [p.stop_s for p in kept] == pytest.approx([0.85, 0.9, 0.95, 1.0, 1.05])
    held = held_rate(kept)
    assert held is not None and held.lag_s == pytest.approx(1.05 - 0.925)
    assert held_rate(()) is None
    with pytest.raises(InputError):
        with_measured_pair(kept, MeasuredPair(1.0, 0.05, 0.0))
    with pytest.raises(InputError):
        with_measured_pair(kept, MeasuredPair(2.0, 0.0, 0.0))


def test_the_held_tolerance_grows_with_the_spread_and_the_time_since_measured() -> None:
    settings_ = YawSettings()
    held = held_rate(_window(0.5, [0.05] * 8))
    assert held is not None
    fresh = make_prior(settings_, 0.05, None, held, 0.0)
    stale = make_prior(settings_, 0.05, None, held, 2.0)
    assert fresh.source is PriorSource.HOLD and fresh.delta_rad == pytest.approx(0.025)
    assert stale.tolerance_rad > fresh.tolerance_rad and stale.variance_rad2 > fresh.variance_rad2
    # rates scattered about their line (noisy measurements): a wider tolerance for a similar held rate
    noisy = tuple(MeasuredPair(1.0 + 0.05 * (i + 1), 0.05, 0.05 * (0.5 + 2.0 * (-1) ** i)) for i in range(8))
    spread = held_rate(noisy)
    assert spread is not None and spread.spread_rad_s > 1.0
    long_gap = make_prior(settings_, 0.13, None, spread, 0.0)
    assert long_gap.tolerance_rad > make_prior(settings_, 0.13, None, held, 0.0).tolerance_rad


CAMERA = CameraModel.from_hfov(320, 240, 90.0)


def _view(texture: object, yaw_deg: float) -> np.ndarray:
    R, p = nadir_camera_pose(0.013, -0.021, 1.0, math.radians(yaw_deg))
    return render_ground_view(texture, CAMERA, R, p)  # type: ignore[arg-type]


def test_tracker_holds_the_windows_rate_not_the_last_short_gaps() -> None:
    """30 deg/s measured over two 50 ms pairs, then 1.2 deg over a 10 ms gap (120 deg/s); a blank frame 50 ms
    later is held at 30 deg/s (1.5 deg), where one delta over one gap would have held 6 deg."""
    texture = checkerboard_texture(seed=0)
    settings_ = YawSettings()
    tracker = YawTracker(settings_, make_patch_grid((CAMERA.height, CAMERA.width), settings_))
    state = tracker.initial_state(_view(texture, 0.0), stamp_s=0.0)
    for yaw_deg, stamp in ((1.5, 0.05), (3.0, 0.10), (4.2, 0.11)):
        state, estimate = tracker.track(state, _view(texture, yaw_deg), stamp)
        assert estimate.provenance is Provenance.MEASURED
    state, held = tracker.track(state, np.full((240, 320), 90, np.uint8), 0.16)
    assert held.provenance is Provenance.HELD
    assert math.degrees(held.delta_yaw_rad) == pytest.approx(1.5, abs=0.1)
