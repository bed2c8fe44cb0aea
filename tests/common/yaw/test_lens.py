"""Real lenses: correspondences undistorted before the fit, so a barrel-distorted wide-angle flight with its
calibration stays within the bounds of the undistorted (pinhole twin) flight on the same trajectory."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.camera import CameraModel
from common.errors import InputError
from common.metrics import accumulated_mean_error, yaw_error_rad
from common.sim.field import FieldFlight, field_flight
from common.yaw import Provenance, YawSettings, YawTracker, gyro_delta_yaw_rad, make_patch_grid

FRAMES = 130


def _run(flight: FieldFlight, camera: CameraModel | None) -> tuple[np.ndarray, float, int]:
    """Per-pair |error| (deg) of the integrated deltas, max AME (eq. 8, N = 100) and measured pairs."""
    settings = YawSettings(camera=camera)
    frames = list(flight.frames())
    tracker = YawTracker(settings, make_patch_grid(frames[0].shape, settings))
    state = tracker.initial_state(frames[0], stamp_s=0.0)
    stamps, deltas, measured = flight.frame_stamps_s, [], 0
    for k in range(1, len(frames)):
        gyro = gyro_delta_yaw_rad(flight.imu.stamps_s, flight.imu.gyro_rad_s, stamps[k - 1], stamps[k])
        state, estimate = tracker.track(state, frames[k], float(stamps[k]), gyro)
        deltas.append(estimate.delta_yaw_rad)
        measured += estimate.provenance is Provenance.MEASURED
    truth = flight.yaw_rad
    pair_err = np.abs(np.degrees(yaw_error_rad(np.array(deltas), np.diff(truth))))
    yaw = np.concatenate([[0.0], np.cumsum(deltas)])
    ame = accumulated_mean_error(np.degrees(yaw_error_rad(yaw, truth - truth[0])), 100)
    return pair_err, float(ame.max()), measured


@pytest.fixture(scope="module")
def flights() -> tuple[FieldFlight, FieldFlight]:
    wide = field_flight("wide_angle", seed=1, n_frames=FRAMES)
    twin = field_flight("wide_angle", seed=1, n_frames=FRAMES, camera=wide.camera.pinhole())
    return wide, twin


def test_distorted_wide_angle_flight_with_calibration_within_the_undistorted_bounds(
    flights: tuple[FieldFlight, FieldFlight],
) -> None:
    wide, twin = flights
    assert wide.camera.is_distorted and not twin.camera.is_distorted
    twin_err, twin_ame, _ = _run(twin, twin.camera)
    wide_err, wide_ame, measured = _run(wide, wide.camera)
    for err, ame in ((twin_err, twin_ame), (wide_err, wide_ame)):
        assert np.count_nonzero(err > 5.0) == 0 and ame <= 2.0  # the bounds
    assert measured >= 0.95 * (FRAMES - 1)  # measured, not bridged by the gyro
    assert np.median(wide_err) <= 2.0 * np.median(twin_err) + 0.01
    assert wide_ame <= 2.0 * twin_ame + 0.1


def test_a_calibration_of_another_resolution_is_scaled_and_another_aspect_refused(
    flights: tuple[FieldFlight, FieldFlight],
) -> None:
    wide = flights[0]
    settings = YawSettings(camera=wide.camera.scaled(2.0))
    tracker = YawTracker(settings, make_patch_grid(wide.camera.shape, settings))
    assert tracker.lens.camera is not None and math.isclose(tracker.lens.camera.fx, wide.camera.fx)
    other = CameraModel.from_hfov(320, 320, 90.0)
    with pytest.raises(InputError):
        YawTracker(YawSettings(camera=other), make_patch_grid(wide.camera.shape, YawSettings()))
