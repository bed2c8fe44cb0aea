"""The embedded default run of the localizer: the built-in office, its default flight, a small camera.

Shared by the demo, the benchmark and the service tests so that they all see the same frames, the same
initial guess (within +-0.5 m and +-10 deg of the truth) and the same odometry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.camera import CameraModel
from common.localization.model import SceneModel
from common.localization.odometry import Odometry, noisy_odometry
from common.localization.office import default_scene, office_camera
from common.localization.particle_filter import ParticleFilter, ParticleFilterSettings
from common.localization.tracking import TrackResult, track_flight
from common.sim.scene import DEFAULT_FLIGHT_RENDER, SceneFlight, default_flight, render_flight
from common.types import FloatArray, U8Array

#: The localizer's default camera: 320 x 240 px, 70 deg horizontal field of view, forward-looking.
#: Initial uncertainty of the default run (each position axis, each angle).
INITIAL_POSITION_ERROR_M = 0.5
INITIAL_ANGLE_ERROR_RAD = float(np.radians(10.0))


@dataclass(frozen=True)
class SimulatedRun:
    """Frames of a flight through a scene with its truth, an initial guess and noisy odometry."""

    scene: SceneModel
    camera: CameraModel
    flight: SceneFlight
    images: tuple[U8Array, ...]
    guess: FloatArray
    odometry: Odometry


def simulate_run(n_frames: int = 300, seed: int = 0, camera: CameraModel | None = None) -> SimulatedRun:
    """Render the default flight through the office; the guess is the first true pose plus a uniform error
    within +-0.5 m per axis and +-10 deg per angle."""
    rng = np.random.default_rng(seed)
    cam = camera or office_camera()
    scene = default_scene()
    flight = default_flight(n_frames=n_frames)
    images = tuple(render_flight(scene, flight, cam, DEFAULT_FLIGHT_RENDER, rng))
    error = rng.uniform(-1.0, 1.0, 6) * np.array(
        [INITIAL_POSITION_ERROR_M] * 3 + [INITIAL_ANGLE_ERROR_RAD] * 3
    )
    odometry = noisy_odometry(flight.velocities_world_m_s, flight.euler_rates_rad_s, rng)
    return SimulatedRun(
        scene=scene,
        camera=cam,
        flight=flight,
        images=images,
        guess=flight.states[0] + error,
        odometry=odometry,
    )


def track_run(run: SimulatedRun, config: ParticleFilterSettings, seed: int = 1) -> TrackResult:
    """The particle filter over a simulated run (its own seeded RNG)."""
    pf = ParticleFilter(run.scene, run.camera, config)
    return track_flight(
        pf, run.images, run.flight.times_s, run.guess, np.random.default_rng(seed), run.odometry
    )
