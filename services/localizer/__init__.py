"""``capataz localizer``: tracks a known 3D model in the camera frames (paper B's particle filter driven by
VO odometry, or the model tracker, which needs none)."""

from services.localizer.filters import odometry_between, pose_message
from services.localizer.service import LocalizerService, register
from services.localizer.settings import LocalizerKind, LocalizerSettings

__all__ = [
    "LocalizerKind",
    "LocalizerService",
    "LocalizerSettings",
    "odometry_between",
    "pose_message",
    "register",
]
