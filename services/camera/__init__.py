"""``capataz camera``: publishes a simulated flight (frames, IMU, rangefinder) or a folder of images."""

from services.camera.service import CameraService, CameraSettings, register
from services.camera.simulated import simulated_flight

__all__ = ["CameraService", "CameraSettings", "register", "simulated_flight"]
