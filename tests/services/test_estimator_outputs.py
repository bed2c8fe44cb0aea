"""The VO pose's horizontal uncertainty: drift with the distance travelled, and for good the motion a
failed pair did not see; such a pose is published as ``lost``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.estimation.coupling_types import PoseOutput
from services.estimator.outputs import (
    MIN_VAR_XY_M2,
    WIDE_PAIR_FRACTION,
    VoPath,
    advance_path,
    horizontal_variance,
    pose_message,
)


def _pose(stamp_s: float, x_m: float, ok: bool = True) -> PoseOutput:
    return PoseOutput(
        stamp_s=stamp_s,
        p_world_body_m=np.array([x_m, 0.0, 3.0]),
        q_world_body=np.array([1.0, 0.0, 0.0, 0.0]),
        attitude_covariance_world=np.eye(3) * 1e-6,
        altitude_var_m2=1e-4,
        vo_yaw_rad=0.0,
        n_inliers=100,
        rectification_weight=1.0,
        ok=ok,
    )


def test_a_failed_pair_adds_the_unseen_motion_for_good_and_is_published_as_lost() -> None:
    path = VoPath()
    for k in range(5):  # 2 m/s along x, 20 frames a second
        path = advance_path(path, _pose(0.05 * k, 0.1 * k))
    assert path.speed_m_s == pytest.approx(2.0) and path.unseen_var_m2 == 0.0
    before = horizontal_variance(path, 0.001)
    # the pair across 0.5 s failed: the chain restarted at the previous position
    failed = _pose(0.7, 0.4, ok=False)
    path = advance_path(path, failed)
    assert path.unseen_var_m2 == pytest.approx((2.0 * 0.5) ** 2)
    assert horizontal_variance(path, 0.001) >= before + 1.0 - 1e-9
    assert pose_message("uav0", 0, failed, horizontal_variance(path, 0.001)).tracking_state == "lost"
    path = advance_path(path, _pose(0.75, 0.5))  # tracking again; the unseen motion stays
    assert path.unseen_var_m2 == pytest.approx(1.0)
    assert pose_message("uav0", 1, _pose(0.75, 0.5), 1.0).tracking_state == "tracking"


@given(st.lists(st.tuples(st.floats(-10, 10), st.booleans()), min_size=1, max_size=30))
def test_the_horizontal_variance_never_shrinks(steps: list[tuple[float, bool]]) -> None:
    path = VoPath()
    last = MIN_VAR_XY_M2
    for k, (x_m, ok) in enumerate(steps):
        path = advance_path(path, _pose(0.05 * (k + 1), x_m, ok))
        var = horizontal_variance(path, 0.001)
        assert var >= last - 1e-15
        last = var


def test_a_pair_wider_than_the_trusted_spacing_adds_a_share_of_its_step() -> None:
    path = advance_path(VoPath(), _pose(0.0, 0.0))
    close = advance_path(path, _pose(0.2, 0.1), max_pair_s=0.25)
    wide = advance_path(path, _pose(0.4, 0.1), max_pair_s=0.25)
    assert close.unseen_var_m2 == 0.0
    assert wide.unseen_var_m2 == pytest.approx((WIDE_PAIR_FRACTION * 0.1) ** 2)
