"""Particle filter of paper B: pose hypotheses ``X = (x, y, z, alpha, beta, gamma)`` weighed against images.

Explicit state in, state out::

    pf = ParticleFilter(scene, camera, ParticleFilterSettings())
    state = pf.initialize(guess, rng)
    state = pf.predict(state, dt_s, rng, velocity_world_m_s=v)     # paper B's motion model + noise
    state, score = pf.weigh(state, extract_image_edges(image))    # project, score, weight
    state = pf.resample_if_degenerate(state, rng)                 # low-variance, when ESS drops
    estimate = pf.estimate(state)                                 # circular mean + covariance

:meth:`ParticleFilter.update` chains weigh, re-initialisation when the likelihood collapses, and resampling.
``alpha, beta, gamma`` are roll, pitch, yaw (ZYX Euler angles of ``R_world_body``, rad).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from common.bounds import bounded, check_duration
from common.camera import CameraModel
from common.errors import CapatazError, InputError
from common.geometry import R_BODY_CAMERA_FORWARD, wrap_angle_rad
from common.localization.model import SceneModel
from common.localization.projection import (
    NEAR_PLANE_M,
    EdgeSamples,
    check_states,
    project_samples,
    sample_edges,
)
from common.localization.scoring import (
    ImageEdges,
    ParticleSettings,
    ScoreResult,
    ScoringMethod,
    ScoringSettings,
    score_particles,
)
from common.types import FloatArray

logger = logging.getLogger(__name__)


class ParticleFilterError(CapatazError):
    """The particle filter was given an inconsistent state or configuration."""


@dataclass(frozen=True)
class ParticleFilterSettings(ParticleSettings):
    """Settings of :class:`ParticleFilter` (the particles' own in :class:`ParticleSettings`).

    Noise is a random walk added at every prediction: standard deviation ``noise * sqrt(dt_s)`` per
    component (position m/sqrt(s); roll, pitch, yaw rad/sqrt(s)). While the best particle's fit is below
    ``good_fit`` the noise grows by up to ``search_gain`` (a wider search until the edges line up).
    On the first frame after (re-)initialisation ``init_candidates`` poses from the prior box are scored
    and ``n_particles`` of them kept (0 disables this). Particles are scored in blocks of
    ``chunk_particles`` (cache-sized temporaries).
    """

    position_noise_m: float = bounded(0.04, ge=0.0)
    angle_noise_rad: tuple[float, float, float] = (0.015, 0.015, 0.02)
    good_fit: float = bounded(0.75)
    search_gain: float = bounded(3.0, ge=0.0)
    resample_ess_fraction: float = bounded(0.5, gt=0.0, le=1.0)
    init_candidates: int = bounded(4000, ge=0)
    collapse_fit: float = bounded(0.15)
    collapse_frames: int = bounded(5, ge=1)
    init_position_spread_m: float = bounded(0.5, ge=0.0)
    init_angle_spread_rad: float = bounded(float(np.radians(10.0)), ge=0.0)
    near_m: float = bounded(NEAR_PLANE_M, gt=0.0)
    R_body_camera: FloatArray = field(default_factory=lambda: R_BODY_CAMERA_FORWARD.copy())

    def __post_init__(self) -> None:
        super().__post_init__()
        if min(self.angle_noise_rad) < 0.0:
            raise InputError("noise levels must be non-negative")


@dataclass(frozen=True)
class ParticleState:
    """Particles (P, 6), their normalised log weights (P,), the last best fit and collapse bookkeeping.

    A freshly initialised state keeps its prior box (``prior_centre +- prior_spread``) until its first frame
    (``frames == 0``), when :meth:`ParticleFilter.update` draws its particles afresh from many candidates.
    """

    particles: FloatArray
    log_weights: FloatArray
    best_fit: float = 1.0
    low_fit_frames: int = 0
    reinitialisations: int = 0
    frames: int = 0
    prior_centre: FloatArray | None = None
    prior_spread: FloatArray | None = None

    @property
    def weights(self) -> FloatArray:
        return np.asarray(np.exp(self.log_weights))

    @property
    def effective_sample_size(self) -> float:
        w = self.weights
        return float(1.0 / np.sum(w * w))


@dataclass(frozen=True)
class PoseStatistics:
    """Weighted pose of the particle cloud: ``mean`` (6,) with circular means of the angles, ``covariance``
    (6, 6) with angle residuals wrapped around that mean, the effective sample size and the best fit."""

    mean: FloatArray
    covariance: FloatArray
    effective_sample_size: float
    best_fit: float


def normalise_log_weights(log_weights: FloatArray) -> FloatArray:
    """Log weights shifted so that the weights sum to one (log-sum-exp); all -inf becomes uniform."""
    finite = np.isfinite(log_weights)
    if not finite.any():
        return np.full(log_weights.shape, -np.log(log_weights.size))
    top = np.max(log_weights[finite])
    total = top + np.log(np.sum(np.exp(np.where(finite, log_weights - top, -np.inf))))
    return np.asarray(np.where(finite, log_weights - total, -np.inf))


def low_variance_resample(
    weights: FloatArray, rng: np.random.Generator, n_draws: int | None = None
) -> npt.NDArray[np.intp]:
    """Low-variance (systematic) resampling: indices of ``n_draws`` (default N) draws, one uniform offset."""
    n = weights.size if n_draws is None else n_draws
    positions = (rng.uniform(0.0, 1.0 / n) + np.arange(n) / n).clip(0.0, 1.0)
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0
    return np.asarray(np.searchsorted(cumulative, positions, side="left").clip(0, weights.size - 1))


def pose_statistics(particles: FloatArray, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Weighted mean (positions arithmetic, angles circular) and covariance with wrapped angle residuals."""
    w = weights / np.sum(weights)
    mean = np.empty(6)
    mean[:3] = w @ particles[:, :3]
    mean[3:] = np.arctan2(w @ np.sin(particles[:, 3:]), w @ np.cos(particles[:, 3:]))
    residual = particles - mean
    residual[:, 3:] = wrap_angle_rad(residual[:, 3:])
    covariance = (residual * w[:, None]).T @ residual
    return mean, 0.5 * (covariance + covariance.T)


def euler_rate_matrix(euler_rad: FloatArray) -> FloatArray:
    """``E`` (3, 3) with ``dtheta_world = E @ d(roll, pitch, yaw)``: how small changes of the ZYX Euler angles
    of ``R_world_body`` rotate the body, as a world-frame rotation vector (columns: the roll axis
    ``Rz Ry e_x``, the pitch axis ``Rz e_y``, the yaw axis ``e_z``)."""
    _, pitch, yaw = euler_rad
    cp, sp, cy, sy = np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])


