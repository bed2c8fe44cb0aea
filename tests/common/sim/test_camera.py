"""Pinhole camera: projection by hand, round trips, validation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.errors import InputError
from common.sim.camera import PinholeCamera


def test_default_intrinsics_are_the_documented_ones() -> None:
    cam = PinholeCamera.default()
    assert (cam.width, cam.height) == (752, 480)
    assert cam.fx == pytest.approx(376.0)
    assert cam.fy == pytest.approx(376.0)
    assert (cam.cx, cam.cy) == (375.5, 239.5)
    assert np.degrees(cam.hfov_rad) == pytest.approx(90.0)
    assert cam.shape == (480, 752)


def test_project_matches_a_hand_computed_point() -> None:
    cam = PinholeCamera(width=640, height=480, fx=500.0, fy=400.0, cx=320.0, cy=240.0)
    # (0.2, -0.1, 2.0): u = 500 * 0.1 + 320 = 370, v = 400 * (-0.05) + 240 = 220
    assert np.allclose(cam.project([0.2, -0.1, 2.0]), [370.0, 220.0])
    assert np.allclose(cam.project([[0.0, 0.0, 5.0]]), [[320.0, 240.0]])
    assert np.allclose(cam.K @ np.array([0.2, -0.1, 2.0]) / 2.0, [370.0, 220.0, 1.0])


@given(st.floats(-500.0, 1200.0), st.floats(-500.0, 900.0), st.floats(0.1, 50.0, allow_nan=False))
def test_rays_and_project_are_inverse(u: float, v: float, depth: float) -> None:
    cam = PinholeCamera.default()
    point = cam.rays([u, v]) * depth
    assert np.allclose(cam.project(point), [u, v], atol=1e-8)
    assert np.allclose(cam.K_inv @ cam.K, np.eye(3))


def test_bad_inputs_raise_input_error() -> None:
    cam = PinholeCamera.default()
    with pytest.raises(InputError, match="in front"):
        cam.project([0.0, 0.0, -1.0])
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        cam.project(np.zeros((4, 2)))
    with pytest.raises(InputError, match="finite"):
        cam.project([np.nan, 0.0, 1.0])
    with pytest.raises(InputError, match="positive"):
        PinholeCamera(width=10, height=10, fx=-1.0, fy=1.0, cx=5.0, cy=5.0)
    with pytest.raises(InputError):
        PinholeCamera.from_hfov(752, 480, 180.0)
