"""Shared fixtures of the localizer tests: the built-in scene and a small camera."""

from __future__ import annotations

import pytest

from common.camera import CameraModel
from common.localization.model import SceneModel, default_scene


@pytest.fixture(scope="session")
def office() -> SceneModel:
    return default_scene()


@pytest.fixture(scope="session")
def small_camera() -> CameraModel:
    return CameraModel.from_hfov(320, 240, 70.0)
