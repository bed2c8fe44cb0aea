"""Issue 30's end to end: a real rclpy node (its own process) flies a simulated hover flight into ROS 2
topics; the bridge brings it onto uav0's capataz streams, the master (one worker) and the estimator compute
from them, and the node receives yaw, attitude and pose/vo (and a pose/pf a capataz client publishes) on ROS 2
with the values a capataz client receives on Zenoh; the camera mount arrives as a static transform on its
own topic and on ``/tf_static`` (a ``tf2_msgs/TFMessage`` of the package services/ros2/tf2_msgs_build.py
builds, with the type hash of ROS 2's own tf2_msgs). DDS stays on loopback (the profile of
services/ros2/dds.py, a random domain per run)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.dispatch import Balance
from common.geometry import R_BODY_CAMERA_DOWN, matrix_from_quaternion
from common.members import Role
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import AttitudeEstimate, Health, PoseEstimate, YawEstimate
from services.master.service import Topology
from services.ros2 import extra_installed
from services.ros2.dds import LOOPBACK, dds_environment, random_domain_id, write_profile
from services.ros2.tf2_msgs_build import ROS_TYPE_HASH
from services.runtime.transport import open_session, zbytes
from services.tools.up import ClusterSpec, HostSpec, LocalCluster
from tests.zenoh_helpers import wait_until

NO_EXTRA = "ros2 extra not installed (pip install 'capataz[ros2]')"
NEEDS_EXTRA = pytest.mark.skipif(not extra_installed(), reason=NO_EXTRA)
pytestmark = [pytest.mark.zenoh, pytest.mark.slow, pytest.mark.ros2, NEEDS_EXTRA]

FRAMES = 60
FPS = 10.0
UAV = "uav0"
RTOL, ATOL = 1e-6, 1e-7  # float32 resolution of values of order 1


def _ns(stamp_s: float) -> int:
    return round(stamp_s * 1e9)


def _ros_ns(item: list[Any]) -> int:
    return int(item[0]) * 1_000_000_000 + int(item[1])


def _same_rotation(q_xyzw: list[float], q_wxyz: np.ndarray) -> None:
    ros = np.array([q_xyzw[3], *q_xyzw[:3]])
    assert min(np.abs(ros - q_wxyz).max(), np.abs(ros + q_wxyz).max()) < 1e-6, (q_xyzw, q_wxyz)


def bridge_counters(session: Any) -> dict[str, int]:
    """The bridge's counters, from its health queryable."""
    for reply in session.get(keys.health_key(Role.BRIDGE, "ros2", 0), timeout=5.0):
        if reply.ok is not None:
            return dict(decode(zbytes(reply.ok.payload), zbytes(reply.ok.attachment), Health).counters)
    return {}


def _same_mount(transform: list[Any]) -> None:
    parent, child, translation, q = transform
    assert (parent, child) == (f"{UAV}/base_link", f"{UAV}/camera_optical_frame")
    assert translation == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(matrix_from_quaternion([q[3], *q[:3]]), R_BODY_CAMERA_DOWN, atol=1e-12)


