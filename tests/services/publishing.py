"""Tests publish a measurement stream (a simulated flight's IMU, rangefinder and camera samples) on one
UAV's keys, as the camera would, to a service under test.

Samples go out in stamp order, paced at ``speed`` times real time (``speed = 0``: as fast as possible).
"""

from __future__ import annotations

import time

import zenoh

from common.estimation.measurements import Measurement
from common.wire.codec import encode
from common.wire.measurements import message_of


def publish_measurements(
    session: zenoh.Session,
    uav: str,
    measurements: list[Measurement],
    speed: float = 1.0,
    block: bool = False,
    first_seq: int = 0,
) -> int:
    """Publish the samples (stamp order) on ``uav``'s keys, numbered from ``first_seq`` (a later part of a
    stream continues its numbering: a restart from 0 is a new epoch at the input gate); returns how many
    were sent.

    ``block`` uses ``CongestionControl.BLOCK`` (nothing dropped on the way: for tests that compare every
    estimate); the default drops like a live sensor stream.
    """
    publishers: dict[str, zenoh.Publisher] = {}
    t_wall0 = time.monotonic()
    t_sim0 = measurements[0].stamp_s if measurements else 0.0
    sent = 0
    try:
        for seq, m in enumerate(measurements):
            if speed > 0.0:
                delay = (m.stamp_s - t_sim0) / speed - (time.monotonic() - t_wall0)
                if delay > 0.0:
                    time.sleep(delay)
            key, message = message_of(uav, first_seq + seq, m)
            if key not in publishers:
                publishers[key] = session.declare_publisher(
                    key,
                    congestion_control=zenoh.CongestionControl.BLOCK
                    if block
                    else zenoh.CongestionControl.DROP,
                )
            payload, attachment = encode(message)
            publishers[key].put(payload, attachment=attachment)
            sent += 1
    finally:
        for publisher in publishers.values():
            publisher.undeclare()
    return sent
