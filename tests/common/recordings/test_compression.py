"""A recording's chunk compression: every compression reads back exactly the messages written (the same
channels, times and bytes as the uncompressed file), the chunks say which compression they carry, and a
compressed file is smaller than the uncompressed one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.estimation.measurements import FrameMeasurement
from common.recordings.mcap import Compression, RecordingWriter, open_recording
from common.sim.flight import hover_flight
from common.wire.messages import Frame, ImuSample, PoseEstimate

Record = tuple[str, int, int, bytes]


def write(path: Path, compression: Compression) -> None:
    flight = hover_flight(seed=1, n_frames=6)
    writer = RecordingWriter(path, compression)
    for i in range(6):
        stamp = float(flight.frame_stamps_s[i])
        ns = round(stamp * 1e9) + 1_000_000_000  # log times are unsigned
        imu = ImuSample(uav="uav0", seq=i, stamp_s=stamp - 1e-3, gyro_rad_s=flight.imu.gyro_rad_s[i],
                        accel_m_s2=flight.imu.accel_m_s2[i])  # fmt: skip
        writer.write("capataz/uav/uav0/imu", imu, ns - 1_000_000)
        frame = Frame(uav="uav0", seq=i, stamp_s=stamp, width=752, height=480, pixels=flight.frame(i))
        writer.write("capataz/uav/uav0/camera", frame, ns, ns - 5)
        pose = PoseEstimate(uav="uav0", seq=i, stamp_s=stamp, p_world_body_m=flight.p_world_body_m[i],
                            q_world_body=flight.q_world_body[i], covariance=np.eye(6),
                            source="vo")  # fmt: skip
        writer.write("capataz/uav/uav0/pose/vo", pose, ns + 1)
    writer.close()


def read(path: Path) -> tuple[list[Record], set[str]]:
    """Every message (topic, log time, publish time, bytes) and the chunks' compressions."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        compressions = {c.compression for c in summary.chunk_indexes}
        records = [
            (c.topic, m.log_time, m.publish_time, bytes(m.data)) for _s, c, m in reader.iter_messages()
        ]
    return records, compressions


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[Compression, Path]:
    folder = tmp_path_factory.mktemp("compression")
    paths = {c: folder / f"{c.value}.mcap" for c in Compression}
    for compression, path in paths.items():
        write(path, compression)
    return paths


@pytest.mark.parametrize("compression", [Compression.LZ4, Compression.ZSTD])
def test_a_compressed_recording_reads_back_the_same_messages_and_is_smaller(
    files: dict[Compression, Path], compression: Compression
) -> None:
    plain, plain_compressions = read(files[Compression.NONE])
    records, compressions = read(files[compression])
    assert plain_compressions == {""} and compressions == {compression.value}
    assert len(records) == len(plain) == 6 * 4  # imu, frame, pose and its PoseInFrame per frame
    assert records == plain
    assert files[compression].stat().st_size < files[Compression.NONE].stat().st_size


def test_a_compressed_recording_replays_its_frames(files: dict[Compression, Path]) -> None:
    flight = hover_flight(seed=1, n_frames=6)
    recording = open_recording(files[Compression.ZSTD])
    frames = [m for m in recording.measurements() if isinstance(m, FrameMeasurement)]
    assert len(frames) == 6
    assert all(np.array_equal(f.image, flight.frame(i)) for i, f in enumerate(frames))


def test_zstd_is_the_default() -> None:
    import inspect

    assert inspect.signature(RecordingWriter).parameters["compression"].default is Compression.ZSTD