def covariance_with_world_error_angles(mean: FloatArray, covariance: FloatArray) -> FloatArray:
    """6x6 covariance of ``(position, roll, pitch, yaw)`` mapped to ``(position, world-frame error angles)``
    (``R_true = Exp(dtheta) R_estimate``), the convention of the ``PoseEstimate`` message."""
    J = np.eye(6)
    J[3:, 3:] = euler_rate_matrix(mean[3:])
    mapped = J @ covariance @ J.T
    return np.asarray(0.5 * (mapped + mapped.T))


class ParticleFilter:
    """Particle filter against a known scene; holds only immutable precomputed data (no filter state)."""

    def __init__(
        self, scene: SceneModel, camera: CameraModel, config: ParticleFilterSettings | None = None
    ) -> None:
        self.scene = scene
        self.camera = camera
        self.config = config or ParticleFilterSettings()
        self.samples: EdgeSamples = sample_edges(scene, self.config.points_per_edge)

    # -- initialisation ---------------------------------------------------------------------------
    def initialize(
        self,
        guess: npt.ArrayLike,
        rng: np.random.Generator,
        position_spread_m: float | None = None,
        angle_spread_rad: float | None = None,
    ) -> ParticleState:
        """Particles uniform in ``guess +- spread`` (every position and angle component), equal weights."""
        centre = check_states(guess, "guess")[0]
        pos = self.config.init_position_spread_m if position_spread_m is None else position_spread_m
        ang = self.config.init_angle_spread_rad if angle_spread_rad is None else angle_spread_rad
        n = self.config.n_particles
        spread = np.array([pos, pos, pos, ang, ang, ang])
        particles = centre + rng.uniform(-1.0, 1.0, size=(n, 6)) * spread
        particles[:, 3:] = wrap_angle_rad(particles[:, 3:])
        return ParticleState(
            particles=particles, log_weights=np.full(n, -np.log(n)), prior_centre=centre, prior_spread=spread
        )

    def initialize_on_frame(
        self, state: ParticleState, edges: ImageEdges, rng: np.random.Generator
    ) -> tuple[ParticleState, ScoreResult]:
        """First frame after (re-)initialisation: score ``init_candidates`` poses drawn from the prior box and
        keep ``n_particles`` of them by low-variance resampling of their weights (importance sampling of the
        prior with the first frame's likelihood; the default particles alone cover a 6D box too thinly)."""
        if state.prior_centre is None or state.prior_spread is None:
            raise ParticleFilterError("initialize_on_frame needs a state made by initialize()")
        n = state.particles.shape[0]
        extra = max(self.config.init_candidates - n, 0)
        drawn = state.prior_centre + rng.uniform(-1.0, 1.0, size=(extra, 6)) * state.prior_spread
        candidates = np.vstack([state.particles, drawn])
        candidates[:, 3:] = wrap_angle_rad(candidates[:, 3:])
        result = self.score(candidates, edges)
        weights = np.exp(normalise_log_weights(result.log_weight))
        chosen = low_variance_resample(weights, rng, n)
        seeded = replace(
            state,
            particles=candidates[chosen],
            log_weights=np.full(n, -np.log(n)),
            best_fit=float(np.max(result.fit)),
            frames=1,
            prior_centre=None,
            prior_spread=None,
        )
        return seeded, result

    # -- prediction -------------------------------------------------------------------------------
    def motion_model(
        self,
        particles: FloatArray,
        dt_s: float,
        velocity_world_m_s: npt.ArrayLike | None = None,
        euler_rates_rad_s: npt.ArrayLike | None = None,
    ) -> FloatArray:
        """Paper B's prediction ``X(t + dt) = X(t) + dt (xdot, ydot, 0, 0, 0, 0)``; optional odometry
        extends it with a vertical velocity (third component of ``velocity_world_m_s``) and Euler rates."""
        moved = particles.copy()
        if velocity_world_m_s is not None:
            velocity = np.asarray(velocity_world_m_s, dtype=np.float64)
            if velocity.shape not in ((2,), (3,)) or not np.all(np.isfinite(velocity)):
                raise InputError(
                    f"velocity_world_m_s must be finite with shape (2,) or (3,), got {velocity.shape}"
                )
            moved[:, : velocity.size] += dt_s * velocity
        if euler_rates_rad_s is not None:
            rates = np.asarray(euler_rates_rad_s, dtype=np.float64)
            if rates.shape != (3,) or not np.all(np.isfinite(rates)):
                raise InputError(f"euler_rates_rad_s must be finite with shape (3,), got {rates.shape}")
            moved[:, 3:] += dt_s * rates
        return moved

    def predict(
        self,
        state: ParticleState,
        dt_s: float,
        rng: np.random.Generator,
        velocity_world_m_s: npt.ArrayLike | None = None,
        euler_rates_rad_s: npt.ArrayLike | None = None,
    ) -> ParticleState:
        """Motion model plus random-walk noise (wider while the fit is poor); weights unchanged."""
        check_duration(dt_s)
        cfg = self.config
        moved = self.motion_model(state.particles, dt_s, velocity_world_m_s, euler_rates_rad_s)
        widen = 1.0 + cfg.search_gain * max(0.0, cfg.good_fit - state.best_fit) / max(cfg.good_fit, 1e-9)
        sigma = widen * np.sqrt(dt_s) * np.array([cfg.position_noise_m] * 3 + list(cfg.angle_noise_rad))
        moved += rng.normal(size=moved.shape) * sigma
        moved[:, 3:] = wrap_angle_rad(moved[:, 3:])
        prior = state.prior_centre
        if prior is not None:
            prior = self.motion_model(prior[None, :], dt_s, velocity_world_m_s, euler_rates_rad_s)[0]
        return replace(state, particles=moved, prior_centre=prior)

    # -- measurement ------------------------------------------------------------------------------
    def score(
        self, particles: FloatArray, edges: ImageEdges, scoring: ScoringSettings | None = None
    ) -> ScoreResult:
        """Project and score every particle at once (the vectorised weighting step without the update).

        Particles go through in blocks of ``chunk_particles`` so that the (particles x points) temporaries
        stay in the CPU cache; the scores do not depend on the blocking.
        """
        params = scoring or self.config.scoring
        chunk = max(1, self.config.chunk_particles)
        results = [
            score_particles(
                project_samples(
                    self.samples,
                    particles[start : start + chunk],
                    self.camera,
                    self.config.R_body_camera,
                    self.config.near_m,
                    with_normals=params.method is ScoringMethod.NEAREST_EDGE,
                ),
                edges,
                params,
            )
            for start in range(0, particles.shape[0], chunk)
        ]
        if len(results) == 1:
            return results[0]
        return ScoreResult(
            log_weight=np.concatenate([r.log_weight for r in results]),
            fit=np.concatenate([r.fit for r in results]),
        )

    def weigh(self, state: ParticleState, edges: ImageEdges) -> tuple[ParticleState, ScoreResult]:
        """One full weighting step: project, score, multiply into the weights (log domain), normalise."""
        if edges.width != self.camera.width or edges.height != self.camera.height:
            raise InputError(
                f"image edges are {edges.width}x{edges.height}, "
                f"the camera is {self.camera.width}x{self.camera.height}"
            )
        result = self.score(state.particles, edges)
        log_weights = normalise_log_weights(state.log_weights + result.log_weight)
        return replace(state, log_weights=log_weights, best_fit=float(np.max(result.fit))), result

    def resample_if_degenerate(self, state: ParticleState, rng: np.random.Generator) -> ParticleState:
        """Low-variance resampling when the effective sample size drops below the configured fraction."""
        n = state.particles.shape[0]
        if state.effective_sample_size >= self.config.resample_ess_fraction * n:
            return state
        index = low_variance_resample(state.weights, rng)
        return replace(state, particles=state.particles[index], log_weights=np.full(n, -np.log(n)))

    def update(self, state: ParticleState, edges: ImageEdges, rng: np.random.Generator) -> ParticleState:
        """Weigh against a frame; re-initialise around the estimate when the likelihood collapsed for
        ``collapse_frames`` frames in a row; resample when degenerate."""
        if state.frames == 0 and state.prior_centre is not None and self.config.init_candidates > 0:
            seeded, _ = self.initialize_on_frame(state, edges, rng)
            low = 1 if seeded.best_fit < self.config.collapse_fit else 0
            return replace(seeded, low_fit_frames=state.low_fit_frames + low if low else 0)
        weighed, _ = self.weigh(state, edges)
        weighed = replace(weighed, frames=weighed.frames + 1)
        low = weighed.low_fit_frames + 1 if weighed.best_fit < self.config.collapse_fit else 0
        if low >= self.config.collapse_frames:
            estimate = self.estimate(weighed)
            logger.warning(
                "likelihood collapsed (best fit %.3f for %d frames): re-initialising", weighed.best_fit, low
            )
            fresh = self.initialize(estimate.mean, rng)
            return replace(fresh, best_fit=weighed.best_fit, reinitialisations=state.reinitialisations + 1)
        return self.resample_if_degenerate(replace(weighed, low_fit_frames=low), rng)

    def estimate(self, state: ParticleState) -> PoseStatistics:
        """Weighted pose mean (circular for angles) and covariance of the cloud."""
        mean, covariance = pose_statistics(state.particles, state.weights)
        return PoseStatistics(
            mean=mean,
            covariance=covariance,
            effective_sample_size=state.effective_sample_size,
            best_fit=state.best_fit,
        )
