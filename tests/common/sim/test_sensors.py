"""Sensors: IMU noise and bias statistics, geometric rangefinder, image degradation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.errors import InputError
from common.geometry import matrix_from_euler
from common.sim.sensors import (
    NORMAL_QUANTILES_8BIT,
    ImageDegradation,
    ImuNoise,
    RangeNoise,
    SensorError,
    ray_ground_distance,
    sample_stamps,
    simulate_imu,
    simulate_range,
)
from common.sim.trajectory import hover_trajectory, turns_trajectory

HOVER = hover_trajectory(seed=0)
TURNS = turns_trajectory(seed=0)


def test_imu_noise_and_bias_match_the_settings() -> None:
    noise = ImuNoise()
    stamps = sample_stamps(100.0, 400.0)
    imu = simulate_imu(HOVER, stamps, noise, seed=3)
    assert imu.n_samples == 40001
    white_gyro = imu.gyro_rad_s - imu.true_gyro_rad_s - imu.gyro_bias_rad_s
    white_accel = imu.accel_m_s2 - imu.true_accel_m_s2 - imu.accel_bias_m_s2
    assert np.allclose(white_gyro.std(axis=0), noise.gyro_noise_density_rad_s_sqrt_hz * 20.0, rtol=0.03)
    assert np.allclose(white_accel.std(axis=0), noise.accel_noise_density_m_s2_sqrt_hz * 20.0, rtol=0.03)
    assert np.allclose(white_gyro.mean(axis=0), 0.0, atol=1e-4)
    # bias: a constant draw plus a slow walk (changes by far less than its size over 100 s)
    drift = np.abs(imu.gyro_bias_rad_s[-1] - imu.gyro_bias_rad_s[0])
    assert np.all(drift < 10 * noise.gyro_bias_walk_rad_s2_sqrt_hz * 10.0 + 1e-12)
    assert np.any(np.abs(imu.gyro_bias_rad_s[0]) > 1e-4)
    # a stationary-ish gyro averages to its bias
    assert np.allclose(
        (imu.gyro_rad_s - imu.true_gyro_rad_s).mean(axis=0), imu.gyro_bias_rad_s.mean(axis=0), atol=5e-5
    )


def test_ideal_imu_reads_the_truth() -> None:
    imu = simulate_imu(TURNS, sample_stamps(50.0, 400.0), ImuNoise.ideal(), seed=0)
    assert np.array_equal(imu.gyro_rad_s, imu.true_gyro_rad_s)
    assert np.array_equal(imu.accel_m_s2, imu.true_accel_m_s2)


def test_imu_at_any_rate_samples_the_same_continuous_truth() -> None:
    fast = simulate_imu(HOVER, sample_stamps(2.0, 1000.0), ImuNoise.ideal(), seed=0)
    slow = simulate_imu(HOVER, sample_stamps(2.0, 400.0), ImuNoise.ideal(), seed=0)
    # common stamps k/200 s: identical truth regardless of the rate
    assert np.allclose(fast.true_gyro_rad_s[::5], slow.true_gyro_rad_s[::2], atol=1e-12)


@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-np.pi, np.pi), st.floats(0.2, 10.0))
def test_rangefinder_ray_hits_the_ground_and_is_longer_when_tilted(
    roll: float, pitch: float, yaw: float, altitude: float
) -> None:
    R = matrix_from_euler(roll, pitch, yaw)
    p = np.array([1.0, -2.0, altitude])
    distance = ray_ground_distance(R, p)[0]
    hit = p + distance * (R @ [0.0, 0.0, -1.0])
    assert hit[2] == pytest.approx(0.0, abs=1e-9)
    assert distance >= altitude - 1e-12
    if max(abs(roll), abs(pitch)) > 0.01:
        assert distance > altitude * (1.0 + 1e-5)


def test_flight_rangefinder_is_longer_than_the_altitude_when_tilted() -> None:
    ranges = simulate_range(TURNS, sample_stamps(50.0, 50.0), RangeNoise.ideal(), seed=0)
    assert ranges.n_samples == 2501
    tilted = ranges.true_range_m - ranges.true_pz_m
    assert np.all(tilted >= -1e-12)
    assert tilted.max() > 1e-3
    noisy = simulate_range(TURNS, sample_stamps(50.0, 50.0), RangeNoise(sigma_m=0.02), seed=0)
    assert (noisy.range_m - noisy.true_range_m).std() == pytest.approx(0.02, rel=0.1)


def test_rangefinder_rejects_impossible_geometry() -> None:
    with pytest.raises(SensorError):
        ray_ground_distance(matrix_from_euler(0.0, 1.7, 0.0), [0.0, 0.0, 1.0])
    with pytest.raises(SensorError):
        ray_ground_distance(np.eye(3), [0.0, 0.0, -1.0])


def test_image_degradation_noise_level_determinism_and_clean() -> None:
    flat = np.full((480, 752), 100, np.uint8)
    mild = ImageDegradation()
    a = mild.apply(flat, t_s=1.0, seed=0, frame_index=20)
    b = mild.apply(flat, t_s=1.0, seed=0, frame_index=20)
    c = mild.apply(flat, t_s=1.0, seed=0, frame_index=21)
    assert a.tobytes() == b.tobytes() and a.tobytes() != c.tobytes()
    expected_sigma = np.sqrt(mild.read_noise_dn**2 + mild.shot_noise_dn2_per_dn * 100.0)
    gain, offset = mild.exposure(1.0, seed=0)
    assert a.astype(float).mean() == pytest.approx(100.0 * gain + offset, abs=0.1)
    assert a.astype(float).std() == pytest.approx(expected_sigma, rel=0.05)
    assert ImageDegradation.clean().apply(flat, 1.0, 0, 20).tobytes() == flat.tobytes()


def test_exposure_drifts_slowly_within_its_bounds() -> None:
    mild = ImageDegradation()
    gains, offsets = zip(*(mild.exposure(t, seed=1) for t in np.arange(0.0, 100.0, 0.05)), strict=True)
    assert max(gains) <= 1.0 + mild.gain_amplitude + 1e-12 and min(gains) >= 1.0 - mild.gain_amplitude
    assert max(np.abs(np.diff(gains))) < 1e-3  # per frame change is tiny
    assert max(offsets) - min(offsets) > mild.offset_amplitude_dn


def test_blur_removes_fine_detail() -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (64, 64), dtype=np.uint8)
    blurred = ImageDegradation(read_noise_dn=0.0, shot_noise_dn2_per_dn=0.0, blur_sigma_px=1.5).apply(
        image, 0.0, 0, 0
    )
    assert (
        np.abs(np.diff(blurred.astype(float), axis=1)).mean()
        < 0.3 * np.abs(np.diff(image.astype(float), axis=1)).mean()
    )


def test_quantised_normal_is_standard() -> None:
    q = NORMAL_QUANTILES_8BIT
    assert q.shape == (256,)
    assert q.mean() == pytest.approx(0.0, abs=1e-12)
    assert q.std() == pytest.approx(1.0)
    assert np.all(np.diff(q) > 0.0)
    assert np.mean(np.abs(q) > 2.0) == pytest.approx(0.0455, abs=3e-3)
    assert np.mean(np.abs(q) > 1.0) == pytest.approx(0.3173, abs=1e-2)


def test_noise_is_fresh_each_frame_and_uncorrelated() -> None:
    flat = np.full((200, 300), 128, np.uint8)
    mild = ImageDegradation(gain_amplitude=0.0, offset_amplitude_dn=0.0)
    a = mild.apply(flat, 0.0, 0, 1).astype(float) - 128.0
    b = mild.apply(flat, 0.0, 0, 2).astype(float) - 128.0
    assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.02
    # and spatially white
    assert abs(np.corrcoef(a[:, 1:].ravel(), a[:, :-1].ravel())[0, 1]) < 0.02


def test_settings_are_validated() -> None:
    with pytest.raises(InputError):
        ImuNoise(gyro_noise_density_rad_s_sqrt_hz=-1.0)
    with pytest.raises(InputError):
        RangeNoise(sigma_m=float("nan"))
    with pytest.raises(InputError):
        ImageDegradation(gain_amplitude=1.5)
    with pytest.raises(InputError):
        ImageDegradation().apply(np.zeros((4, 4), np.float32), 0.0, 0, 0)
    with pytest.raises(InputError):
        sample_stamps(1.0, 0.0)
