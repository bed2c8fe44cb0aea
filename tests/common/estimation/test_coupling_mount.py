"""Double coupling on flight (b) with a rig whose camera and IMU are not the ideal ones: the camera tilted
10 deg and turned 90 deg about its axis, the IMU upside down and turned 90 deg, its clock 12 ms ahead.
Told the rig, the estimator keeps the bounds of the ideal rig (test_coupling); not told the IMU's axes,
it fails, counted (its diverged altitude once raised out of the VO: a crash)."""

from __future__ import annotations

import numpy as np
import pytest

from common.camera import CameraModel
from common.errors import InputError
from common.estimation.coupling import DoubleCouplingEstimator
from common.estimation.coupling_types import CouplingSettings
from common.estimation.measurements import ImuMeasurement
from common.estimation.replay import camera_model_of, evaluate, run_estimators
from common.sim.field import MOUNTED_RIG
from common.sim.flight import Flight, turns_flight
from common.sim.ground import GroundTexture
from common.sim.stream import flight_measurements

START, STOP = 400, 480  # as test_coupling: 4 s in the middle of the manoeuvre


@pytest.fixture(scope="module")
def mounted_flight(texture: GroundTexture) -> Flight:
    return turns_flight(
        seed=0,
        texture=texture,
        R_body_camera=MOUNTED_RIG.R_body_camera,
        R_body_imu=MOUNTED_RIG.R_body_imu,
        imu_time_offset_s=MOUNTED_RIG.imu_time_offset_s,
    )


def _settings(flight: Flight, **kwargs: object) -> CouplingSettings:
    q0, q1, q2, q3 = (float(v) for v in flight.q_world_body[START])
    return CouplingSettings(
        initial_yaw_rad=float(flight.yaw_rad[START]),
        initial_position_m=(float(flight.p_world_body_m[START, 0]), float(flight.p_world_body_m[START, 1])),
        initial_q_world_body=(q0, q1, q2, q3),
        accel_wait_for_vo_s=1.0,
        **kwargs,  # type: ignore[arg-type]
    )


def test_the_estimator_told_the_rig_keeps_the_ideal_rigs_bounds(mounted_flight: Flight) -> None:
    flight = mounted_flight
    camera = camera_model_of(flight)
    R_bi, offset = flight.imu.R_body_imu, flight.imu.time_offset_s

    def told(settings: CouplingSettings) -> DoubleCouplingEstimator:
        return DoubleCouplingEstimator(
            camera, flight.R_body_camera, settings=settings, R_body_imu=R_bi, imu_time_offset_s=offset
        )

    estimators = {
        "rectified": told(_settings(flight)),
        "traditional": told(_settings(flight, rectify=False)),
        "imu_axes_unknown": DoubleCouplingEstimator(camera, flight.R_body_camera, settings=_settings(flight)),
    }
    results = run_estimators(estimators, flight_measurements(flight, START, STOP))
    for name in ("rectified", "traditional"):
        errors = evaluate(results[name], flight, START)
        assert np.all(errors.att_rmse_deg < 0.5), (name, errors.att_rmse_deg)
        assert errors.alt_rmse_m < 0.02, (name, errors.alt_rmse_m)
        assert errors.path_length_m > 1.0
        assert errors.vo_final_error_m < 0.01, (name, errors.vo_final_error_m)
        assert errors.vo_max_error_m < (0.1 if name == "rectified" else 0.01), (name, errors.vo_max_error_m)
        assert estimators[name].counters["vo_pairs"] == STOP - START - 1
    wrong = evaluate(results["imu_axes_unknown"], flight, START)
    assert np.max(wrong.att_max_deg) > 10.0, wrong.att_max_deg  # the gyro read in the wrong axes
    assert estimators["imu_axes_unknown"].counters["vo_failures"] > 0  # failed pairs, counted, no crash


def test_imu_samples_enter_in_the_body_axes_on_the_camera_clock() -> None:
    R_body_imu = MOUNTED_RIG.R_body_imu
    estimator = DoubleCouplingEstimator(CameraModel.default(), R_body_imu=R_body_imu, imu_time_offset_s=0.012)
    gyro, accel = np.array([0.1, -0.2, 0.3]), np.array([0.0, 0.5, -9.8])
    m = estimator.imu_in_body(ImuMeasurement(1.012, gyro, accel))
    assert m.stamp_s == pytest.approx(1.0)
    assert np.allclose(m.gyro_rad_s, R_body_imu @ gyro) and np.allclose(m.accel_m_s2, R_body_imu @ accel)
    assert np.allclose(m.accel_m_s2, [0.5, 0.0, 9.8])  # upside down, turned 90 deg: gravity's reaction up
    with pytest.raises(InputError, match="R_body_imu"):
        DoubleCouplingEstimator(CameraModel.default(), R_body_imu=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InputError, match="offset"):
        DoubleCouplingEstimator(CameraModel.default(), imu_time_offset_s=5.0)
