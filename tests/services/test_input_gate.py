"""The one input gate (services/runtime/gate.py) and the consumers that use it: a refused input never changes
state, is counted once, and a real restart is adopted after the documented confirmation."""

from __future__ import annotations

import time

import numpy as np
import pytest

from common.streams import FrameGateSettings, GateVerdict
from common.wire.messages import Frame, ImuSample
from common.yaw import gyro_delta_yaw_rad
from services.master.gyro import GyroPrior
from services.runtime.counters import Counters
from services.runtime.gate import InputGate

RATE_HZ = 200.0


class _Service:
    def __init__(self) -> None:
        self.counters = Counters()
        self.lines: list[str] = []

    def count_error(self, counter: str, what: str, exc: BaseException | str) -> None:
        self.counters.inc(counter)
        self.lines.append(f"{what} ({counter}): {exc}")


def _imu(k: int, uav: str = "uav0", stamp_s: float | None = None, rate_z: float = 0.5) -> ImuSample:
    return ImuSample(
        uav=uav,
        seq=k,
        stamp_s=k / RATE_HZ if stamp_s is None else stamp_s,
        gyro_rad_s=np.array([0.0, 0.0, rate_z]),
        accel_m_s2=np.array([0.0, 0.0, 9.81]),
    )


def _prior() -> tuple[GyroPrior, _Service]:
    service = _Service()
    gate = InputGate("uav0", service)
    return GyroPrior(True, 0.0, service.counters, gate), service


def _feed(prior: GyroPrior, first: int, last: int, source: str = "cam") -> None:
    for k in range(first, last):
        prior.on_sample(_imu(k), source)


def _delta(prior: GyroPrior, start_s: float, stop_s: float) -> float | None:
    return prior.delta_rad(start_s, stop_s, {})


def _truth(start_s: float, stop_s: float) -> float:
    stamps = np.arange(0, 400) / RATE_HZ
    gyro = np.tile([0.0, 0.0, 0.5], (stamps.size, 1))
    value = gyro_delta_yaw_rad(stamps, gyro, start_s, stop_s)
    assert value is not None
    return value


def test_future_imu_sample_does_not_lock_the_gyro_prior_out() -> None:
    """Regression (issue 27): one IMU sample stamped in the future made the master's buffer refuse every later
    real sample until restart."""
    prior, service = _prior()
    _feed(prior, 0, 100)
    prior.on_sample(_imu(100, stamp_s=1e4), "cam")  # hours ahead of the stream
    _feed(prior, 100, 200)
    assert service.counters.get("refused_imu_stamp_jump") == 1
    assert service.counters.get("imu_in") == 200 and service.counters.get("imu_refused") == 0
    assert _delta(prior, 0.6, 0.9) == pytest.approx(_truth(0.6, 0.9), abs=1e-12)


def test_foreign_uav_and_second_sender_imu_samples_are_refused_and_counted() -> None:
    """Regression (issue 27): an IMU sample of another UAV, or of a second sender, reached the master."""
    prior, service = _prior()
    _feed(prior, 0, 50)
    prior.on_sample(_imu(50, uav="uav1", rate_z=9.0), "cam")
    prior.on_sample(_imu(50, rate_z=9.0), "forger")
    _feed(prior, 50, 100)
    assert service.counters.get("refused_imu_foreign_uav") == 1
    assert service.counters.get("refused_imu_foreign_sender") == 1
    assert service.counters.get("imu_in") == 100
    assert _delta(prior, 0.1, 0.4) == pytest.approx(_truth(0.1, 0.4), abs=1e-12)


def test_a_real_imu_clock_jump_is_adopted_after_the_confirmation_and_starts_the_buffer_over() -> None:
    prior, service = _prior()
    _feed(prior, 0, 50)
    confirm = FrameGateSettings().confirm_frames
    for k in range(confirm + 5):  # the IMU restarted from t = 0 (stamps go back): confirm_frames in a row
        prior.on_sample(_imu(k), "cam")
    assert service.counters.get("refused_imu_stamp_backward") == confirm - 1
    assert service.counters.get("epochs_imu") == 1
    assert len(prior.buffer) == 6  # the restarted stream only


def test_a_frame_gate_refusal_changes_nothing_and_health_reads_it() -> None:
    service = _Service()
    gate = InputGate("uav0", service, window_s=60.0)
    pixels = np.zeros((4, 6), np.uint8)

    def frame(seq: int, stamp_s: float, uav: str = "uav0") -> Frame:
        return Frame(uav=uav, seq=seq, stamp_s=stamp_s, width=6, height=4, pixels=pixels)

    now = time.monotonic()
    assert gate.admit("camera", frame(0, 0.0), "cam", now).verdict is GateVerdict.NEW_EPOCH
    assert gate.admit("camera", frame(1, 0.05), "cam", now + 0.05).verdict is GateVerdict.ACCEPT
    refused = [frame(2**53, 0.1), frame(2, 0.1, uav="uav1"), frame(2, 1e6)]
    assert all(gate.admit("camera", f, "cam", now + 0.1).verdict is GateVerdict.REFUSE for f in refused)
    assert gate.admit("camera", frame(2, 0.1), "cam", now + 0.1).verdict is GateVerdict.ACCEPT
    assert gate.epoch("camera") == 0
    assert gate.recent_refusals() == 3 and len(service.lines) == 3
    names = {"refused_camera_seq_jump", "refused_camera_foreign_uav", "refused_camera_stamp_jump"}
    assert all(service.counters.get(n) == 1 for n in names)
