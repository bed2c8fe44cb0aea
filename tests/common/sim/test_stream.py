"""The one way a simulated flight becomes a stream (common/sim/stream.py): every sample of the window once,
in stamp order, equal stamps in SENSOR_ORDER, so every sensor sample up to a frame's stamp precedes it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.estimation.measurements import (
    SENSOR_ORDER,
    FrameMeasurement,
    ImuMeasurement,
    RangeMeasurement,
    sensor_of,
)
from common.sim.flight import Flight, hover_flight
from common.sim.ground import GroundTexture
from common.sim.stream import flight_measurements

N_FRAMES = 12


@pytest.fixture(scope="module")
def flight(small_texture: GroundTexture) -> Flight:
    return hover_flight(
        seed=0, n_frames=N_FRAMES, camera=CameraModel.from_hfov(64, 48, 60.0), texture=small_texture
    )


def test_equal_stamps_come_range_then_imu_then_frame(flight: Flight) -> None:
    at_100ms = [m for m in flight_measurements(flight, 0, 3) if m.stamp_s == 0.1]
    assert [type(m) for m in at_100ms] == [RangeMeasurement, ImuMeasurement, FrameMeasurement]


@settings(max_examples=25, deadline=None)
@given(start=st.integers(0, N_FRAMES - 1), length=st.integers(1, N_FRAMES + 3))
def test_a_window_holds_each_sample_once_in_stamp_and_sensor_order(
    flight: Flight, start: int, length: int
) -> None:
    stream = list(flight_measurements(flight, start, start + length))
    stop = min(start + length, N_FRAMES)
    keys = [(m.stamp_s, SENSOR_ORDER[sensor_of(m)]) for m in stream]
    assert keys == sorted(keys)
    frames = [m for m in stream if isinstance(m, FrameMeasurement)]
    assert [f.stamp_s for f in frames] == flight.frame_stamps_s[start:stop].tolist()
    for f, i in zip(frames[:2], range(start, stop), strict=False):
        assert np.array_equal(f.image, flight.frame(i))
    t0, t1 = flight.frame_stamps_s[start], flight.frame_stamps_s[stop - 1]
    imu = [m for m in stream if isinstance(m, ImuMeasurement)]
    inside = (flight.imu.stamps_s >= t0) & (flight.imu.stamps_s <= t1)
    assert [m.stamp_s for m in imu] == flight.imu.stamps_s[inside].tolist()
    assert np.array_equal([m.gyro_rad_s for m in imu], flight.imu.gyro_rad_s[inside])
    assert np.array_equal([m.accel_m_s2 for m in imu], flight.imu.accel_m_s2[inside])
    ranges = [m for m in stream if isinstance(m, RangeMeasurement)]
    inside = (flight.range.stamps_s >= t0) & (flight.range.stamps_s <= t1)
    assert [m.stamp_s for m in ranges] == flight.range.stamps_s[inside].tolist()
    assert [m.range_m for m in ranges] == flight.range.range_m[inside].tolist()
    assert isinstance(stream[-1], FrameMeasurement)  # nothing after the last frame


def test_the_localizers_office_start_is_the_simulated_office_flights_first_state() -> None:
    """common.localization.office keeps the office flight's start as a constant (a service may not import
    the simulator); this ties it to the simulator."""
    from common.localization.office import OFFICE_START_STATE
    from common.sim.scene import default_flight

    assert np.allclose(default_flight(n_frames=2).states[0], OFFICE_START_STATE, atol=1e-12)
