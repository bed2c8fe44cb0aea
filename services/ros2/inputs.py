"""Admission of ROS 2 sensor samples: the stream gate every capataz camera stream passes
(:func:`common.streams.admit_frame`), one state per ``(uav, stream)``.

The bridge numbers each stream's messages in arrival order (the ``seq`` capataz streams carry); a sample
whose stamp goes back, jumps ahead, lies in the future, or whose size or encoding differs from the stream's
is refused with the gate's reason (``stamp_backward``, ``stamp_jump``, ``future_stamp``, ``wrong_size``, ...),
and a consistent restart (a replayed bag, a rebooted driver) is adopted after the gate's confirmation.
IMU and range streams pass the same gate with a fixed key (their "size" never changes).
"""

from __future__ import annotations

import threading
import time

from common.streams import Decision, FrameGateSettings, FrameGateState, FrameKey, admit_frame

#: the key of the streams without an image size
SENSOR_KEYS = {"imu": FrameKey(0, 0, "imu"), "range": FrameKey(0, 0, "range")}


class SensorGates:
    """One gate per ``(uav, stream)``; :meth:`next_seq` numbers arrivals, :meth:`admit` decides."""

    def __init__(self, settings: FrameGateSettings | None = None) -> None:
        self.settings = settings or FrameGateSettings()
        self._states: dict[tuple[str, str], FrameGateState] = {}
        self._seq: dict[tuple[str, str], int] = {}
        self._lock = threading.Lock()

    def next_seq(self, uav: str, stream: str) -> int:
        with self._lock:
            seq = self._seq[uav, stream] = self._seq.get((uav, stream), -1) + 1
            return seq

    def admit(self, uav: str, stream: str, seq: int, stamp_s: float, key: FrameKey | None = None) -> Decision:
        """The gate's decision about one sample (``key``: the image's size and encoding; None for sensors)."""
        with self._lock:
            state = self._states.get((uav, stream), FrameGateState())
            state, decision = admit_frame(
                state,
                self.settings,
                uav,
                uav,
                seq,
                stamp_s,
                key or SENSOR_KEYS.get(stream, FrameKey(0, 0, stream)),
                time.monotonic(),
                time.time(),
            )
            self._states[uav, stream] = state
        return decision
