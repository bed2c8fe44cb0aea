"""Every output message carries a ``frame_id`` (docs/data.md "Keys and frames"): defaults per message, kept on
the wire, refused when it is not a frame name."""

from __future__ import annotations

import numpy as np
import pytest

from common.wire.codec import decode, encode
from common.wire.messages import AttitudeEstimate, Frame, ImuSample, PoseEstimate, RangeSample, YawEstimate
from common.wire.schema import WireError

MESSAGES = [
    (Frame(uav="u", seq=0, stamp_s=1.0, width=2, height=2, pixels=np.zeros((2, 2), np.uint8)), "camera"),
    (ImuSample(uav="u", stamp_s=1.0, gyro_rad_s=np.zeros(3), accel_m_s2=np.zeros(3)), "body"),
    (RangeSample(uav="u", stamp_s=1.0, range_m=1.0), "body"),
    (YawEstimate(uav="u", seq=0, stamp_s=1.0, delta_yaw_rad=0.0, yaw_rad=0.0, inlier_count=0, patch_count=0,
                 confidence=0.0, low_confidence=True, method="first"), "world"),
    (AttitudeEstimate(uav="u", stamp_s=1.0, q_world_body=[1.0, 0, 0, 0], covariance=np.eye(3)), "world"),
    (PoseEstimate(uav="u", stamp_s=1.0, p_world_body_m=np.zeros(3), q_world_body=[1.0, 0, 0, 0],
                  covariance=np.eye(6), source="vo"), "world"),
]  # fmt: skip


@pytest.mark.parametrize(("message", "frame"), MESSAGES, ids=lambda m: type(m).__name__)
def test_each_output_message_has_its_documented_frame_and_keeps_it_on_the_wire(
    message: object, frame: str
) -> None:
    assert message.frame_id == frame  # type: ignore[attr-defined]
    renamed = message.model_copy(update={"frame_id": "uav0/base_link"})  # type: ignore[attr-defined]
    back = decode(*encode(renamed))
    assert back.frame_id == "uav0/base_link"  # type: ignore[attr-defined]


def test_a_frame_id_that_is_not_a_frame_name_is_refused() -> None:
    payload, header = encode(MESSAGES[2][0])  # type: ignore[arg-type]
    import msgpack

    doc = msgpack.unpackb(header)
    doc["f"]["frame_id"] = "world frame with spaces"
    with pytest.raises(WireError, match="frame_id"):
        decode(payload, msgpack.packb(doc))
