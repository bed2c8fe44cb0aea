"""``capataz localizer``: particle-filter localization against a known 3D scene (paper B)."""

from services.localizer.service import (
    LocalizerService,
    LocalizerSettings,
    odometry_between,
    pose_message,
    register,
)

__all__ = ["LocalizerService", "LocalizerSettings", "odometry_between", "pose_message", "register"]
