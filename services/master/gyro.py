"""The master's gyro prior: IMU samples of the stream (``capataz/uav/{uav}/imu``) in a bounded buffer, the
gyro's rotation between two frame stamps for the yaw core's honest integration, and the body's tilt at a
frame for its level views (:func:`common.yaw.level.R_level_body_from_imu`, the same bits as in-process).

The delta is :func:`common.yaw.gyro_delta_yaw_rad` on the buffered samples: it uses only the samples from
the last one at or before the earlier stamp to the last one at or before the later stamp, so when the buffer
holds them the master's prior has the same bits as the in-process tracker's (fed the flight's IMU series).
The camera publishes every IMU sample up to a frame's stamp before the frame; the master still waits a
bounded time for samples that reach the later stamp (another route may deliver them a little later).
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
import time

import numpy as np
import numpy.typing as npt

from common.streams import GateVerdict
from common.types import FloatArray
from common.wire.messages import ImuSample
from common.yaw import gyro_delta_yaw_rad
from common.yaw.level import DEFAULT_UP_WINDOW_S, R_level_body_from_imu
from common.yaw.mount import imu_stamp_s
from services.master.lens import YawPriorSettings
from services.runtime.counters import Counters
from services.runtime.gate import InputGate

logger = logging.getLogger(__name__)

#: Samples kept (10 s at 400 Hz): enough for any frame interval the master bridges.
DEFAULT_CAPACITY = 4000


class GyroBuffer:
    """Thread-safe, bounded, time-ordered gyro samples of one stream (out-of-order samples are dropped)."""

    def __init__(self, capacity: int = DEFAULT_CAPACITY, sample_period_tolerance_s: float = 0.01) -> None:
        self._stamps: list[float] = []
        self._gyro: list[np.ndarray] = []
        self._accel: list[np.ndarray] = []
        self._capacity = capacity
        self._cond = threading.Condition()
        self._tolerance_s = sample_period_tolerance_s
        self.out_of_order = 0

    def clear(self) -> None:
        """Forget every sample (the stream restarted: a new epoch at the input gate)."""
        with self._cond:
            self._stamps.clear()
            self._gyro.clear()
            self._accel.clear()

    def add(self, sample: ImuSample) -> bool:
        """Append a sample; False (and counted) when it is not newer than the newest held. A sample older
        than everything held means the stream restarted: the buffer starts over."""
        gyro = np.asarray(sample.gyro_rad_s, dtype=np.float64)
        if gyro.shape != (3,) or not np.all(np.isfinite(gyro)) or not math.isfinite(sample.stamp_s):
            return False
        with self._cond:
            if self._stamps and sample.stamp_s <= self._stamps[-1]:
                if sample.stamp_s >= self._stamps[0]:
                    self.out_of_order += 1
                    return False
                self._stamps.clear()
                self._gyro.clear()
                self._accel.clear()
            self._stamps.append(float(sample.stamp_s))
            self._gyro.append(gyro)
            self._accel.append(np.asarray(sample.accel_m_s2, dtype=np.float64))
            if len(self._stamps) > 2 * self._capacity:  # trim in chunks: amortised O(1) per sample
                del self._stamps[: -self._capacity]
                del self._gyro[: -self._capacity]
                del self._accel[: -self._capacity]
            self._cond.notify_all()
        return True

    def __len__(self) -> int:
        with self._cond:
            return len(self._stamps)

    def delta_rad(
        self, start_s: float, stop_s: float, wait_s: float = 0.0, axis_imu: npt.ArrayLike = (0.0, 0.0, 1.0)
    ) -> float | None:
        """The gyro's rotation weighed by ``axis_imu`` from ``start_s`` to ``stop_s`` (the IMU's clock), or
        None without coverage; waits up to ``wait_s`` for samples reaching ``stop_s`` (not when no sample has
        arrived at all)."""
        deadline = time.monotonic() + wait_s
        with self._cond:
            while self._stamps and self._stamps[-1] < stop_s - self._tolerance_s:
                left = deadline - time.monotonic()
                if left <= 0.0:
                    break
                self._cond.wait(left)
            first = bisect.bisect_right(self._stamps, start_s) - 1
            last = bisect.bisect_right(self._stamps, stop_s) - 1
            if first < 0 or last < 0:
                return None
            stamps = np.array(self._stamps[first : last + 1], dtype=np.float64)
            gyro = np.stack(self._gyro[first : last + 1])
        return gyro_delta_yaw_rad(stamps, gyro, start_s, stop_s, axis_imu)

    def tilt(self, stamp_s: float, R_body_imu: npt.ArrayLike) -> FloatArray | None:
        """The body's tilt at ``stamp_s`` (the IMU's clock) from the samples of the window before it (None
        without enough of them): call after :meth:`delta_rad` has waited for the samples reaching it."""
        with self._cond:
            first = bisect.bisect_right(self._stamps, stamp_s - DEFAULT_UP_WINDOW_S)
            last = bisect.bisect_right(self._stamps, stamp_s)
            if last - first < 2:
                return None
            stamps = np.array(self._stamps[first:last], dtype=np.float64)
            gyro, accel = np.stack(self._gyro[first:last]), np.stack(self._accel[first:last])
        return R_level_body_from_imu(stamps, gyro, accel, stamp_s, R_body_imu)


class GyroPrior:
    """The master's side of the yaw prior: IMU samples in (through the master's input gate), the gyro's delta
    between frame stamps out, weighed by ``axis_imu`` (:func:`~common.yaw.mount.image_turn_axis_imu` of the
    mount and the IMU's axes: the body's yaw rate times the cosine of the camera's tilt) and between the
    frame stamps moved onto the IMU's clock (``t_imu = t_cam + time_offset_s``).

    A sample the gate refuses (another UAV's, a second sender's, a stamp in the future or jumping) never
    reaches the buffer, so no single sample can make the buffer refuse the real ones after it; a restart the
    gate adopts (a new epoch) starts the buffer over."""

    message_type = ImuSample

    def __init__(
        self,
        enabled: bool,
        wait_s: float,
        counters: Counters,
        gate: InputGate,
        axis_imu: npt.ArrayLike = (0.0, 0.0, 1.0),
        time_offset_s: float = 0.0,
        level: bool = False,
        R_body_imu: npt.ArrayLike | None = None,
    ) -> None:
        self.enabled = enabled
        #: level each pair's views by the IMU's tilt (asked for); :meth:`for_stream` keeps it for a stream
        #: whose lens the master knows (the level views need the intrinsics)
        self.level_views = level
        self.level = level
        self.R_body_imu = np.eye(3) if R_body_imu is None else np.asarray(R_body_imu, dtype=np.float64)
        self.wait_s = wait_s
        self.buffer = GyroBuffer()
        self._counters = counters
        self.axis_imu = np.asarray(axis_imu, dtype=np.float64)
        self.time_offset_s = float(time_offset_s)
        self._gate = gate

    @classmethod
    def of(cls, prior: YawPriorSettings, counters: Counters, gate: InputGate, name: str) -> GyroPrior:
        """The prior the master's settings describe (logged in one line)."""
        axis, mount = prior.gyro_axis_imu(), prior.rig_mount
        level = prior.gyro_prior and prior.level_views
        logger.info(
            "%s: gyro prior %s, level views %s, the IMU's weights %s (%s)", name,
            "on" if prior.gyro_prior else "off", "on" if level else "off", np.round(axis, 4).tolist(),
            mount.describe(),
        )  # fmt: skip
        return cls(
            prior.gyro_prior, prior.gyro_wait_s, counters, gate, axis, mount.imu_time_offset_s, level,
            mount.R_body_imu,
        )  # fmt: skip

    def for_stream(
        self, axis_imu: FloatArray, time_offset_s: float, R_body_imu: FloatArray, lensed: bool, name: str
    ) -> None:
        """A new stream's IMU axes and clock offset; the level views only with its lens (else said once)."""
        self.axis_imu, self.time_offset_s, self.R_body_imu = axis_imu, time_offset_s, R_body_imu
        self.level = self.level_views and lensed
        if self.level_views and not lensed:
            logger.warning(
                "%s: --level-views needs the camera's intrinsics: the fixed view for this stream", name
            )

    def on_sample(self, imu: ImuSample | None, source: str | None = None) -> None:
        """A decoded IMU sample from ``source`` (None: it failed to decode, counted by the runtime)."""
        if imu is None:
            return
        decision = self._gate.admit("imu", imu, source)
        if decision.verdict is GateVerdict.REFUSE:
            return
        if decision.verdict is GateVerdict.NEW_EPOCH:
            self.buffer.clear()
        self._counters.inc("imu_in" if self.buffer.add(imu) else "imu_refused")

    def delta_rad(
        self, previous_stamp_s: float | None, stamp_s: float, counts: dict[str, int]
    ) -> float | None:
        """The gyro's rotation since the previous frame (None without IMU coverage or when disabled),
        counted as ``gyro_prior`` or ``no_gyro_prior`` in ``counts`` (the frame's, added to the service's
        counters once, at its end)."""
        if not self.enabled or previous_stamp_s is None:
            return None
        offset = self.time_offset_s
        delta = self.buffer.delta_rad(
            imu_stamp_s(previous_stamp_s, offset), imu_stamp_s(stamp_s, offset), self.wait_s, self.axis_imu
        )
        name = "gyro_prior" if delta is not None else "no_gyro_prior"
        counts[name] = counts.get(name, 0) + 1
        return delta

    def tilt(self, stamp_s: float | None, counts: dict[str, int]) -> FloatArray | None:
        """The body's tilt at a frame (:meth:`GyroBuffer.tilt`; None when levelling is off, the frame
        unstamped or the window's samples missing), counted as ``tilt`` or ``no_tilt`` in ``counts``."""
        if not (self.enabled and self.level) or stamp_s is None:
            return None
        tilt = self.buffer.tilt(imu_stamp_s(stamp_s, self.time_offset_s), self.R_body_imu)
        name = "tilt" if tilt is not None else "no_tilt"
        counts[name] = counts.get(name, 0) + 1
        return tilt
