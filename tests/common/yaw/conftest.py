"""Fixtures of the yaw tests: the simulator's ground texture and nadir view pairs with known truth."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from common.camera import CameraModel
from common.sim.ground import GroundTexture, make_ground_texture, nadir_camera_pose, render_ground_view

ALTITUDE_M = 1.5

PairMaker = Callable[..., tuple[np.ndarray, np.ndarray]]


@pytest.fixture(scope="session")
def texture() -> GroundTexture:
    return make_ground_texture(seed=0)


@pytest.fixture(scope="session")
def camera() -> CameraModel:
    return CameraModel.default()


@pytest.fixture(scope="session")
def nadir_pair(texture: GroundTexture, camera: CameraModel) -> PairMaker:
    """``nadir_pair(delta_yaw_deg, shift_px=(0, 0), yaw0_deg=20, altitude_ratio=1)``: two noise-free downward
    views from a level body; the second is yawed by ``delta_yaw_deg``, moved by ``shift_px`` (the ground
    distance of that many pixels along world x, y) and flown at ``altitude_ratio`` times the height."""

    def make(
        delta_yaw_deg: float,
        shift_px: tuple[float, float] = (0.0, 0.0),
        yaw0_deg: float = 20.0,
        altitude_ratio: float = 1.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        metres_per_px = ALTITUDE_M / camera.fx
        yaw0 = math.radians(yaw0_deg)
        a = render_ground_view(texture, camera, *nadir_camera_pose(0.4, -0.3, ALTITUDE_M, yaw0))
        pose_b = nadir_camera_pose(
            0.4 + shift_px[0] * metres_per_px,
            -0.3 + shift_px[1] * metres_per_px,
            ALTITUDE_M * altitude_ratio,
            yaw0 + math.radians(delta_yaw_deg),
        )
        return a, render_ground_view(texture, camera, *pose_b)

    return make
