"""What the estimator may assume of the vehicle: any (the default) or a multirotor in still air.

At hover an accelerometer bias reads as a tilt; only the vehicle's yaw turns tell them apart, unless the
vehicle is a multirotor in still air, whose body-horizontal specific force is the rotor drag alone."""

from __future__ import annotations

import numpy as np

from common.estimation.coupling_types import CouplingSettings, Vehicle, vehicle_settings
from common.estimation.replay import (
    ABLATIONS,
    CONFIGURATIONS,
    evaluate,
    run_estimators,
    standard_estimators,
)
from common.sim.flight import turns_flight
from common.sim.stream import flight_measurements


def test_any_vehicle_is_the_default_and_assumes_nothing() -> None:
    assert vehicle_settings(Vehicle.ANY) == {}
    assert CouplingSettings().thrust_axis_interval_s == 0.0


def test_still_air_multirotor_turns_the_thrust_axis_on_and_the_accelerometer_only_fallbacks_off() -> None:
    settings = CouplingSettings(**vehicle_settings(Vehicle.STILL_AIR_MULTIROTOR))
    assert settings.thrust_axis_interval_s > 0.0
    assert not settings.vision_tilt_correction
    assert not settings.origin_tilt_from_bias


def test_the_bench_flies_a_still_air_multirotor_and_keeps_the_any_vehicle_proposal_as_an_ablation() -> None:
    fields = vehicle_settings(Vehicle.STILL_AIR_MULTIROTOR)
    for name in ("rectified", "traditional"):
        assert all(CONFIGURATIONS[name][key] == value for key, value in fields.items())
    assert not set(fields) & set(ABLATIONS["rectified_any_vehicle"])
    assert "rectified_any_vehicle" not in CONFIGURATIONS  # the demo and the single-seed bench run without it


def test_still_air_multirotor_tells_an_accelerometer_bias_from_a_tilt_at_hover() -> None:
    """Paper C's flight, seed 18 (accelerometer bias 0.117 m/s^2 along body x, 2.3 sigma), its first 3 s of
    hover: without the vehicle's model the bias reads as 0.68 deg of pitch; with it, the pitch error falls."""
    flight = turns_flight(seed=18)
    bias_x = float(flight.imu.accel_bias_m_s2[0, 0])
    assert abs(bias_x) > 0.1  # the case this test is about
    names = ("rectified", "rectified_any_vehicle")
    runs = run_estimators(standard_estimators(flight, 0, names), flight_measurements(flight, 0, 61))
    # the last second of the hover (the first 2 s settle)
    pitch_error_deg = {
        name: float(evaluate(runs[name], flight, settle_s=2.0).att_rmse_deg[1]) for name in names
    }
    # the bias read as a tilt: pitch error about bias / g
    assert pitch_error_deg["rectified_any_vehicle"] > 0.5 * np.degrees(abs(bias_x) / 9.81)
    assert pitch_error_deg["rectified"] < 0.5 * pitch_error_deg["rectified_any_vehicle"], pitch_error_deg
