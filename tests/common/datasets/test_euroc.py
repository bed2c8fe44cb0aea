"""EuRoC folders: a simulated flight written in the EuRoC layout reads back as the same stream, with its
calibration and ground truth; a broken folder is one EurocError."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.camera import CameraModel
from common.datasets.euroc import EurocError, open_euroc, write_euroc
from common.datasets.tum import Trajectory
from common.estimation.measurements import FrameMeasurement, ImuMeasurement
from common.sim.flight import hover_flight
from common.sim.stream import flight_measurements


def test_euroc_folder_reads_back_the_simulated_stream(tmp_path: Path) -> None:
    flight = hover_flight(seed=0, n_frames=5)
    stream = list(flight_measurements(flight))
    truth = Trajectory(flight.frame_stamps_s, flight.p_world_body_m, flight.q_world_body)
    info = CameraModel.default()
    write_euroc(tmp_path / "MH_sim", stream, info, truth)
    folder = open_euroc(tmp_path / "MH_sim")
    expected = stream  # in the same order: stamp order, equal stamps in SENSOR_ORDER
    read = list(folder.measurements())
    assert [type(m) for m in read] == [type(m) for m in expected]
    assert [m.stamp_s for m in read] == [m.stamp_s for m in expected]
    for r, e in zip(read, expected, strict=True):
        if isinstance(r, FrameMeasurement):
            assert np.array_equal(r.image, e.image)  # type: ignore[union-attr]
        elif isinstance(r, ImuMeasurement):
            assert np.array_equal(r.gyro_rad_s, e.gyro_rad_s)  # type: ignore[union-attr]
        else:
            assert r.range_m == e.range_m  # type: ignore[union-attr]
    assert folder.camera_info == info
    assert folder.ground_truth is not None
    assert np.array_equal(folder.ground_truth.p_world_body_m, truth.p_world_body_m)
    # the mav0 folder itself is accepted too
    assert len(open_euroc(tmp_path / "MH_sim" / "mav0").camera) == 5


def test_broken_euroc_folders_are_one_clear_error(tmp_path: Path) -> None:
    flight = hover_flight(seed=0, n_frames=3)
    write_euroc(tmp_path / "e", flight_measurements(flight))
    imu = tmp_path / "e" / "mav0" / "imu0" / "data.csv"
    imu.write_text(imu.read_text() + "123,1,2\n")
    with pytest.raises(EurocError, match="imu0"):
        open_euroc(tmp_path / "e")
    with pytest.raises(EurocError, match="not a EuRoC folder"):
        open_euroc(tmp_path / "e" / "mav0" / "imu0")
