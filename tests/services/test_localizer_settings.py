"""Localizer service pieces without a network: settings, scene files, VO odometry, the pose message."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.errors import CapatazError
from common.geometry import matrix_from_euler, matrix_from_quaternion, quaternion_from_euler
from common.localization.model import SceneModelError, scene_to_dict
from common.localization.office import default_scene
from common.localization.particle_filter import PoseStatistics
from common.messages import PoseEstimate
from services.localizer import LocalizerSettings, odometry_between, pose_message


def _pose(stamp_s: float, p: list[float], euler: list[float]) -> PoseEstimate:
    return PoseEstimate(
        uav="uav0",
        stamp_s=stamp_s,
        p_world_body_m=np.asarray(p, dtype=float),
        q_world_body=quaternion_from_euler(*euler),
        covariance=np.eye(6),
        source="vo",
    )


def test_vo_odometry_is_the_finite_difference_of_positions_and_wrapped_angles() -> None:
    a = _pose(1.0, [1.0, 2.0, 1.5], [0.0, 0.0, np.radians(179.0)])
    b = _pose(1.5, [1.5, 1.0, 1.5], [0.0, 0.0, np.radians(-179.0)])
    result = odometry_between(a, b)
    assert result is not None
    velocity, rates = result
    assert np.allclose(velocity, [1.0, -2.0, 0.0])
    assert np.allclose(rates, [0.0, 0.0, np.radians(2.0) / 0.5], atol=1e-9)
    assert odometry_between(b, a) is None


def test_scene_files_load_and_bad_ones_fail_clearly(tmp_path: Path) -> None:
    path = tmp_path / "office.json"
    path.write_text(json.dumps(scene_to_dict(default_scene())))
    assert LocalizerSettings(scene=path).load_scene().n_edges == default_scene().n_edges
    with pytest.raises(CapatazError, match="cannot read"):
        LocalizerSettings(scene=tmp_path / "missing.json").load_scene()
    (tmp_path / "bad.json").write_text('{"vertices": []}')
    with pytest.raises(SceneModelError):
        LocalizerSettings(scene=tmp_path / "bad.json").load_scene()


def test_pose_message_carries_the_mean_and_a_world_error_angle_covariance() -> None:
    mean = np.array([1.0, 2.0, 1.5, 0.1, -0.05, 2.0])
    covariance = np.diag([1e-4, 2e-4, 3e-4, 1e-5, 2e-5, 3e-5])
    message = pose_message("uav0", 7, 3.5, PoseStatistics(mean, covariance, 150.0, 0.8))
    assert message.seq == 7 and message.source == "pf"
    assert np.allclose(message.p_world_body_m, mean[:3])
    assert np.allclose(matrix_from_quaternion(message.q_world_body), matrix_from_euler(*mean[3:]))
    assert np.allclose(message.covariance[:3, :3], covariance[:3, :3])
    # a pure yaw variance is a variance about world z
    yaw_only = pose_message("uav0", 0, 0.0, PoseStatistics(mean, np.diag([0, 0, 0, 0, 0, 1e-4]), 1.0, 1.0))
    assert yaw_only.covariance[5, 5] == pytest.approx(1e-4)
    assert np.allclose(yaw_only.covariance[3:5, 3:5], 0.0)


def test_settings_are_validated() -> None:
    with pytest.raises(ValueError, match="particles"):
        LocalizerSettings(particles=1)
    with pytest.raises(ValueError, match="scoring"):
        LocalizerSettings(scoring="best")  # type: ignore[arg-type]
