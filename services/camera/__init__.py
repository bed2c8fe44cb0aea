"""``capataz camera``: publishes a simulated flight (frames, IMU, rangefinder) or a folder of images."""

from services.camera.flights import simulated_flight
from services.camera.service import CameraService, register
from services.camera.settings import CameraSettings

__all__ = ["CameraService", "CameraSettings", "register", "simulated_flight"]
