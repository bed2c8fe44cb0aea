"""The foreman's crop store (previous-frame crops stay available for a second block of the same frame),
the speed measure its time balancing uses, and the forwarding of a worker's whole-block reply."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest

from common.dispatch import Dispatcher, DispatchSettings, SpeedSource
from common.dispatch.patchwork import PatchWorkError, merge_measurements
from common.messages import BlockJob, BlockResult, PatchJob, PatchResult, decode, encode
from common.transport import Counters
from common.yaw.correlation import PatchMeasurement
from services.foreman.service import CropStore, ForwardingScatter, forward_block_result
from services.master.scatter import FrameWork, RoundReport, Scatter, result_from_measurement


def crops(value: int, n: int) -> np.ndarray:
    return np.full((n, 4, 4), value, dtype=np.uint8)


def test_a_second_block_of_a_frame_still_finds_the_previous_frame() -> None:
    store = CropStore()
    store.add("s", 4, np.array([0, 1]), crops(4, 2))
    store.add("s", 5, np.array([0, 1]), crops(5, 2))  # first block of frame 5 done
    store.add("s", 4, np.array([7]), crops(40, 1))  # re-dispatched block of frame 5 brings its frame-4 crops
    got = store.get("s", 4, np.array([7, 0]), (4, 4))
    assert got[0, 0, 0] == 40 and got[1, 0, 0] == 4
    store.add("s", 6, np.array([0]), crops(6, 1))
    with pytest.raises(PatchWorkError, match="frame 4"):
        store.get("s", 4, np.array([0]), (4, 4))
    with pytest.raises(PatchWorkError, match="patch 3"):
        store.get("s", 5, np.array([3]), (4, 4))
    assert store.get("s", 6, np.array([], dtype=np.int64), (4, 4)).shape == (0, 4, 4)


class _Bytes:
    def __init__(self, data: bytes) -> None:
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


class _Reply:
    def __init__(self, payload: bytes, attachment: bytes) -> None:
        self.err = None
        self.ok = type("Sample", (), {"payload": _Bytes(payload), "attachment": _Bytes(attachment)})()


class _Workers:
    """A stand-in session: each get is answered at once by a worker that reports ``reported`` patches/s."""

    def __init__(self, reported: float, delay_s: float) -> None:
        self.reported = reported
        self.delay_s = delay_s

    def get(self, key: str, handler: Any, payload: bytes, attachment: bytes, **_kw: Any) -> None:
        job = decode(payload, attachment, PatchJob)
        time.sleep(self.delay_s)
        n = job.indices.size
        result = PatchResult(
            stream=job.stream, seq=job.seq, prev_seq=job.prev_seq, member=key, indices=job.indices,
            shift_px=np.zeros((n, 2)), confidence=np.ones(n), peak=np.ones(n), valid=np.ones(n, bool),
            compute_s=0.001, members={key: int(n)}, speeds={key: self.reported},
        )  # fmt: skip
        handler.callback(_Reply(*encode(result)))


@pytest.mark.parametrize("source", list(SpeedSource))
def test_time_balancing_uses_the_chosen_speed_measure(source: SpeedSource) -> None:
    dispatcher = Dispatcher(DispatchSettings(speed_source=source, ema_alpha=1.0), 8)
    dispatcher.join("worker/a/0")
    session: Any = _Workers(reported=1e6, delay_s=0.02)
    scatter = Scatter(session, dispatcher, str, PatchJob, PatchResult, Counters())
    work = FrameWork(
        stream="s", seq=1, prev_seq=0, settings={}, budget_s=1.0,
        crops=lambda idx: np.zeros((idx.size, 4, 4), np.uint8),
        prev_crops=lambda idx: np.zeros((idx.size, 4, 4), np.uint8),
        compute_self=lambda idx, moved: pytest.fail("nothing is computed locally"),
    )  # fmt: skip
    report = scatter.run(work, dispatcher.plan(1, 0, time.monotonic()))
    assert report.members == {"worker/a/0": 8}
    speed = dispatcher.speed("worker/a/0")
    assert speed is not None
    if source is SpeedSource.REPORTED:
        assert speed == 1e6
    else:  # 8 patches in at least the 20 ms the reply took
        assert 0 < speed <= 8 / 0.02


class _MeasuringWorkers:
    """A stand-in session whose workers answer with varied measurements (NaN shifts at invalid patches)."""

    def __init__(self, bad_indices: bool = False) -> None:
        self.bad_indices = bad_indices
        self.requests = 0

    def get(self, key: str, handler: Any, payload: bytes, attachment: bytes, **_kw: Any) -> None:
        self.requests += 1
        job = decode(payload, attachment, PatchJob)
        idx = job.indices
        valid = idx % 3 != 0
        shift = np.stack([np.sin(idx), np.cos(idx)], axis=1)
        shift[~valid] = np.nan
        result = PatchResult(
            stream=job.stream, seq=job.seq, prev_seq=job.prev_seq, member=key,
            indices=idx[::-1].copy() if self.bad_indices else idx, shift_px=shift,
            confidence=np.sqrt(idx + 1.0), peak=1.0 / (idx + 1.0), valid=valid,
            compute_s=0.002, members={key: int(idx.size)}, speeds={key: 500.0 + idx.size},
        )  # fmt: skip
        handler.callback(_Reply(*encode(result)))


def _round(
    workers: list[str], session: Any, compute_self: Any = None
) -> tuple[BlockJob, ForwardingScatter, RoundReport]:
    n = 12
    dispatcher = Dispatcher(DispatchSettings(), n)
    for worker in workers:
        dispatcher.join(worker)
    scatter = ForwardingScatter(session, dispatcher, str, PatchJob, PatchResult, Counters())
    indices = np.arange(n, dtype=np.int32)
    job = BlockJob(
        stream="s", seq=3, prev_seq=2, settings={}, indices=indices, crops=crops(1, n),
        prev_indices=indices[:0], prev_crops=crops(1, 0), budget_s=1.0,
    )  # fmt: skip
    work = FrameWork(
        stream="s", seq=3, prev_seq=2, settings={}, budget_s=1.0,
        crops=lambda idx: crops(1, idx.size), prev_crops=lambda idx: crops(1, idx.size),
        compute_self=compute_self or (lambda idx, moved: pytest.fail("nothing is computed locally")),
    )  # fmt: skip
    scatter.block_indices = job.indices
    report = scatter.run(work, dispatcher.plan(3, 2, time.monotonic(), job.indices))
    return job, scatter, report


def test_a_forwarded_whole_block_reply_equals_the_merged_and_re_encoded_one() -> None:
    job, scatter, report = _round(["worker/a/0"], _MeasuringWorkers())
    assert scatter.forward is not None and len(report.parts) == 1
    members, speeds = report.members, {"worker/a/0": 321.0}
    forwarded = forward_block_result(scatter.forward, job, "foreman/a/0", 0.003, members, speeds)
    merged = merge_measurements(report.parts, job.indices)
    encoded = encode(result_from_measurement(BlockResult, job, "foreman/a/0", merged, 0.003, members, speeds))
    assert forwarded == encoded  # the same bytes, so the master decodes the same BlockResult
    result = decode(*forwarded, BlockResult)
    assert result.member == "foreman/a/0" and result.members == {"worker/a/0": 12}
    np.testing.assert_array_equal(result.indices, job.indices)
    assert np.isnan(result.shift_px[~result.valid]).all() and result.valid.sum() == 8


def test_a_split_block_is_merged_not_forwarded() -> None:
    _job, scatter, report = _round(["worker/a/0", "worker/a/1"], _MeasuringWorkers())
    assert scatter.forward is None and len(report.parts) == 2


def test_a_whole_block_reply_with_other_indices_is_refused_and_redone() -> None:
    computed: list[np.ndarray] = []

    def compute_self(idx: np.ndarray, moved: np.ndarray) -> PatchMeasurement:
        computed.append(idx)
        zeros = np.zeros(idx.size)
        return PatchMeasurement(idx, np.zeros((idx.size, 2)), zeros, zeros, np.ones(idx.size, bool))

    _job, scatter, report = _round(["worker/a/0"], _MeasuringWorkers(bad_indices=True), compute_self)
    assert scatter.forward is None
    assert scatter.counters.counts()["malformed_replies"] == 1
    assert report.redispatched == 1 and np.array_equal(np.concatenate(computed), np.arange(12))
