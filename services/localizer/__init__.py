"""``capataz localizer``: tracks a known 3D model in the camera frames (paper B, without odometry)."""

from services.localizer.service import LocalizerService, odometry_between, pose_message, register
from services.localizer.settings import LocalizerSettings

__all__ = ["LocalizerService", "LocalizerSettings", "odometry_between", "pose_message", "register"]
