"""Shared fixtures of the localizer tests: the built-in scene and a small camera."""

from __future__ import annotations

import pytest

from common.localization.model import SceneModel, default_scene
from common.sim.camera import PinholeCamera


@pytest.fixture(scope="session")
def office() -> SceneModel:
    return default_scene()


@pytest.fixture(scope="session")
def small_camera() -> PinholeCamera:
    return PinholeCamera.from_hfov(320, 240, 70.0)
