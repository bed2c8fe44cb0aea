"""The localizer's files, read at the service's boundary: its model (scene) and its camera.

The settings hold values (paths among them); these read them, once, when the service sets up (or a test
builds the same filters in process).
"""

from __future__ import annotations

from common.camera import CameraModel
from common.datasets.models import load_model
from common.localization.model import SceneModel
from common.localization.office import default_scene, office_camera
from services.localizer.settings import LocalizerSettings
from services.runtime.camera_options import load_camera


def load_scene(settings: LocalizerSettings) -> SceneModel:
    """The model file of ``settings`` (scaled to metres), or the built-in office."""
    if settings.model is None:
        return default_scene()
    return load_model(settings.model, settings.model_scale)


def localizer_camera(settings: LocalizerSettings) -> CameraModel:
    """The camera of ``settings``' camera options; nothing given: the simulated office camera."""
    camera = load_camera(settings.camera, office_camera())
    assert camera is not None  # a default is given
    return camera
