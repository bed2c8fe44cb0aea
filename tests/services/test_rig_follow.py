"""The rig follower's queries for a stream's rig (services/runtime/rig_follow.py)."""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any, cast

import numpy as np
import pytest
import zenoh

from common.camera import CameraModel
from common.rig import Rig
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Frame
from common.wire.rig import RigMessage, message_of_rig
from services.runtime.counters import Counters
from services.runtime.rig_follow import RigFollower
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import WAIT_S, hub, peer, put_message, wait_until


class _Service:
    """What the follower needs of a service; a 'sample' here is the decoded message itself."""

    name = "test"

    def __init__(self) -> None:
        self.counters = Counters()

    def count_error(self, counter: str, what: str, exc: BaseException | str) -> None:
        self.counters.inc(counter)

    def decode_sample(self, sample: Any, expected: type[RigMessage]) -> RigMessage | None:
        return cast(RigMessage, sample)


class _Session:
    """A camera that answers the rig query only once it exists (``rig`` set), as a late camera does."""

    def __init__(self) -> None:
        self.rig: Rig | None = None
        self.queries: list[float | None] = []

    def declare_subscriber(self, key: str, handler: Any) -> object:
        return object()

    def get(self, key: str, handler: Any = None, timeout: float = 0.0) -> list[Any]:
        self.queries.append(timeout if handler is None else None)
        replies = (
            [] if self.rig is None else [SimpleNamespace(ok=message_of_rig("uav0", self.rig, time.time()))]
        )
        if handler is not None:
            for reply in replies:
                handler(reply)
            return []
        return replies


def test_a_frames_wait_for_its_rig_is_not_throttled_by_the_start_ask() -> None:
    """Regression (a busy host, test_rig_stream): the start's ask found no camera yet, and within the next
    second the first frame's wait for the rig it names was throttled away: the frame was refused."""
    service, session = _Service(), _Session()
    follower = RigFollower("uav0", service)
    follower.start(session)  # type: ignore[arg-type]
    assert session.queries == [None]  # asked at start: no camera yet, no reply
    rig = Rig(CameraModel(width=320, height=240, fx=300.0, fy=300.0, cx=159.5, cy=119.5))
    session.rig = rig  # the camera came up, and its publication of the rig has not arrived
    frame = cast(Frame, SimpleNamespace(seq=0, rig_id=rig.rig_id))
    found, admitted = follower.rig_of(frame, wait_s=3.0)
    assert admitted and found is not None and found.rig_id == rig.rig_id
    assert session.queries == [None, 3.0] and not service.counters.get("refused_camera_unknown_rig")


def test_waiting_asks_are_throttled_among_themselves() -> None:
    """A flood of frames naming a rig nobody answers for waits once a second, not once a frame."""
    service, session = _Service(), _Session()
    follower = RigFollower("uav0", service)
    follower.start(session)  # type: ignore[arg-type]
    frames = [cast(Frame, SimpleNamespace(seq=k, rig_id="0123456789abcdef")) for k in range(5)]
    verdicts = [follower.rig_of(frame, wait_s=0.01)[1] for frame in frames]
    assert verdicts == [False] * 5 and service.counters.get("refused_camera_unknown_rig") == 5
    assert session.queries.count(0.01) == 1


class _DecodingService(_Service):
    """As :class:`_Service`, but taking real samples off the wire."""

    def decode_sample(self, sample: Any, expected: type[RigMessage]) -> RigMessage | None:
        return decode(zbytes(sample.payload), zbytes(sample.attachment), expected)


@pytest.mark.zenoh
def test_a_rig_published_just_before_a_frame_is_known_when_the_frame_arrives() -> None:
    """Regression (CI, test_rig_formats[euroc], busy host): the estimator takes frames on zenoh's receiving
    thread, and the follower took the rig on a Python thread of its own; the rig, published before the
    first frame, reached the follower after it, and the frame was refused as naming an unknown rig. Twenty
    rounds of a new rig and, at once, a frame naming it, taken the way the estimator takes frames."""
    service = _DecodingService()
    follower = RigFollower("uav0", service)
    verdicts: list[bool] = []

    def on_frame(sample: zenoh.Sample) -> None:
        frame = decode(zbytes(sample.payload), zbytes(sample.attachment), Frame)
        verdicts.append(follower.rig_of(frame)[1])

    with hub() as endpoint, open_session(peer(endpoint)) as consumer, open_session(peer(endpoint)) as camera:
        follower.start(consumer)
        consumer.declare_subscriber(
            keys.camera_key("uav0"), zenoh.handlers.Callback(on_frame, indirect=False)
        )
        rig_pub = camera.declare_publisher(keys.rig_key("uav0"))
        frame_pub = camera.declare_publisher(keys.camera_key("uav0"))
        assert wait_until(
            lambda: rig_pub.matching_status.matching and frame_pub.matching_status.matching, WAIT_S
        )
        image = np.zeros((24, 32), np.uint8)
        for k in range(20):
            rig = Rig(CameraModel(width=32, height=24, fx=30.0 + k, fy=30.0 + k, cx=15.5, cy=11.5))
            put_message(rig_pub, message_of_rig("uav0", rig, time.time()))
            frame = Frame(
                uav="uav0", seq=k, stamp_s=0.05 * k, width=32, height=24, pixels=image, rig_id=rig.rig_id
            )
            put_message(frame_pub, frame)
        assert wait_until(lambda: len(verdicts) == 20, WAIT_S), verdicts
    assert all(verdicts) and not service.counters.get("refused_camera_unknown_rig"), verdicts
