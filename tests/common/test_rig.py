"""The rig value: validation, defaults, and its content id (stable, and changed by any real change)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.camera import CameraModel, Distortion, DistortionModel
from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, R_BODY_CAMERA_FORWARD
from common.rig import RIG_ID_DECIMALS, RIG_ID_HEX, Rig
from tests.common.rigs import rigs

QUANTUM = 10.0**-RIG_ID_DECIMALS


def test_defaults_are_a_down_camera_with_the_imu_as_the_body() -> None:
    rig = Rig(CameraModel.default())
    assert np.array_equal(rig.R_body_camera, R_BODY_CAMERA_DOWN)
    assert np.array_equal(rig.R_body_imu, np.eye(3))
    assert np.array_equal(rig.t_body_camera_m, np.zeros(3))
    assert rig.time_offset_s == 0.0
    assert len(rig.rig_id) == RIG_ID_HEX and int(rig.rig_id, 16) >= 0
    # the camera's optical axis (camera z) is the body's down (-z)
    assert np.allclose(rig.R_body_camera @ [0.0, 0.0, 1.0], [0.0, 0.0, -1.0])
    assert np.allclose(rig.R_camera_imu, R_BODY_CAMERA_DOWN.T)


def test_arrays_are_read_only_copies() -> None:
    R = np.array(R_BODY_CAMERA_FORWARD)
    rig = Rig(CameraModel.default(), R_body_camera=R)
    R[0, 0] = 5.0
    assert rig.R_body_camera[0, 0] == 0.0
    with pytest.raises(ValueError):
        rig.t_body_camera_m[0] = 1.0


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"R_body_camera": np.diag([1.0, 1.0, -1.0])}, "reflection"),
        ({"R_body_camera": np.eye(3) * 2.0}, "not orthonormal"),
        ({"R_body_imu": np.eye(4)}, "shape"),
        ({"R_body_imu": np.full((3, 3), np.nan)}, "finite"),
        ({"t_body_camera_m": [0.0, 0.0]}, "shape"),
        ({"t_body_camera_m": [0.0, np.inf, 0.0]}, "finite"),
        ({"t_body_camera_m": [1000.0, 0.0, 0.0]}, "over"),
        ({"t_body_camera_m": ["a", 0, 0]}, "numbers"),
        ({"time_offset_s": float("nan")}, "finite"),
        ({"time_offset_s": True}, "finite"),
        ({"time_offset_s": 5.0}, "over"),
        ({"camera": "752x480"}, "CameraModel"),
    ],
)
def test_bad_fields_raise_one_input_error(changes: dict[str, object], message: str) -> None:
    values: dict[str, object] = {"camera": CameraModel.default(), **changes}
    with pytest.raises(InputError, match=message):
        Rig(**values)  # type: ignore[arg-type]


def test_equal_rigs_have_equal_ids_and_hashes() -> None:
    a = Rig(CameraModel.default(), t_body_camera_m=np.array([0.0, -0.0, 0.1]), time_offset_s=-0.0)
    b = Rig(CameraModel.default(), t_body_camera_m=np.array([0.0, 0.0, 0.1]), time_offset_s=0)
    assert a == b and a.rig_id == b.rig_id and hash(a) == hash(b)
    assert a != Rig(CameraModel.default(), t_body_camera_m=np.array([0.0, 0.0, 0.2]))
    assert a != "rig"


def test_a_change_below_the_precision_keeps_the_id() -> None:
    camera = CameraModel(752, 480, 458.654, 457.296, 367.215, 248.375)
    a = Rig(camera, time_offset_s=0.0021)
    b = Rig(replace(camera, fx=458.654 + 1e-12), time_offset_s=0.0021 + 1e-13)
    assert a != b and a.rig_id == b.rig_id


@given(rigs())
def test_the_id_is_stable_when_the_rig_is_rebuilt_from_plain_numbers(rig: Rig) -> None:
    cam = rig.camera
    rebuilt = Rig(
        camera=CameraModel(
            int(cam.width), int(cam.height), float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy),
            Distortion(DistortionModel(cam.distortion.model.value), tuple(cam.distortion.coeffs)),
        ),
        R_body_camera=rig.R_body_camera.tolist(),
        t_body_camera_m=rig.t_body_camera_m.tolist(),
        R_body_imu=rig.R_body_imu.tolist(),
        time_offset_s=float(rig.time_offset_s),
    )  # fmt: skip
    assert rebuilt == rig and rebuilt.rig_id == rig.rig_id


def _changed(rig: Rig, which: str, delta: float) -> Rig:
    cam = rig.camera
    if which in ("fx", "fy", "cx", "cy"):
        return replace(rig, camera=replace(cam, **{which: getattr(cam, which) + delta}))
    if which == "width":
        return replace(rig, camera=replace(cam, width=cam.width + 1))
    if which == "coeff":
        if not cam.distortion.coeffs:
            lens = Distortion(DistortionModel.RADTAN, (delta, 0.0, 0.0, 0.0, 0.0))
        else:
            coeffs = (cam.distortion.coeffs[0] + delta, *cam.distortion.coeffs[1:])
            lens = Distortion(cam.distortion.model, coeffs)
        return replace(rig, camera=replace(cam, distortion=lens))
    if which in ("R_body_camera", "R_body_imu"):
        R = np.array(getattr(rig, which))
        R[1, 2] += delta
        return replace(rig, R_body_camera=R) if which == "R_body_camera" else replace(rig, R_body_imu=R)
    if which == "t_body_camera_m":
        return replace(rig, t_body_camera_m=rig.t_body_camera_m + np.array([0.0, 0.0, delta]))
    return replace(rig, time_offset_s=rig.time_offset_s + delta)


FIELDS = [
    "fx",
    "fy",
    "cx",
    "cy",
    "width",
    "coeff",
    "R_body_camera",
    "R_body_imu",
    "t_body_camera_m",
    "offset",
]


@given(rigs(), st.sampled_from(FIELDS), st.floats(2.0 * QUANTUM, 1e-6), st.booleans())
def test_any_change_beyond_the_precision_changes_the_id(
    rig: Rig, which: str, size: float, negative: bool
) -> None:
    other = _changed(rig, which, -size if negative else size)
    assert other != rig
    assert other.rig_id != rig.rig_id, (which, rig.canonical_text(), other.canonical_text())


def test_a_radtan_lens_with_zero_coefficients_is_the_pinhole_it_is() -> None:
    zero = replace(CameraModel.default(), distortion=Distortion(DistortionModel.RADTAN, (0.0,) * 5))
    rig = Rig(zero)
    assert rig.camera == CameraModel.default()
    assert rig == Rig(CameraModel.default()) and rig.rig_id == Rig(CameraModel.default()).rig_id
    fisheye = Distortion(DistortionModel.FISHEYE, (0.0,) * 4)  # the ideal equidistant lens: not a pinhole
    assert Rig(replace(zero, distortion=fisheye)).camera.distortion == fisheye