def test_a_ros2_node_flies_into_capataz_and_reads_its_estimates_back(tmp_path: Path) -> None:
    if importlib.util.find_spec("tf2_msgs") is None:
        pytest.fail("tf2_msgs not built: make .venv/.installed (or python -m services.ros2.tf2_msgs_build)")
    domain = random_domain_id()
    env = dds_environment(write_profile(tmp_path / "fastdds.xml"), domain)
    zenoh_side: dict[str, dict[int, Any]] = {"yaw": {}, "attitude": {}, "pose/vo": {}}
    lock = threading.Lock()

    def collect(name: str, kind: type) -> Any:
        def on(sample: Any) -> None:
            message: Any = decode(zbytes(sample.payload), zbytes(sample.attachment), kind)
            with lock:
                zenoh_side[name][_ns(message.stamp_s)] = message

        return on

    spec = ClusterSpec(
        name="ros2",
        topology=Topology.MASTER_WORKER,
        balance=Balance.TIME,
        hosts=(HostSpec(name="h1", workers=1),),
    )
    config: dict[str, Any] = {
        "uav": UAV, "fps": FPS, "frames": FRAMES, "timeout_s": 120.0,
        "ready": str(tmp_path / "ready"), "done": str(tmp_path / "done"), "out": str(tmp_path / "ros.json"),
    }  # fmt: skip
    (tmp_path / "config.json").write_text(json.dumps(config))
    with LocalCluster(spec, tmp_path / "logs") as cluster:
        cluster.start()
        cluster.spawn("estimator/estimator/0", ["estimator", *cluster.transport_args(), "--uav", UAV])
        bridge = cluster.spawn(
            "bridge/ros2/0",
            ["ros2", *cluster.transport_args(), "--uav", UAV, "--input-uav", UAV, "--domain-id", str(domain),
             "--dds-profile", str(tmp_path / "fastdds.xml"),
             "--calibration-out", str(tmp_path / "{uav}.yml")],
        )  # fmt: skip
        cluster.wait_alive({"master/master/0", "worker/h1/0", "estimator/estimator/0", "bridge/ros2/0"})
        with open_session(cluster.observer_transport()) as session:
            subscribers = [
                session.declare_subscriber(keys.yaw_key(UAV), collect("yaw", YawEstimate)),
                session.declare_subscriber(keys.attitude_key(UAV), collect("attitude", AttitudeEstimate)),
                session.declare_subscriber(keys.pose_vo_key(UAV), collect("pose/vo", PoseEstimate)),
            ]
            pf_publisher = session.declare_publisher(keys.pose_pf_key(UAV))
            node = subprocess.Popen(
                [sys.executable, "-m", "tests.integration.ros2_node", str(tmp_path / "config.json")],
                env={**os.environ, **env},
                stdout=(tmp_path / "node.log").open("wb"),
                stderr=subprocess.STDOUT,
            )
            try:
                deadline = time.monotonic() + 120.0
                while (
                    not Path(config["ready"]).exists() and time.monotonic() < deadline and node.poll() is None
                ):
                    time.sleep(0.05)
                time.sleep(FRAMES / FPS)  # the flight's own length: the node paces it
                # the estimates of the last frames, then a localizer's pose/pf published by a capataz client
                pf = [
                    PoseEstimate(
                        uav=UAV, seq=k, stamp_s=100.0 + 0.05 * k,
                        p_world_body_m=np.array([1.0, 2.0 + k, 3.0]),
                        q_world_body=np.array([0.6, 0.0, 0.8, 0.0]),
                        covariance=np.diag(np.arange(1.0, 7.0)) * 1e-3, source="pf",
                    )
                    for k in range(5)
                ]  # fmt: skip
                for message in pf:
                    payload, attachment = encode(message)
                    pf_publisher.put(payload, attachment=attachment)
                    time.sleep(0.1)
                time.sleep(2.0)
                Path(config["done"]).write_text("done")
                node.wait(60)
                # the node's bad input after the flight: refused and counted by the bridge, one reason each
                refused = {"refused_malformed": 4, "refused_stamp_backward": 1}
                wait_until(lambda: all(bridge_counters(session).get(k) == n for k, n in refused.items()))
                counters = bridge_counters(session)
            finally:
                if node.poll() is None:
                    node.kill()
                    node.wait()
                for s in subscribers:
                    s.undeclare()
        assert bridge.poll() is None, "the bridge exited early"
        codes = cluster.stop()
    assert codes["bridge/ros2/0"] == 0, "the bridge did not stop cleanly on SIGTERM"
    assert node.returncode == 0, (tmp_path / "node.log").read_text()[-3000:]
    assert {k: counters.get(k) for k in refused} == refused, counters
    ros = json.loads(Path(config["out"]).read_text())

    # DDS stayed on loopback: every UDP socket of the ROS node is bound to 127.0.0.1
    assert ros["udp_sockets"] and {address for address, _ in ros["udp_sockets"]} == {LOOPBACK}

    with lock:
        zenoh_copy = {name: dict(items) for name, items in zenoh_side.items()}
    for name in ("yaw", "attitude", "pose/vo"):
        assert len(zenoh_copy[name]) >= 5, f"capataz computed only {len(zenoh_copy[name])} {name} estimates"
        # best effort on loopback: nearly all arrive; every one that arrives carries the same values
        assert len(ros[name]) >= 0.8 * len(zenoh_copy[name]), (name, len(ros[name]), len(zenoh_copy[name]))
    for item in ros["yaw"]:
        z = zenoh_copy["yaw"][_ros_ns(item)]
        assert item[2] == f"{UAV}/yaw_origin"
        x, y, zq, w = item[3]
        assert np.isclose(2.0 * np.arctan2(zq, w), z.yaw_rad, rtol=RTOL, atol=ATOL) or abs(z.yaw_rad) < 1e-7
        assert x == y == 0.0
        assert np.isclose(item[4][8], z.yaw_variance_rad2, rtol=RTOL, atol=ATOL)
    for item in ros["attitude"]:
        a = zenoh_copy["attitude"][_ros_ns(item)]
        assert item[2] == f"{UAV}/world"
        _same_rotation(item[3], a.q_world_body)
        np.testing.assert_allclose(item[4], a.covariance.reshape(9), rtol=RTOL, atol=ATOL)
    for item in ros["pose/vo"]:
        p = zenoh_copy["pose/vo"][_ros_ns(item)]
        assert item[2] == f"{UAV}/world"
        np.testing.assert_allclose(item[3], p.p_world_body_m, rtol=RTOL, atol=ATOL)
        _same_rotation(item[4], p.q_world_body)
        np.testing.assert_allclose(item[5], p.covariance.reshape(36), rtol=RTOL, atol=ATOL)
    assert len(ros["pose/pf"]) >= 3
    by_stamp = {_ns(m.stamp_s): m for m in pf}
    for item in ros["pose/pf"]:
        p = by_stamp[_ros_ns(item)]
        assert item[2] == f"{UAV}/map"
        np.testing.assert_allclose(item[3], p.p_world_body_m, rtol=RTOL, atol=ATOL)
        _same_rotation(item[4], p.q_world_body)
        np.testing.assert_allclose(item[5], p.covariance.reshape(36), rtol=RTOL, atol=ATOL)

    # the camera mount, static (transient local: the node joined after it was published), on its own topic
    # and on /tf_static as the one transform of a tf2_msgs/TFMessage whose type is ROS 2's own
    assert ros["mount"], "no camera mount received"
    _same_mount(ros["mount"][-1])
    assert ros["tf_static"], "nothing received on /tf_static"
    assert len(ros["tf_static"][-1]) == 1, ros["tf_static"]
    _same_mount(ros["tf_static"][-1][0])
    tf_type = ["tf2_msgs/msg/TFMessage", ROS_TYPE_HASH]
    assert ros["tf_static_publishers"] == [["capataz_bridge_ros2_0", *tf_type]], ros["tf_static_publishers"]
    # the CameraInfo became the master's kind of calibration file
    assert (tmp_path / f"{UAV}.yml").is_file()
