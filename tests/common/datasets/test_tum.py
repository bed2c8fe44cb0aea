"""TUM trajectories: exact round trip, evo's own reader agrees, and capataz's APE equals evo's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.datasets.tum import Trajectory, TumError, TumWriter, read_tum, write_tum
from common.metrics import ape_rotation_rmse_deg, ape_translation_rmse_m
from common.sim.flight import turns_flight


def _flight_trajectory(n: int = 200) -> Trajectory:
    flight = turns_flight(seed=0)
    k = np.arange(n)
    return Trajectory(flight.frame_stamps_s[k], flight.p_world_body_m[k], flight.q_world_body[k])


def _noisy(truth: Trajectory, seed: int) -> Trajectory:
    rng = np.random.default_rng(seed)
    q = truth.q_world_body + rng.normal(0, 0.01, truth.q_world_body.shape)
    return Trajectory(
        truth.stamps_s,
        truth.p_world_body_m + rng.normal(0, 0.05, truth.p_world_body_m.shape),
        q / np.linalg.norm(q, axis=1, keepdims=True),
    )


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 40), st.integers(0, 2**31))
def test_write_then_read_gives_the_same_floats(n: int, seed: int) -> None:
    import tempfile

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    traj = Trajectory(
        np.cumsum(rng.uniform(0.001, 1.0, n)) + rng.uniform(0, 2e9),
        rng.normal(0, 100, (n, 3)),
        q / np.linalg.norm(q, axis=1, keepdims=True),
    )
    with tempfile.TemporaryDirectory() as tmp:
        back = read_tum(write_tum(Path(tmp) / "t.tum", traj))
    for name in ("stamps_s", "p_world_body_m", "q_world_body"):
        assert np.array_equal(getattr(back, name), getattr(traj, name))


def test_evo_reads_our_files_and_its_ape_equals_ours(tmp_path: Path) -> None:
    from evo.core import metrics, sync
    from evo.tools import file_interface

    truth = _flight_trajectory()
    estimate = _noisy(truth, 1)
    write_tum(tmp_path / "truth.tum", truth)
    writer = TumWriter(tmp_path / "est.tum")
    for t, p, q in zip(estimate.stamps_s, estimate.p_world_body_m, estimate.q_world_body, strict=True):
        writer.write(float(t), p, q)
    writer.close()
    ref = file_interface.read_tum_trajectory_file(str(tmp_path / "truth.tum"))
    est = file_interface.read_tum_trajectory_file(str(tmp_path / "est.tum"))
    assert np.array_equal(est.positions_xyz, estimate.p_world_body_m)
    assert np.allclose(est.orientations_quat_wxyz, estimate.q_world_body, atol=0)
    ref, est = sync.associate_trajectories(ref, est)
    for relation, ours in (
        (
            metrics.PoseRelation.translation_part,
            ape_translation_rmse_m(
                estimate.stamps_s, estimate.p_world_body_m, truth.stamps_s, truth.p_world_body_m
            ),
        ),
        (
            metrics.PoseRelation.rotation_angle_deg,
            ape_rotation_rmse_deg(
                estimate.stamps_s, estimate.q_world_body, truth.stamps_s, truth.q_world_body
            ),
        ),
    ):
        ape = metrics.APE(relation)
        ape.process_data((ref, est))
        theirs = ape.get_statistic(metrics.StatisticsType.rmse)
        assert theirs == pytest.approx(ours, abs=1e-9), relation
        assert ours > 0.01  # the noise is seen: not a trivially equal zero


def test_yaw_trajectory_is_a_rotation_about_z() -> None:
    traj = Trajectory.from_yaw([0.0, 1.0], [0.0, np.pi / 2])
    assert np.allclose(traj.q_world_body[1], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    assert np.array_equal(traj.p_world_body_m, np.zeros((2, 3)))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0 1 2 3 0 0 0\n", "expected 8 columns"),
        ("0 1 2 x 0 0 0 1\n", "not numbers"),
        ("0 1 2 3 0 0 0 2\n", "unit quaternions"),
        ("0 nan 2 3 0 0 0 1\n", "NaN"),
    ],
)
def test_malformed_files_name_the_problem(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.tum"
    path.write_text(text)
    with pytest.raises(TumError, match=message):
        read_tum(path)
