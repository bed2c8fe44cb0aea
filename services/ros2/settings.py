"""The bridge's settings (``capataz ros2``'s options), its ROS topic names and QoS choices."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from common.members import check_name
from services.ros2.dds import MAX_DOMAIN_ID


class Ros2Settings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    #: UAVs whose estimates go out to ROS 2 (yaw, attitude, pose/vo, pose/pf, camera mount)
    uavs: tuple[str, ...] = ("uav0",)
    #: UAVs whose sensors come in from ROS 2 (images, camera info, IMU, range) onto their capataz streams
    input_uavs: tuple[str, ...] = ()
    #: the ROS 2 domain (``ROS_DOMAIN_ID``)
    domain_id: int = Field(default=0, ge=0, le=MAX_DOMAIN_ID)
    #: a Fast DDS profile of the user's (loaded as it is; the loopback profile is written there when absent);
    #: None: the loopback profile, written to out/ros2/fastdds_loopback.xml
    dds_profile: Path | None = None
    #: write each new CameraInfo as an OpenCV YAML calibration here (for the master's --calibration)
    calibration_out: Path | None = None

    def model_post_init(self, _context: object) -> None:
        for uav in (*self.uavs, *self.input_uavs):
            check_name(uav, "uav")


def out_topic(uav: str, name: str) -> str:
    """ROS topic of an estimate of ``uav``: ``/uav0/capataz/yaw``, ``/uav0/capataz/pose/vo``, ..."""
    return f"/{uav}/capataz/{name}"


def in_topic(uav: str, name: str) -> str:
    """ROS topic a sensor of ``uav`` is read from: ``/uav0/camera/image_raw``, ``/uav0/imu``, ..."""
    return f"/{uav}/{name}"


#: sensor topics read per input UAV (topic suffix -> stream)
IN_TOPICS = {
    "image": "camera/image_raw",
    "compressed": "camera/image_raw/compressed",
    "camera_info": "camera/camera_info",
    "imu": "imu",
    "range": "range",
}
