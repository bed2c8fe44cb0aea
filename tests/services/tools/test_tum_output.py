"""``make run``'s TUM files: evo's own reader loads each estimate and its ground truth, and evo's APE
equals the figure capataz reports (within 1e-6): pose/pf (localizer demo), attitude and pose/vo (estimator
demo), and the services' ``--trajectory`` writer. The yaw files of the cluster demo are checked in its
(slow) test with the same helper."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.datasets.tum import read_tum
from common.sim.comparison import compare_on_flight_b
from common.wire.messages import AttitudeEstimate, PoseEstimate, YawEstimate
from services.runtime.trajectory import TrajectoryTap
from services.tools.demo_estimator import write_estimator_tum
from services.tools.demo_localizer import run_demo as localizer_demo
from tests.builders import yaw_estimate


def assert_evo_agrees(entry: dict[str, Any]) -> None:
    """evo reads ``entry``'s two files; its APE (relation as in ``entry['evo']``) equals capataz's."""
    from evo.core import metrics, sync
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(entry["truth"])
    est = file_interface.read_tum_trajectory_file(entry["file"])
    assert est.num_poses == entry["poses"] > 0
    ref, est = sync.associate_trajectories(ref, est)
    assert est.num_poses == entry["poses"]  # every estimate found its ground truth
    checks = [(metrics.PoseRelation.rotation_angle_deg, entry["ape_rotation_rmse_deg"])]
    if "trans_part" in entry["evo"]:
        checks.append((metrics.PoseRelation.translation_part, entry["ape_translation_rmse_m"]))
    for relation, ours in checks:
        ape = metrics.APE(relation)
        ape.process_data((ref, est))
        assert ape.get_statistic(metrics.StatisticsType.rmse) == pytest.approx(ours, abs=1e-6), relation


def test_localizer_demo_writes_pose_pf_files_evo_agrees_with(tmp_path: Path) -> None:
    summary = localizer_demo(tmp_path, n_frames=30, n_particles=100)
    entry = summary["tum"]
    assert Path(entry["file"]).name == "pose_pf.tum" and Path(entry["truth"]).name == "pose_pf_truth.tum"
    assert entry["ape_translation_rmse_m"] > 0.0  # a real error, not a file compared with itself
    assert_evo_agrees(entry)


def test_estimator_tum_files_evo_agrees_with(tmp_path: Path) -> None:
    flight, runs = compare_on_flight_b(frames=30, start_frame=300)  # VO poses from the first frame on
    entries = write_estimator_tum(tmp_path, flight, runs["rectified"])
    assert entries["attitude"]["poses"] == len(runs["rectified"].attitude_stamps_s)
    assert entries["pose_vo"]["poses"] == len(runs["rectified"].pose_stamps_s) > 0
    for entry in entries.values():
        assert entry["ape_rotation_rmse_deg"] > 0.0
        assert_evo_agrees(entry)


def test_services_trajectory_tap_writes_each_estimate_once(tmp_path: Path) -> None:
    tap = TrajectoryTap(
        {YawEstimate: tmp_path / "yaw.tum", PoseEstimate: tmp_path / "pose.tum", AttitudeEstimate: None}
    )
    q = np.array([np.cos(0.25), 0.0, 0.0, np.sin(0.25)])
    tap.write(yaw_estimate(stamp_s=1.5, yaw_rad=0.5, inlier_count=0, patch_count=0))
    tap.write(
        PoseEstimate(
            uav="u",
            stamp_s=2.0,
            p_world_body_m=[1.0, 2.0, 3.0],
            q_world_body=q,
            covariance=np.eye(6),
            source="vo",
        )
    )
    tap.write(AttitudeEstimate(uav="u", stamp_s=2.0, q_world_body=q, covariance=np.eye(3)))  # no file asked
    tap.close()
    yaw, pose = read_tum(tmp_path / "yaw.tum"), read_tum(tmp_path / "pose.tum")
    assert yaw.stamps_s.tolist() == [1.5] and np.allclose(yaw.q_world_body[0], q)
    assert pose.p_world_body_m.tolist() == [[1.0, 2.0, 3.0]] and np.allclose(pose.q_world_body[0], q)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pose.tum", "yaw.tum"]


def test_an_estimating_service_command_runs_the_service_with_its_trajectory_files(tmp_path: Path) -> None:
    import argparse

    from services.runtime.trajectory import register_estimating_service

    class Service:
        trajectory_tap: TrajectoryTap | None = None

        def __init__(self, args: argparse.Namespace) -> None:
            self.args = args

        def run(self) -> int:
            assert self.trajectory_tap is not None
            self.trajectory_tap.write(yaw_estimate(stamp_s=1.0, yaw_rad=0.25, inlier_count=0, patch_count=0))
            return 3

    started: list[Service] = []

    def start(args: argparse.Namespace) -> Service:
        started.append(Service(args))
        return started[-1]

    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--rate", type=float, default=1.0)

    parser = argparse.ArgumentParser()
    register_estimating_service(
        parser.add_subparsers(),
        "thing",
        "a test service",
        add_arguments,
        start,
        {YawEstimate: ("--trajectory", "yaw"), AttitudeEstimate: ("--attitude-trajectory", "attitude")},
    )
    args = parser.parse_args(["thing", "--rate", "2", "--attitude-trajectory", str(tmp_path / "att.tum")])
    assert args.trajectory is None
    assert args.handler(args) == 3 and started[0].args.rate == 2.0
    assert len(read_tum(tmp_path / "att.tum")) == 0  # asked for, opened, nothing of its type
    args = parser.parse_args(["thing", "--trajectory", str(tmp_path / "yaw.tum")])
    assert args.handler(args) == 3
    assert read_tum(tmp_path / "yaw.tum").stamps_s.tolist() == [1.0]
