"""Issue 15's first "done when": a simulated flight exported as a ROS 2 MCAP bag (rosbags' writer), a ROS 1
bag and a EuRoC folder replays through the cluster (master + worker) and the estimator with the same
results as the simulated camera itself, all in one deployment on 127.0.0.1.

Yaw: identical frames give identical yaw (<= 1e-9 deg). Estimator: the same attitude and pose stamps and
values within bounds (1e-4 quaternion, 1 cm): ROS's ``sensor_msgs/Range.range`` is a float32, and the
estimator keeps only its newest frame, so a frame dropped under load in one run would change its VO pairs.
Measured (2.5 fps): a second run of the simulated camera and the EuRoC folder give exactly the simulated
camera's outputs (difference 0); the ROS 1 and ROS 2 bags differ by 0.11 mm / 2.3e-5 (float32 ranges).
"""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.datasets.euroc import write_euroc
from common.datasets.rosbag_writer import write_bag
from common.dispatch import Balance
from common.sim.flight import hover_flight
from common.sim.stream import flight_measurements
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import AttitudeEstimate, PoseEstimate, YawEstimate
from services.master.service import Topology
from services.runtime.transport import open_session, zbytes
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.up import LocalCluster

pytestmark = [pytest.mark.zenoh, pytest.mark.slow, pytest.mark.long]  # shorter: test_rig_formats.py

N_FRAMES = 30
#: replay speed: 2.5 frames per second, slow enough for the estimator to take every frame on a busy host
#: (its frames are latest-wins: a frame dropped in one run and not in the other would change the VO pairs)
FPS = 2.5
#: bounds of |estimate - simulated camera's| (quaternion components; metres): see the module docstring
Q_BOUND, P_BOUND_M = 1e-4, 0.01


class _Outputs:
    """Every yaw, attitude and pose/vo estimate of one UAV, in arrival order."""

    def __init__(self, session: Any, uav: str) -> None:
        self.lock = threading.Condition()
        self.yaw: dict[int, YawEstimate] = {}
        self.attitude: list[AttitudeEstimate] = []
        self.pose: list[PoseEstimate] = []
        self.subs = [
            session.declare_subscriber(keys.yaw_key(uav), self._on(YawEstimate)),
            session.declare_subscriber(keys.attitude_key(uav), self._on(AttitudeEstimate)),
            session.declare_subscriber(keys.pose_vo_key(uav), self._on(PoseEstimate)),
        ]

    def _on(self, cls: type) -> Any:
        def handler(sample: Any) -> None:
            message: Any = decode(zbytes(sample.payload), zbytes(sample.attachment), cls)
            with self.lock:
                if isinstance(message, YawEstimate):
                    self.yaw[message.seq] = message
                elif isinstance(message, AttitudeEstimate):
                    self.attitude.append(message)
                else:
                    self.pose.append(message)
                self.lock.notify_all()

        return handler

    def counts(self) -> tuple[int, int, int]:
        with self.lock:
            return len(self.yaw), len(self.attitude), len(self.pose)

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()


def _run(cluster: LocalCluster, session: Any, name: str, camera_args: list[str], flight: Any) -> _Outputs:
    """One replay on its own UAV id with a fresh estimator; returns when every frame has a yaw and the
    estimator's outputs stopped growing (bounded)."""
    uav = f"uav-{name}"
    estimator = f"estimator/est-{name}/0"
    cluster.spawn(
        estimator,
        [
            "estimator",
            *cluster.transport_args(),
            "--node",
            f"est-{name}",
            "--uav",
            uav,
            # a queue that holds the whole flight: a busy host must not make the estimator skip frames
            # (every replay is compared with the simulated camera's frame by frame)
            "--frame-queue",
            str(2 * N_FRAMES),
            "--initial-yaw",
            repr(float(flight.yaw_rad[0])),
            "--initial-xy",
            repr(float(flight.p_world_body_m[0, 0])),
            repr(float(flight.p_world_body_m[0, 1])),
        ],
    )
    master = f"master/m-{name}/0"
    cluster.spawn(
        master,
        [
            "master",
            *cluster.transport_args(),
            "--node",
            f"m-{name}",
            "--uav",
            uav,
            "--topology",
            "master-worker",
        ],
    )
    cluster.wait_alive({estimator, master, "worker/h1/0"})
    outputs = _Outputs(session, uav)
    time.sleep(0.3)  # let the new subscribers' routes reach the router (not an assertion's wait)
    camera = cluster.spawn(
        f"camera/{name}/0",
        [
            "camera",
            *cluster.transport_args(),
            "--node",
            name,
            "--uav",
            uav,
            "--in-flight",
            "1",
            *camera_args,
        ],
    )
    deadline = time.monotonic() + 120.0
    last, stable_since = outputs.counts(), time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.1)
        now = outputs.counts()
        if now != last:
            last, stable_since = now, time.monotonic()
        if camera.poll() is not None and now[0] >= N_FRAMES and time.monotonic() - stable_since > 1.5:
            break
    assert camera.wait(10.0) == 0, f"camera {name} failed; see {cluster.log_dir}"
    cluster.signal(f"camera/{name}/0", signal.SIGTERM)  # exited: marks it stopped for later wait_alive
    for member in (estimator, master):
        cluster.signal(member, signal.SIGTERM)
        try:
            cluster.processes[member].wait(10.0)
        except subprocess.TimeoutExpired:
            cluster.signal(member, signal.SIGKILL)
    outputs.close()
    return outputs


