"""The rig's wire message: codec round trips, the id checked at decode, and a frame's optional rig_id."""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import given

from common.camera import CameraModel, Distortion, DistortionModel
from common.rig import Rig
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import Frame
from common.wire.rig import RigMessage, message_of_rig, rig_from_message
from common.wire.schema import WireError
from tests.common.rigs import rigs

RIG = Rig(
    CameraModel(
        320, 240, 170.0, 171.0, 159.5, 119.5, Distortion(DistortionModel.RADTAN, (-0.1, 0.02, 0.0, 0.0, 0.0))
    ),
    t_body_camera_m=np.array([0.05, 0.0, -0.02]),
    time_offset_s=-8.121e-05,
)


@given(rigs())
def test_a_rig_survives_the_codec_with_its_id(rig: Rig) -> None:
    message = message_of_rig("uav0", rig, stamp_s=12.5, seq=3)
    decoded = decode(*encode(message), RigMessage)
    assert rig_from_message(decoded) == rig
    assert decoded.rig_id == rig.rig_id == rig_from_message(decoded).rig_id
    assert (decoded.uav, decoded.seq, decoded.stamp_s, decoded.frame_id) == ("uav0", 3, 12.5, "body")


def test_the_rig_goes_out_beside_the_frames() -> None:
    assert keys.rig_key("uav0") == "capataz/uav/uav0/rig"


def _forged(**changes: Any) -> tuple[bytes, bytes]:
    """The encoding of RIG's message with ``changes``, built without validation (what a hostile or buggy
    sender could put on the wire)."""
    good = message_of_rig("uav0", RIG, stamp_s=1.0)
    values = {name: getattr(good, name) for name in RigMessage.model_fields}
    return encode(RigMessage.model_construct(**{**values, **changes}))


REFLECTION = np.diag([1.0, 1.0, -1.0])


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"fx": 170.5}, "is not its content's id"),
        ({"time_offset_s": 0.0}, "is not its content's id"),
        ({"t_body_camera_m": np.array([0.05, 0.0, 0.02])}, "is not its content's id"),
        ({"rig_id": "0123456789abcdef"}, "is not its content's id"),
        ({"rig_id": "0123456789ABCDEF"}, "rig_id"),
        ({"rig_id": "0123"}, "rig_id"),
        ({"R_body_imu": REFLECTION}, "not a rig: R_body_imu has determinant -1"),
        ({"R_body_camera": np.eye(3) * 2.0}, "not orthonormal"),
        ({"R_body_camera": np.eye(4)}, "R_body_camera"),
        ({"t_body_camera_m": np.array([np.nan, 0.0, 0.0])}, "NaN"),
        ({"distortion_coeffs": np.zeros(6)}, "distortion_coeffs: 6 > 5"),
        ({"distortion_coeffs": np.zeros(4), "distortion_model": "fisheye"}, "is not its content's id"),
        ({"distortion_model": "omni"}, "distortion_model"),
        ({"distortion_coeffs": np.array([-5.0, 0.0, 0.0, 0.0, 0.0])}, "not a rig: distortion"),
        ({"width": 752.0}, "width"),
        ({"width": True}, "width"),
        ({"width": 100_000}, "width"),
        ({"fx": 0.0}, "fx"),
        ({"fx": "170"}, "fx"),
        ({"time_offset_s": 5.0}, "time_offset_s"),
    ],
)
def test_a_forged_or_broken_rig_message_is_refused_at_decode(changes: dict[str, Any], message: str) -> None:
    with pytest.raises(WireError, match="RigMessage") as info:
        decode(*_forged(**changes))
    assert message in str(info.value), str(info.value)


def test_an_unknown_field_is_refused() -> None:
    payload, attachment = encode(message_of_rig("uav0", RIG, stamp_s=1.0))
    header = msgpack.unpackb(attachment)
    header["f"]["lens"] = "radtan"
    with pytest.raises(WireError, match="lens"):
        decode(payload, msgpack.packb(header))


def _frame(**extra: Any) -> Frame:
    return Frame(uav="a", seq=1, stamp_s=0.0, width=4, height=3, pixels=np.zeros((3, 4), np.uint8), **extra)


def test_a_frame_carries_its_rig_id() -> None:
    frame = _frame(rig_id=RIG.rig_id)
    assert decode(*encode(frame), Frame).rig_id == RIG.rig_id
    assert decode(*encode(_frame()), Frame).rig_id is None
    for bad in ("0123456789ABCDEF", "xyz", "0123456789abcdef0"):
        with pytest.raises(WireError, match="rig_id"):
            decode(*encode(Frame.model_construct(**{**dict(frame), "rig_id": bad})))


def test_a_frame_of_an_old_recording_without_rig_id_still_decodes() -> None:
    payload, attachment = encode(_frame())
    header = msgpack.unpackb(attachment)
    del header["f"]["rig_id"]  # what frames were before the field existed
    assert decode(payload, msgpack.packb(header), Frame).rig_id is None
