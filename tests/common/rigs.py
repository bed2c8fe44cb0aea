"""Hypothesis strategies for :class:`common.rig.Rig` (shared by the rig, rig file and rig message tests)."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from common.camera import CameraModel, Distortion, DistortionModel
from common.geometry import matrix_from_quaternion
from common.rig import Rig

_unit = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def rotations(draw: st.DrawFn) -> np.ndarray:
    q = np.array([draw(_unit) for _ in range(4)])
    if np.linalg.norm(q) < 1e-3:
        q = np.array([1.0, 0.0, 0.0, 0.0])
    return np.asarray(matrix_from_quaternion(q))


@st.composite
def distortions(draw: st.DrawFn) -> Distortion:
    model = draw(st.sampled_from(list(DistortionModel)))
    small = st.floats(-0.01, 0.01, allow_nan=False)
    if model is DistortionModel.NONE:
        return Distortion()
    n = 5 if model is DistortionModel.RADTAN else 4
    return Distortion(model, tuple(draw(small) for _ in range(n)))


@st.composite
def cameras(draw: st.DrawFn) -> CameraModel:
    width, height = draw(st.integers(16, 2000)), draw(st.integers(16, 2000))
    return CameraModel(
        width=width,
        height=height,
        # corners near the axis in normalised coordinates: small coefficients keep the lens invertible
        fx=draw(st.floats(1.0, 3.0)) * max(width, height),
        fy=draw(st.floats(1.0, 3.0)) * max(width, height),
        cx=draw(st.floats(0.3, 0.7)) * width,
        cy=draw(st.floats(0.3, 0.7)) * height,
        distortion=draw(distortions()),
    )


@st.composite
def rigs(draw: st.DrawFn) -> Rig:
    return Rig(
        camera=draw(cameras()),
        R_body_camera=draw(rotations()),
        t_body_camera_m=np.array([draw(_unit) for _ in range(3)]),
        R_body_imu=draw(rotations()),
        time_offset_s=draw(st.floats(-0.05, 0.05, allow_nan=False)),
    )
