"""Particle filter: resampling, circular means, prediction, collapse, baseline equality, a short flight."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.geometry import matrix_from_euler, quaternion_from_matrix, rotation_vector_from_quaternion
from common.localization.baseline import weigh_per_particle
from common.localization.model import SceneModel
from common.localization.odometry import noisy_odometry
from common.localization.particle_filter import (
    ParticleFilter,
    ParticleFilterSettings,
    ParticleState,
    covariance_with_world_error_angles,
    euler_rate_matrix,
    low_variance_resample,
    normalise_log_weights,
    pose_statistics,
)
from common.localization.scoring import ScoringMethod, ScoringSettings, extract_image_edges
from common.localization.tracking import track_accuracy, track_flight
from common.sim.scene import DEFAULT_FLIGHT_RENDER, default_flight, render_flight, render_scene


def test_low_variance_resampling_copies_a_certain_particle_and_keeps_uniform_ones() -> None:
    rng = np.random.default_rng(0)
    one_hot = np.zeros(10)
    one_hot[7] = 1.0
    assert np.all(low_variance_resample(one_hot, rng) == 7)
    assert np.array_equal(low_variance_resample(np.full(10, 0.1), rng), np.arange(10))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.01, 1.0), min_size=5, max_size=50), st.integers(0, 1000))
def test_low_variance_resampling_draws_each_particle_in_proportion(raw: list[float], seed: int) -> None:
    weights = np.asarray(raw) / np.sum(raw)
    index = low_variance_resample(weights, np.random.default_rng(seed))
    counts = np.bincount(index, minlength=weights.size)
    # systematic resampling: each count is floor or ceil of N w
    assert np.all(np.abs(counts - weights.size * weights) < 1.0 + 1e-9)


def test_circular_mean_of_angles_across_the_wrap() -> None:
    particles = np.zeros((4, 6))
    particles[:, 5] = np.radians([179.0, -179.0, 178.0, -178.0])
    particles[:, 0] = [1.0, 2.0, 3.0, 4.0]
    mean, covariance = pose_statistics(particles, np.full(4, 0.25))
    assert abs(abs(mean[5]) - np.pi) < 1e-9
    assert mean[0] == pytest.approx(2.5)
    assert np.sqrt(covariance[5, 5]) == pytest.approx(np.radians(np.sqrt((1 + 1 + 4 + 4) / 4)), rel=1e-6)
    assert np.allclose(covariance, covariance.T)


def test_normalised_log_weights_sum_to_one_and_survive_all_minus_infinity() -> None:
    w = normalise_log_weights(np.array([-1000.0, -1001.0, -np.inf]))
    assert np.exp(w).sum() == pytest.approx(1.0)
    assert np.allclose(np.exp(normalise_log_weights(np.full(4, -np.inf))), 0.25)


def test_prediction_follows_paper_b_motion_model_and_seeded_noise(
    office: SceneModel, small_camera: CameraModel
) -> None:
    quiet = ParticleFilter(
        office,
        small_camera,
        ParticleFilterSettings(n_particles=5, position_noise_m=0.0, angle_noise_rad=(0, 0, 0)),
    )
    state = quiet.initialize([5.0, 4.0, 1.5, 0.0, 0.0, 0.0], np.random.default_rng(1))
    moved = quiet.predict(state, 0.5, np.random.default_rng(2), velocity_world_m_s=[1.0, -2.0])
    assert np.allclose(moved.particles - state.particles, [0.5, -1.0, 0.0, 0.0, 0.0, 0.0])
    assert np.array_equal(moved.log_weights, state.log_weights)
    noisy = ParticleFilter(office, small_camera, ParticleFilterSettings(n_particles=5))
    a = noisy.predict(state, 0.1, np.random.default_rng(3))
    b = noisy.predict(state, 0.1, np.random.default_rng(3))
    assert np.array_equal(a.particles, b.particles)
    assert not np.array_equal(a.particles, state.particles)
    with pytest.raises(InputError, match="velocity"):
        noisy.predict(state, 0.1, np.random.default_rng(3), velocity_world_m_s=[np.nan, 0.0])
    with pytest.raises(InputError, match="dt_s"):
        noisy.predict(state, -1.0, np.random.default_rng(3))


def test_vectorised_weighting_equals_the_per_particle_baseline(
    office: SceneModel, small_camera: CameraModel
) -> None:
    rng = np.random.default_rng(4)
    truth = np.array([5.0, 3.0, 1.4, 0.02, -0.03, 2.0])
    edges = extract_image_edges(render_scene(office, truth, small_camera, DEFAULT_FLIGHT_RENDER, rng))
    for method in ScoringMethod:
        pf = ParticleFilter(
            office, small_camera, ParticleFilterSettings(n_particles=40, scoring=ScoringSettings(method))
        )
        state = pf.initialize(truth, rng)
        fast, fast_score = pf.weigh(state, edges)
        slow, slow_score = weigh_per_particle(pf, state, edges)
        assert np.allclose(fast_score.log_weight, slow_score.log_weight, atol=1e-9)
        assert np.allclose(fast.log_weights, slow.log_weights, atol=1e-9)


def test_resampling_happens_only_when_the_effective_sample_size_drops(
    office: SceneModel, small_camera: CameraModel
) -> None:
    pf = ParticleFilter(office, small_camera, ParticleFilterSettings(n_particles=8))
    rng = np.random.default_rng(5)
    state = pf.initialize([5.0, 4.0, 1.5, 0.0, 0.0, 0.0], rng)
    assert pf.resample_if_degenerate(state, rng) is state
    skewed = replace(state, log_weights=normalise_log_weights(np.array([0.0] + [-50.0] * 7)))
    resampled = pf.resample_if_degenerate(skewed, rng)
    assert np.allclose(resampled.particles, state.particles[0])
    assert resampled.effective_sample_size == pytest.approx(8.0)


def test_collapsed_likelihood_reinitialises_around_the_estimate(
    office: SceneModel, small_camera: CameraModel
) -> None:
    config = ParticleFilterSettings(n_particles=30, collapse_frames=3)
    pf = ParticleFilter(office, small_camera, config)
    rng = np.random.default_rng(6)
    state: ParticleState = pf.initialize([5.0, 4.0, 1.5, 0.0, 0.0, 0.0], rng, 0.01, 0.001)
    blank = extract_image_edges(np.full(small_camera.shape, 90, dtype=np.uint8))
    for _ in range(2):
        state = pf.update(state, blank, rng)
        assert state.reinitialisations == 0
    state = pf.update(state, blank, rng)
    assert state.reinitialisations == 1
    spread = state.particles.max(axis=0) - state.particles.min(axis=0)
    assert np.all(spread[:3] > 0.5)  # back to the initial +-0.5 m


def test_short_flight_converges_from_the_initial_uncertainty(
    office: SceneModel, small_camera: CameraModel
) -> None:
    rng = np.random.default_rng(7)
    flight = default_flight(n_frames=100)
    pf = ParticleFilter(office, small_camera, ParticleFilterSettings(n_particles=200))
    guess = flight.states[0] + np.array([0.4, -0.4, 0.3, 0.1, -0.1, np.radians(-9.0)])
    odometry = noisy_odometry(flight.velocities_world_m_s, flight.euler_rates_rad_s, rng)
    images = render_flight(office, flight, small_camera, DEFAULT_FLIGHT_RENDER, rng)
    result = track_flight(pf, images, flight.times_s, guess, rng, odometry)
    accuracy = track_accuracy(result.means, flight.states, first_frame=50)
    assert np.linalg.norm(guess[:3] - flight.states[0, :3]) > 0.5
    assert accuracy.position_errors_m[0] > 2.0 * accuracy.position_rmse_m
    assert accuracy.position_rmse_m < 0.05
    assert np.degrees(accuracy.yaw_rmse_rad) < 1.0
    assert result.covariances.shape == (100, 6, 6)
    # the reported covariance shrinks as the filter converges
    assert np.trace(result.covariances[-1][:3, :3]) < 0.1 * np.trace(result.covariances[0][:3, :3])


@settings(max_examples=30, deadline=None)
@given(
    st.tuples(st.floats(-1.0, 1.0), st.floats(-1.2, 1.2), st.floats(-3.1, 3.1)),
    st.tuples(*(st.floats(-1.0, 1.0) for _ in range(3))),
)
def test_euler_rate_matrix_maps_small_euler_changes_to_world_rotation_vectors(
    euler: tuple[float, float, float], direction: tuple[float, float, float]
) -> None:
    e = np.asarray(euler)
    delta = 1e-6 * np.asarray(direction)
    R0 = matrix_from_euler(*e)
    R1 = matrix_from_euler(*(e + delta))
    dtheta = rotation_vector_from_quaternion(quaternion_from_matrix(R1 @ R0.T))
    assert np.allclose(dtheta, euler_rate_matrix(e) @ delta, atol=1e-11)
    cov = covariance_with_world_error_angles(np.r_[0, 0, 0, e], np.diag([1.0, 2.0, 3.0, 1e-4, 2e-4, 3e-4]))
    assert np.allclose(cov[:3, :3], np.diag([1.0, 2.0, 3.0]))
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)
