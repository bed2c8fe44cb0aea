"""The yaw core's default at any frame size: the pyramid level and the pixel thresholds follow the frame's
size (:func:`~common.yaw.grid.auto_pyramid_level`, :func:`~common.yaw.grid.for_frame`)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.sim.field import FieldFlight, field_flight, wide_angle_camera
from common.types import U8Array
from common.yaw import (
    FrameYaw,
    Provenance,
    YawSettings,
    YawTracker,
    auto_pyramid_level,
    for_frame,
    gyro_delta_yaw_rad,
    make_patch_grid,
)
from common.yaw.grid import AUTO_LEVEL_SIDE_PX, MAX_PYRAMID_LEVEL, level_shape

HdFlight = tuple[FieldFlight, list[U8Array]]


@pytest.mark.parametrize(
    ("frame_shape", "level"),
    [((240, 320), 1), ((120, 160), 1), ((480, 640), 1), ((480, 752), 1), ((600, 800), 2), ((720, 1280), 2),
     ((1080, 1920), 3), ((2160, 3840), 4), ((40, 40), 0)],
)  # fmt: skip
def test_the_default_pyramid_level_follows_the_frame_size(frame_shape: tuple[int, int], level: int) -> None:
    """Up to 752x480 the level the defaults were measured at (1); above, each doubling of the size adds one;
    a frame too small for a patch at level 1, 0."""
    assert auto_pyramid_level(frame_shape, YawSettings()) == level
    assert make_patch_grid(frame_shape, YawSettings()).pyramid_level == level


@settings(max_examples=200, deadline=None)
@given(st.integers(32, 4000), st.integers(32, 4000))
@example(121, 3493)  # 325 px at level 1, but 31 px high at level 2: stays at 1
def test_the_default_level_works_within_the_measured_size_and_always_fits(height: int, width: int) -> None:
    """The default level is 1 or the first coarser one at which the frame is no larger than the largest
    working size the defaults were measured at (up to the pyramid's rounding up), unless a patch would not
    fit there (a long thin frame); 0 only for a frame too small for a patch at level 1; the grid always
    fits."""
    chosen = auto_pyramid_level((height, width), YawSettings())

    def side(level: int) -> float:
        return math.sqrt(math.prod(level_shape((height, width), level)))

    if chosen == 0:
        assert min(level_shape((height, width), 1)) < 32
    elif chosen > 1:
        assert side(chosen - 1) > AUTO_LEVEL_SIDE_PX  # a finer level would be larger than measured
    if 0 < chosen < MAX_PYRAMID_LEVEL and min(level_shape((height, width), chosen + 1)) >= 32:
        assert side(chosen) <= AUTO_LEVEL_SIDE_PX * 1.02
    if min(height, width) >= 32:
        make_patch_grid((height, width), YawSettings())  # never too small at the level chosen


@pytest.mark.parametrize("frame_shape", [(0, 0), (-5, 10), (math.nan, 3), (240.5, 320), (240,), (True, 320)])
def test_a_frame_shape_that_is_not_two_positive_integers_is_one_clear_error(
    frame_shape: tuple[int, int],
) -> None:
    """Regression: ``for_frame`` and ``auto_pyramid_level`` took the log of any shape (math domain error)."""
    for call in (
        lambda: for_frame(YawSettings(), frame_shape),
        lambda: make_patch_grid(frame_shape, YawSettings()),
    ):
        with pytest.raises(InputError, match="frame_shape"):
            call()


def test_a_long_thin_frame_stays_at_the_coarsest_level_a_patch_fits() -> None:
    """4000x120 is larger than 752x480 at level 1 (346 px against 320) but only 30 px high at level 2."""
    assert auto_pyramid_level((120, 4000), YawSettings()) == 1


def test_resolving_scales_the_pixel_thresholds_with_the_level_once_and_keeps_a_given_level() -> None:
    base = YawSettings()
    hd = for_frame(base, (1080, 1920))
    assert hd.pyramid_level == 3
    assert hd.ransac_threshold_px == pytest.approx(4.0 * base.ransac_threshold_px)
    assert hd.max_residual_px == pytest.approx(4.0 * base.max_residual_px)
    assert for_frame(hd, (1080, 1920)) == hd  # resolving twice changes nothing
    assert for_frame(for_frame(base, (240, 320)), (240, 320)) == replace(base, pyramid_level=1)
    given_level = YawSettings(pyramid_level=1)
    assert for_frame(given_level, (720, 1280)) == given_level  # a user's level and thresholds stay


@pytest.fixture(scope="module")
def hd_flight() -> HdFlight:
    """The first 13 frames of the combined field flight (checkerboard, low and drifting, 60 deg/s turns,
    blur) through a 1280x720 wide-angle lens."""
    flight = field_flight("field", seed=0, n_frames=300, camera=wide_angle_camera(1280, 720))
    return flight, [flight.frame(k) for k in range(13)]


def _track(hd: HdFlight, settings: YawSettings, gyro: bool) -> list[FrameYaw]:
    """The flight's pairs as a user wires the core: its calibration, the gyro's turn between the stamps."""
    flight, frames = hd
    settings = replace(settings, camera=flight.camera)
    tracker = YawTracker(settings, make_patch_grid(frames[0].shape, settings), flight.R_body_camera)
    state = tracker.initial_state(frames[0], stamp_s=float(flight.frame_stamps_s[0]))
    imu, estimates = flight.imu, []
    for k in range(1, len(frames)):
        t0, t1 = float(flight.frame_stamps_s[k - 1]), float(flight.frame_stamps_s[k])
        prior = gyro_delta_yaw_rad(imu.stamps_s, imu.gyro_rad_s, t0, t1) if gyro else None
        state, estimate = tracker.track(state, frames[k], t1, prior)
        estimates.append(estimate)
    return estimates


@pytest.mark.parametrize("gyro", [True, False])
def test_an_hd_wide_angle_flight_is_measured_with_the_defaults(hd_flight: HdFlight, gyro: bool) -> None:
    """Regression: at a fixed level 1 with 1 px thresholds, 1280x720 frames move four times as many pixels as
    the 320x240 ones the defaults were measured on: the patch fit kept under half of its patches and the
    gyro bridged 4 of these 12 pairs (without it the held rate carried 1). Resolved for the frame's size
    (level 2, 2 px), every pair is measured."""
    fixed = _track(hd_flight, YawSettings(pyramid_level=1), gyro)
    assert sum(e.provenance is not Provenance.MEASURED for e in fixed) >= (3 if gyro else 1)
    estimates = _track(hd_flight, YawSettings(), gyro)
    assert [e.provenance for e in estimates] == [Provenance.MEASURED] * len(estimates)
    true_delta = np.diff(hd_flight[0].yaw_rad[: len(estimates) + 1])
    errors = [abs(math.degrees(e.delta_yaw_rad - d)) for e, d in zip(estimates, true_delta, strict=True)]
    assert max(errors) < 0.5
