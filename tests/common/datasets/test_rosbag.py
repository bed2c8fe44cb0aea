"""ROS bags in: a simulated flight written with rosbags' writers (ROS 2 MCAP and sqlite3, ROS 1) reads
back as the same measurements; bad bags get one BagError naming the problem."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.camera import CameraModel, Distortion, DistortionModel
from common.datasets.rosbag import BagError, open_bag
from common.datasets.rosbag_writer import write_bag
from common.estimation.measurements import FrameMeasurement, ImuMeasurement, Measurement, RangeMeasurement
from common.sim.flight import Flight, hover_flight
from common.sim.stream import flight_measurements

N_FRAMES = 6


@pytest.fixture(scope="module")
def flight() -> Flight:
    return hover_flight(seed=0, n_frames=N_FRAMES)


@pytest.fixture(scope="module")
def stream(flight: Flight) -> list[Measurement]:
    return list(flight_measurements(flight))


def _info(flight: Flight) -> CameraModel:
    c = flight.camera
    return CameraModel(
        c.width,
        c.height,
        c.fx,
        c.fy,
        c.cx,
        c.cy,
        Distortion(DistortionModel.RADTAN, (0.1, -0.02, 0.0, 0.0, 0.0)),
    )


def _assert_same(read: list[Measurement], written: list[Measurement]) -> None:
    """Equal streams, in the same order: stamp order, equal stamps in SENSOR_ORDER (the simulated stream's
    and the reader's)."""
    assert len(read) == len(written)
    for r, w in zip(read, written, strict=True):
        assert type(r) is type(w)
        assert r.stamp_s == w.stamp_s  # ns / 1e9: the same float as the simulation's stamps
        if isinstance(r, FrameMeasurement):
            assert np.array_equal(r.image, w.image)  # type: ignore[union-attr]
        elif isinstance(r, ImuMeasurement):
            assert np.array_equal(r.gyro_rad_s, w.gyro_rad_s)  # type: ignore[union-attr]
            assert np.array_equal(r.accel_m_s2, w.accel_m_s2)  # type: ignore[union-attr]
        elif isinstance(r, RangeMeasurement):
            assert r.range_m == pytest.approx(w.range_m, rel=1e-7)  # type: ignore[union-attr]  # float32 field


@pytest.mark.parametrize(
    ("kind", "encoding"),
    [
        ("ros2-mcap", "mono8"),
        ("ros2-mcap", "png"),
        ("ros2-sqlite3", "bgr8"),
        ("ros1", "rgb8"),
        ("ros1", "mono16"),
    ],
)
def test_bag_reads_back_the_simulated_stream(
    tmp_path: Path, flight: Flight, stream: list[Measurement], kind: str, encoding: str
) -> None:
    path = tmp_path / ("flight.bag" if kind == "ros1" else "flight")
    write_bag(path, stream, _info(flight), kind, encoding)  # type: ignore[arg-type]
    bag = open_bag(path)
    assert bag.topics.imu == "/imu" and bag.topics.range == "/range"
    assert bag.counts["/camera/image_raw"] == N_FRAMES
    assert bag.camera_info is not None
    assert (bag.camera_info.width, bag.camera_info.fx, bag.camera_info.cy) == (
        752,
        float(flight.camera.fx),
        239.5,
    )
    assert bag.camera_info == _info(flight)  # CameraInfo became the project's camera model
    _assert_same(list(bag.measurements()), stream)


def test_a_single_mcap_file_of_a_ros2_bag_is_read_too(tmp_path: Path, stream: list[Measurement]) -> None:
    write_bag(tmp_path / "bag", stream, None, "ros2-mcap")
    (mcap,) = (tmp_path / "bag").glob("*.mcap")
    _assert_same(list(open_bag(mcap).measurements()), stream)


def test_unknown_encoding_is_one_clear_error(tmp_path: Path, stream: list[Measurement]) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    with Writer(tmp_path / "bayer", version=9) as writer:
        conn = writer.add_connection("/cam", "sensor_msgs/msg/Image", typestore=ts)
        header = T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="c"
        )
        msg = T["sensor_msgs/msg/Image"](
            header=header,
            height=2,
            width=2,
            encoding="bayer_rggb8",
            is_bigendian=0,
            step=2,
            data=np.zeros(4, np.uint8),
        )
        writer.write(conn, 1, ts.serialize_cdr(msg, "sensor_msgs/msg/Image"))
    with pytest.raises(BagError, match="encoding 'bayer_rggb8' is not supported"):
        open_bag(tmp_path / "bayer")  # refused at open, before a frame is published


def test_missing_topics_are_named(tmp_path: Path, stream: list[Measurement]) -> None:
    write_bag(tmp_path / "b", stream, None, "ros2-sqlite3")
    with pytest.raises(BagError, match="image topic '/nope' is not in the bag"):
        open_bag(tmp_path / "b", image_topic="/nope")
    with pytest.raises(BagError, match="'/range' does not carry sensor_msgs/msg/Imu"):
        open_bag(tmp_path / "b", imu_topic="/range")
    with pytest.raises(BagError, match="camera-info topic '/info' is not in the bag"):
        open_bag(tmp_path / "b", camera_info_topic="/info")
    imu_only = [m for m in stream if isinstance(m, ImuMeasurement)]
    write_bag(tmp_path / "imu_only", imu_only, None, "ros2-mcap")
    with pytest.raises(BagError, match="image topic /camera/image_raw has no messages"):
        open_bag(tmp_path / "imu_only")


@pytest.mark.parametrize("kind", ["ros2-mcap", "ros2-sqlite3", "ros1"])
def test_truncated_bags_are_one_clear_error(tmp_path: Path, stream: list[Measurement], kind: str) -> None:
    path = tmp_path / ("t.bag" if kind == "ros1" else "t")
    write_bag(path, stream, None, kind)  # type: ignore[arg-type]
    (data,) = [path] if kind == "ros1" else [p for p in path.iterdir() if p.suffix in (".mcap", ".db3")]
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    with pytest.raises(BagError, match=r"truncated or corrupt|not a readable"):
        list(open_bag(path).measurements())


def test_not_a_bag_and_no_such_bag(tmp_path: Path) -> None:
    (tmp_path / "x.bag").write_bytes(b"hello")
    with pytest.raises(BagError, match="not a readable"):
        open_bag(tmp_path / "x.bag")
    with pytest.raises(BagError, match="no such bag"):
        open_bag(tmp_path / "missing.bag")
