"""A tap's queue is bounded in samples and, when given, in bytes; what does not fit is dropped and counted
(``dropped_full``), and handled samples give their bytes back (regression: the recorder's 256-sample queue
lost 2 of 20 frames on a loaded host while 400 IMU samples/s filled it)."""

from __future__ import annotations

from types import SimpleNamespace

from common.members import Role
from common.wire.schema import WireModel
from services.runtime.tap import KeyTap
from services.runtime.transport import TransportSettings
from services.tools.record.service import RecordSettings
from tests.services.fakes import FakeBytes


class _Tap(KeyTap):
    role = Role.RECORDER

    def __init__(self, queue: int, max_queue_bytes: int | None) -> None:
        super().__init__("tap", 0, TransportSettings(), queue, max_queue_bytes=max_queue_bytes)

    def tap_keys(self) -> tuple[str, ...]:
        return ("capataz/**",)

    def handle(self, key: str, message: WireModel, log_ns: int, publish_ns: int | None) -> None:
        pass


def _sample(size: int) -> SimpleNamespace:
    return SimpleNamespace(
        key_expr="capataz/x", payload=FakeBytes(b"\0" * size), attachment=None, timestamp=None
    )


def test_the_byte_bound_drops_what_does_not_fit_and_handling_gives_the_bytes_back() -> None:
    tap = _Tap(queue=100, max_queue_bytes=1000)
    for _ in range(4):
        tap._on_sample(_sample(300))  # type: ignore[arg-type]
    assert tap._queue.depth() == 3 and tap.counters.get("dropped_full") == 1
    for item in tap._queue.drain():
        tap._handle_item(item)  # malformed (counted), its bytes given back all the same
    assert tap.counters.get("malformed") == 3 and tap._queued_bytes == 0
    tap._on_sample(_sample(1000))  # type: ignore[arg-type]
    assert tap._queue.depth() == 1 and tap.counters.get("dropped_full") == 1


def test_the_sample_bound_still_holds_and_gives_the_bytes_back() -> None:
    tap = _Tap(queue=2, max_queue_bytes=10_000)
    for _ in range(3):
        tap._on_sample(_sample(10))  # type: ignore[arg-type]
    assert tap._queue.depth() == 2 and tap.counters.get("dropped_full") == 1 and tap._queued_bytes == 20


def test_the_recorder_keeps_a_second_of_frames_and_imu_many_times_over() -> None:
    settings = RecordSettings(out="x.mcap")  # type: ignore[arg-type]
    one_second = 20 * 361_000 + 400 * 150  # 752x480 frames at 20 fps and IMU samples at 400 Hz
    assert settings.queue >= 10 * 420 and (settings.queue_mb << 20) >= 10 * one_second
