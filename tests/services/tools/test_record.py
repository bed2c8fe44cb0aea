"""``capataz record`` on loopback: every key becomes an MCAP channel with a schema the ``mcap`` reader
and Foxglove understand (RawImage frames, JSON Schema messages, PoseInFrame poses), a malformed sample is
counted and not recorded, and the file reads back as the camera's measurements (``camera --mcap``)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from common.recordings.mcap import RecordingError, from_json, open_recording
from common.sim.flight import hover_flight
from common.wire import keys
from common.wire.codec import encode
from common.wire.messages import Frame, ImuSample, PoseEstimate, RangeSample
from services.runtime.transport import open_session
from services.tools.record import RecordService, RecordSettings
from tests.zenoh_helpers import hub, peer

pytestmark = pytest.mark.zenoh


@pytest.fixture
def endpoint() -> Iterator[str]:
    with hub() as router:
        yield router


def _wait(condition, timeout_s: float = 20.0) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return False


def test_record_writes_every_key_as_a_channel_and_reads_back(tmp_path: Path, endpoint: str) -> None:
    from mcap.reader import make_reader

    flight = hover_flight(seed=0, n_frames=3)
    out = tmp_path / "run.mcap"
    service = RecordService("rec", 0, peer(endpoint), RecordSettings(out=out))
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    assert service.started.wait(20.0)
    sent = []
    with open_session(peer(endpoint)) as session:
        publishers = {
            k: session.declare_publisher(k)
            for k in (
                keys.camera_key("uav0"),
                keys.imu_key("uav0"),
                keys.range_key("uav0"),
                keys.pose_vo_key("uav0"),
            )
        }
        assert _wait(lambda: all(p.matching_status.matching for p in publishers.values()))
        for i in range(3):
            stamp = float(flight.frame_stamps_s[i])
            messages = [
                (
                    keys.imu_key("uav0"),
                    ImuSample(
                        uav="uav0",
                        seq=i,
                        stamp_s=stamp - 0.001,
                        gyro_rad_s=flight.imu.gyro_rad_s[i],
                        accel_m_s2=flight.imu.accel_m_s2[i],
                    ),
                ),
                (
                    keys.range_key("uav0"),
                    RangeSample(uav="uav0", seq=i, stamp_s=stamp - 0.0005, range_m=1.5 + i),
                ),
                (
                    keys.camera_key("uav0"),
                    Frame(uav="uav0", seq=i, stamp_s=stamp, width=752, height=480, pixels=flight.frame(i)),
                ),
                (
                    keys.pose_vo_key("uav0"),
                    PoseEstimate(
                        uav="uav0",
                        seq=i,
                        stamp_s=stamp,
                        p_world_body_m=[i, 2.0, 3.0],
                        q_world_body=[1.0, 0, 0, 0],
                        covariance=np.eye(6) * (i + 1),
                        source="vo",
                    ),
                ),
            ]
            for key, message in messages:
                payload, attachment = encode(message)
                publishers[key].put(payload, attachment=attachment)
                sent.append((key, message))
        publishers[keys.camera_key("uav0")].put(b"garbage", attachment=b"\x01\x02")
        assert _wait(
            lambda: service.counters.get("recorded") == 12 and service.counters.get("malformed") == 1
        )
    service.request_stop()
    runner.join(10.0)
    assert not runner.is_alive()

    with out.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}  # compressed by default
        by_topic = {c.topic: c for c in summary.channels.values()}
        schemas = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert set(by_topic) == {
            keys.camera_key("uav0"),
            keys.imu_key("uav0"),
            keys.range_key("uav0"),
            keys.pose_vo_key("uav0"),
            keys.pose_vo_key("uav0") + "/in_frame",
        }
        assert schemas[keys.camera_key("uav0")].name == "foxglove.RawImage"
        assert by_topic[keys.camera_key("uav0")].message_encoding == "protobuf"
        assert schemas[keys.pose_vo_key("uav0") + "/in_frame"].name == "foxglove.PoseInFrame"
        imu_schema = json.loads(schemas[keys.imu_key("uav0")].data)
        assert (
            schemas[keys.imu_key("uav0")].encoding == "jsonschema"
            and "gyro_rad_s" in imu_schema["properties"]
        )
        poses = [m for _s, c, m in reader.iter_messages(topics=[keys.pose_vo_key("uav0")])]
        assert len(poses) == 3 and all(m.log_time > 0 and m.publish_time > 0 for m in poses)
        back = from_json(poses[2].data, PoseEstimate)
        assert np.array_equal(back.covariance, np.eye(6) * 3)  # type: ignore[attr-defined]  # lossless JSON

    recording = open_recording(out, "uav0")
    assert (recording.frames, recording.width, recording.height) == (3, 752, 480)
    replayed = list(recording.measurements())
    assert [type(m).__name__ for m in replayed] == [
        "ImuMeasurement",
        "RangeMeasurement",
        "FrameMeasurement",
    ] * 3
    frames = [m for m in replayed if type(m).__name__ == "FrameMeasurement"]
    for i, f in enumerate(frames):
        assert f.stamp_s == float(flight.frame_stamps_s[i]) and np.array_equal(f.image, flight.frame(i))  # type: ignore[attr-defined]


def test_broken_recordings_are_one_clear_error(tmp_path: Path) -> None:
    (tmp_path / "x.mcap").write_bytes(b"not mcap")
    with pytest.raises(RecordingError):
        open_recording(tmp_path / "x.mcap")
    with pytest.raises(RecordingError, match="no such recording"):
        open_recording(tmp_path / "missing.mcap")


def test_truncated_recording_is_one_clear_error(tmp_path: Path) -> None:
    from common.recordings.mcap import RecordingWriter

    flight = hover_flight(seed=0, n_frames=4)
    writer = RecordingWriter(tmp_path / "r.mcap")
    for i in range(4):
        frame = Frame(
            uav="u",
            seq=i,
            stamp_s=float(flight.frame_stamps_s[i]),
            width=752,
            height=480,
            pixels=flight.frame(i),
        )
        writer.write(keys.camera_key("u"), frame, 1000 + i)
    writer.close()
    data = (tmp_path / "r.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError):
        list(open_recording(tmp_path / "cut.mcap").measurements())
