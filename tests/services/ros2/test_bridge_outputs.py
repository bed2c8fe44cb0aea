"""The ROS messages the bridge fills from capataz estimates (real rclpy message classes; no graph needed):
fields, covariances, "not provided" markers, and an estimate that cannot be a ROS message refused."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np
import pytest

from common.errors import InputError
from common.wire.messages import AttitudeEstimate, PoseEstimate, YawEstimate
from services.ros2 import extra_installed
from services.ros2.bridge import Ros2Bridge
from services.ros2.dds import dds_environment, random_domain_id, write_profile
from services.ros2.settings import Ros2Settings
from services.runtime.transport import TransportSettings

NO_EXTRA = "ros2 extra not installed (pip install 'capataz[ros2]')"
pytestmark = [pytest.mark.ros2, pytest.mark.skipif(not extra_installed(), reason=NO_EXTRA)]


@pytest.fixture
def bridge() -> Ros2Bridge:
    return Ros2Bridge("ros2", 0, TransportSettings(), Ros2Settings())


def test_attitude_fills_an_imu_message_with_orientation_and_covariance_only(bridge: Ros2Bridge) -> None:
    covariance = np.diag([1e-4, 2e-4, 3e-4]) + 1e-6
    estimate = AttitudeEstimate(
        uav="uav2",
        seq=5,
        stamp_s=7.000000001,
        q_world_body=np.array([0.5, 0.5, -0.5, 0.5]),
        covariance=covariance,
    )
    imu = bridge._ros_message("attitude", estimate)
    assert type(imu).__name__ == "Imu"
    assert (imu.header.stamp.sec, imu.header.stamp.nanosec, imu.header.frame_id) == (7, 1, "uav2/world")
    q = imu.orientation
    assert (q.x, q.y, q.z, q.w) == (0.5, -0.5, 0.5, 0.5)
    assert np.array_equal(np.asarray(imu.orientation_covariance), covariance.reshape(9))
    assert imu.angular_velocity_covariance[0] == imu.linear_acceleration_covariance[0] == -1.0


def test_a_pose_fills_pose_with_covariance_stamped(bridge: Ros2Bridge) -> None:
    covariance = np.diag(np.arange(1.0, 7.0)) * 1e-3
    estimate = PoseEstimate(
        uav="uav0", seq=1, stamp_s=2.5, p_world_body_m=np.array([1.0, 2.0, 3.0]),
        q_world_body=np.array([1.0, 0.0, 0.0, 0.0]), covariance=covariance, source="vo",
    )  # fmt: skip
    pose = bridge._ros_message("pose/vo", estimate)
    assert type(pose).__name__ == "PoseWithCovarianceStamped"
    p = pose.pose.pose.position
    assert (p.x, p.y, p.z) == (1.0, 2.0, 3.0) and pose.header.frame_id == "uav0/world"
    assert np.array_equal(np.asarray(pose.pose.covariance), covariance.reshape(36))
    assert bridge._ros_message("pose/pf", estimate).header.frame_id == "uav0/map"


def test_an_estimate_stamped_before_the_epoch_is_no_ros_message(bridge: Ros2Bridge) -> None:
    estimate = YawEstimate(
        uav="uav0", seq=1, stamp_s=-1.0, delta_yaw_rad=0.0, yaw_rad=0.1, inlier_count=3, patch_count=4,
        confidence=1.0, low_confidence=False, method="t",
    )  # fmt: skip
    with pytest.raises(InputError, match="ROS time"):
        bridge._ros_message("yaw", estimate)


@pytest.mark.parametrize("tf2_msgs_importable", [True, False])
def test_the_mount_goes_to_tf_static_with_tf2_msgs_and_a_warning_without(
    tf2_msgs_importable: bool,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    domain = random_domain_id()
    profile = write_profile(tmp_path / "fastdds.xml")
    for name, value in dds_environment(profile, domain).items():  # restored after the test
        monkeypatch.setenv(name, value)
    if not tf2_msgs_importable:
        monkeypatch.setitem(sys.modules, "tf2_msgs.msg", None)  # as without the built package
    settings = Ros2Settings(uavs=("uav3",), domain_id=domain, dds_profile=profile)
    bridge = Ros2Bridge("ros2", 0, TransportSettings(), settings)
    bridge._open_ros()
    try:
        with caplog.at_level(logging.WARNING, logger="services.ros2.bridge"):
            bridge._publish_mount("uav3")
        topics = dict(bridge.ros_node.get_topic_names_and_types())
    finally:
        bridge.ros_node.destroy_node()
        bridge.context.try_shutdown()
    assert topics["/uav3/capataz/camera_mount"] == ["geometry_msgs/msg/TransformStamped"]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    if tf2_msgs_importable:
        assert topics["/tf_static"] == ["tf2_msgs/msg/TFMessage"] and warnings == []
    else:
        assert "/tf_static" not in topics
        assert warnings == [
            "no /tf_static for uav3: tf2_msgs is not importable (capataz ros2 --build-tf2-msgs builds it)"
        ]
