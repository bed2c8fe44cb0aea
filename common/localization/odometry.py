"""Per-frame motion hints for the localizer's prediction, and the simulated stand-in for them.

Its own module, apart from the particle filter, so that a process that only simulates them (the camera's
``pose/vo`` for the localizer) does not load the filter and its compiled kernels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.types import FloatArray


@dataclass(frozen=True)
class Odometry:
    """Per-frame motion hints for the prediction: world velocity (T, 3) m/s and Euler rates (T, 3) rad/s."""

    velocities_world_m_s: FloatArray
    euler_rates_rad_s: FloatArray


def noisy_odometry(
    velocities_world_m_s: FloatArray,
    euler_rates_rad_s: FloatArray,
    rng: np.random.Generator,
    velocity_sigma_m_s: float = 0.05,
    rate_sigma_rad_s: float = 0.02,
) -> Odometry:
    """Ground-truth rates plus white noise: a stand-in for the estimator's odometry."""
    return Odometry(
        velocities_world_m_s=velocities_world_m_s
        + rng.normal(0.0, velocity_sigma_m_s, velocities_world_m_s.shape),
        euler_rates_rad_s=euler_rates_rad_s + rng.normal(0.0, rate_sigma_rad_s, euler_rates_rad_s.shape),
    )
