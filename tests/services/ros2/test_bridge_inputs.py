"""The bridge's input path with real Zenoh (no ROS needed: duck-typed sensor messages as rclpy gives them):
good samples reach the UAV's capataz keys unchanged, and bad ROS input (an unknown encoding, a wrong step,
NaN, a stamp going back, a size that is not the camera info's) is refused, counted under its reason and
never forwarded."""

from __future__ import annotations

import array
import threading
from types import SimpleNamespace as Ns
from typing import Any

import numpy as np
import pytest

from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Frame, ImuSample, RangeSample
from common.wire.schema import WireModel
from services.ros2.bridge import Ros2Bridge
from services.ros2.settings import Ros2Settings
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import hub, matched, peer, wait_until

pytestmark = pytest.mark.zenoh
UAV = "uav0"


def header(stamp_s: float) -> Any:
    ns = round(stamp_s * 1e9)
    return Ns(stamp=Ns(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="x")


def image(stamp_s: float, pixels: np.ndarray, encoding: str = "mono8", step: int | None = None) -> Any:
    h, w = pixels.shape
    return Ns(header=header(stamp_s), height=h, width=w, encoding=encoding, is_bigendian=0,
              step=w if step is None else step, data=array.array("B", pixels.tobytes()))  # fmt: skip


def imu(stamp_s: float, gyro_z: float) -> Any:
    return Ns(header=header(stamp_s), angular_velocity=Ns(x=0.0, y=0.0, z=gyro_z),
              linear_acceleration=Ns(x=0.0, y=0.0, z=9.81))  # fmt: skip


def rng(stamp_s: float, value: float) -> Any:
    return Ns(header=header(stamp_s), range=value, min_range=0.1, max_range=40.0)


def info(width: int, height: int) -> Any:
    return Ns(width=width, height=height, distortion_model="plumb_bob", d=[0.0] * 5,
              k=[100.0, 0.0, (width - 1) / 2, 0.0, 100.0, (height - 1) / 2, 0.0, 0.0, 1.0])  # fmt: skip


def test_good_ros_samples_are_forwarded_and_bad_ones_refused_and_counted(tmp_path: Any) -> None:
    received: dict[str, list[Any]] = {"camera": [], "imu": [], "range": []}
    lock = threading.Lock()
    kinds: dict[str, type[WireModel]] = {"camera": Frame, "imu": ImuSample, "range": RangeSample}

    def on(name: str) -> Any:
        def callback(sample: Any) -> None:
            message: Any = decode(zbytes(sample.payload), zbytes(sample.attachment), kinds[name])
            with lock:
                received[name].append(message)

        return callback

    settings = Ros2Settings(input_uavs=(UAV,), calibration_out=tmp_path / "{uav}.yml")
    with (
        hub() as endpoint,
        open_session(peer(endpoint)) as bridge_session,
        open_session(peer(endpoint)) as client,
    ):
        bridge = Ros2Bridge("ros2", 0, peer(endpoint), settings)
        subscribers = [
            client.declare_subscriber(keys.uav_key(UAV, name), on(name))
            for name in ("camera", "imu", "range")
        ]
        bridge.declare_inputs(bridge_session, UAV)
        for kind in ("camera", "imu", "range"):
            assert matched(bridge._zpub[UAV, kind])
        grey = np.arange(48, dtype=np.uint8).reshape(6, 8)
        feed = [
            ("camera_info", info(8, 6)),
            ("image", image(1.0, grey)),
            ("image", image(1.1, grey, encoding="yuv422")),  # unknown encoding
            ("image", image(1.2, grey, step=5)),  # step shorter than a row
            ("image", image(1.3, np.zeros((4, 8), np.uint8))),  # not the camera info's size
            ("image", image(0.9, grey)),  # stamp going back
            ("image", image(1.4, grey)),
            ("imu", imu(1.00, 0.1)),
            ("imu", imu(1.01, float("nan"))),  # NaN
            ("imu", imu(0.50, 0.2)),  # stamp going back
            ("imu", imu(1.02, 0.3)),
            ("range", rng(1.0, 2.0)),
            ("range", rng(1.1, float("nan"))),
            ("range", rng(1.2, 2.5)),
        ]
        for stream, msg in feed:
            bridge.on_sensor(UAV, stream, f"/{UAV}/{stream}", msg)
        assert wait_until(lambda: [len(received[k]) for k in ("camera", "imu", "range")] == [2, 2, 2])
        for s in subscribers:
            s.undeclare()
    counts = bridge.counters.counts()
    assert counts["refused_malformed"] == 5  # encoding, step, size vs camera info, NaN IMU, NaN range
    assert counts["refused_stamp_backward"] == 2  # the frame and the IMU sample
    assert counts["forwarded_camera"] == counts["forwarded_imu"] == counts["forwarded_range"] == 2
    with lock:
        frames, imus, ranges = received["camera"], received["imu"], received["range"]
    assert [f.stamp_s for f in frames] == [1.0, 1.4] and all(np.array_equal(f.pixels, grey) for f in frames)
    assert frames[0].seq < frames[1].seq
    assert [(s.stamp_s, s.gyro_rad_s[2]) for s in imus] == [(1.0, 0.1), (1.02, 0.3)]
    assert [(s.stamp_s, s.range_m) for s in ranges] == [(1.0, 2.0), (1.2, 2.5)]
    # the camera info became a calibration file the master reads (--calibration)
    assert "camera_matrix" in (tmp_path / f"{UAV}.yml").read_text()