def test_bags_and_euroc_folder_replay_with_the_simulated_cameras_results(tmp_path: Path) -> None:
    flight = hover_flight(seed=0, n_frames=N_FRAMES)  # what `capataz camera --frames N` simulates
    stream = list(flight_measurements(flight))
    write_bag(tmp_path / "flight_ros2", stream, None, "ros2-mcap")
    write_bag(tmp_path / "flight.bag", stream, None, "ros1", encoding="bgr8")
    write_euroc(tmp_path / "flight_euroc", stream)
    spec = ClusterSpec(
        name="replay",
        topology=Topology.MASTER_WORKER,
        balance=Balance.TIME,
        hosts=(HostSpec(name="h1", workers=1),),
    )
    runs: dict[str, _Outputs] = {}
    rate = FPS * float(flight.frame_stamps_s[1] - flight.frame_stamps_s[0])  # recorded rate -> FPS
    with LocalCluster(spec, tmp_path / "logs") as cluster:
        cluster.start(with_master=False)
        with open_session(cluster.observer_transport()) as session:
            for name, args in (
                ("sim", ["--frames", str(N_FRAMES), "--fps", str(FPS)]),
                ("sim2", ["--frames", str(N_FRAMES), "--fps", str(FPS)]),
                ("ros2", ["--bag", str(tmp_path / "flight_ros2"), "--rate", str(rate)]),
                ("ros1", ["--bag", str(tmp_path / "flight.bag"), "--rate", str(rate)]),
                ("euroc", ["--euroc", str(tmp_path / "flight_euroc"), "--rate", str(rate)]),
            ):
                runs[name] = _run(cluster, session, name, args, flight)
    sim = runs["sim"]
    assert len(sim.yaw) == N_FRAMES and len(sim.attitude) > N_FRAMES and len(sim.pose) >= N_FRAMES - 2
    for name in ("sim2", "ros2", "ros1", "euroc"):
        run = runs[name]
        assert sorted(run.yaw) == list(range(N_FRAMES)), name
        yaw_diff = max(abs(run.yaw[s].yaw_rad - sim.yaw[s].yaw_rad) for s in range(N_FRAMES))
        assert np.degrees(yaw_diff) <= 1e-9, (name, yaw_diff)
        assert [a.stamp_s for a in run.attitude] == [a.stamp_s for a in sim.attitude], name
        assert [p.stamp_s for p in run.pose] == [p.stamp_s for p in sim.pose], name
        q_diff = max(
            np.max(np.abs(a.q_world_body - b.q_world_body))
            for a, b in zip(run.attitude, sim.attitude, strict=True)
        )
        p_diff = max(
            np.max(np.abs(a.p_world_body_m - b.p_world_body_m))
            for a, b in zip(run.pose, sim.pose, strict=True)
        )
        assert q_diff <= Q_BOUND and p_diff <= P_BOUND_M, (name, q_diff, p_diff)
        print(
            f"{name}: max |yaw diff| {np.degrees(yaw_diff):.1e} deg, |q diff| {q_diff:.1e}, "
            f"|p diff| {p_diff:.1e} m"
        )
