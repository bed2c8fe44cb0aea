"""A turning frame's second pass on the members (:mod:`services.runtime.transient`): a foreman measures a
transient block with the previous crops it holds, spread over its workers, and keeps nothing of it; a worker
measures a transient job only with the previous crops of all its patches; a part whose member fails (error,
a reply for another frame, no reply) comes back as None, counted, for its sender to measure."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from common.dispatch import SELF
from common.wire import keys
from common.wire.codec import decode, encode, read_error_reply
from common.wire.messages import BlockJob, BlockResult, PatchJob, PatchResult
from common.yaw.patchwork import measure_crops
from services.foreman.service import ForemanService, ForemanSettings
from services.runtime.counters import Counters
from services.runtime.transient import TransientPart, gather, send_parts
from services.runtime.transport import open_session, zbytes
from services.worker.service import WorkerService, WorkerSettings
from tests.builders import JOB_SETTINGS, patch_job
from tests.services.fakes import FakeBytes, FakeChannel
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until

pytestmark = pytest.mark.zenoh

SIDE = int(JOB_SETTINGS.patch_size_px)
N = 6


def _crops(seed: int) -> np.ndarray:
    """Textured crops: a frame's patches (each seed a different frame)."""
    return np.random.default_rng(seed).integers(0, 256, (N, SIDE, SIDE), dtype=np.uint8)


@contextmanager
def _node(endpoint: str, workers: int) -> Iterator[tuple[ForemanService, list[WorkerService]]]:
    foreman = ForemanService("h", 0, peer(endpoint), ForemanSettings())
    members = [WorkerService("h", i, peer(endpoint), WorkerSettings()) for i in range(workers)]
    threads = [threading.Thread(target=s.run, daemon=True) for s in (foreman, *members)]
    for thread in threads:
        thread.start()
    try:
        assert foreman.started.wait(WAIT_S) and all(w.started.wait(WAIT_S) for w in members)
        assert wait_until(lambda: foreman.counters.get("members_joined") >= workers)
        yield foreman, members
    finally:
        for service in (foreman, *members):
            service.request_stop()
        for thread in threads:
            thread.join(5.0)


def _ask(endpoint: str, key: str, job: PatchJob, result_type: type[PatchResult]) -> PatchResult | str:
    with open_session(peer(endpoint)) as session:
        querier = session.declare_querier(key, timeout=WAIT_S)
        assert matched(querier)
        reply = querier.get(payload=(sent := encode(job))[0], attachment=sent[1]).recv()
        querier.undeclare()
    if reply.err is not None:
        return read_error_reply(zbytes(reply.err.payload))
    return decode(zbytes(reply.ok.payload), zbytes(reply.ok.attachment), result_type)


def _shifts(result: PatchResult | str) -> np.ndarray:
    assert isinstance(result, PatchResult), result
    return np.asarray(result.shift_px)


def test_a_foreman_measures_a_transient_block_over_its_workers_and_keeps_nothing() -> None:
    indices = np.arange(N, dtype=np.int32)
    frame0, frame1, turned1, frame2 = _crops(0), _crops(1), _crops(11), _crops(2)
    settings = JOB_SETTINGS.yaw_settings
    with hub() as endpoint, _node(endpoint, workers=2) as (foreman, workers):
        key = keys.foreman_key("h")
        first = patch_job(N, SIDE, cls=BlockJob, seq=1, prev_seq=0, crops=frame1, prev_indices=indices,
                          prev_crops=frame0)  # fmt: skip
        assert isinstance(_ask(endpoint, key, first, BlockResult), BlockResult)
        # frame 1 turned back, measured against frame 0's crops, which the foreman holds
        transient = patch_job(N, SIDE, cls=BlockJob, seq=1, prev_seq=0, crops=turned1, transient=True)
        jobs_before = sum(w.counters.get("jobs") for w in workers)
        got = _ask(endpoint, key, transient, BlockResult)
        expected = measure_crops(settings, indices, turned1, frame0)
        assert np.array_equal(_shifts(got), expected.shift_px, equal_nan=True)
        assert wait_until(lambda: foreman.counters.get("transient_blocks") == 1)  # counted after the reply
        # one part on each active worker (two on a quiet host; a worker that missed a deadline on a busy one
        # is paused), counted after their replies: polled
        assert wait_until(lambda: sum(w.counters.get("jobs") for w in workers) - jobs_before >= 1)
        assert sum(w.counters.get("jobs") for w in workers) - jobs_before <= 2
        # nothing of it was kept: frame 2 is measured against frame 1's own crops
        second = patch_job(N, SIDE, cls=BlockJob, seq=2, prev_seq=1, crops=frame2)
        after = _ask(endpoint, key, second, BlockResult)
        expected2 = measure_crops(settings, indices, frame2, frame1)
        assert np.array_equal(_shifts(after), expected2.shift_px, equal_nan=True)


def test_a_foreman_without_the_previous_crops_refuses_a_transient_block() -> None:
    with hub() as endpoint, _node(endpoint, workers=1) as (foreman, _):
        transient = patch_job(N, SIDE, cls=BlockJob, seq=7, prev_seq=6, crops=_crops(7), transient=True)
        got = _ask(endpoint, keys.foreman_key("h"), transient, BlockResult)
        assert isinstance(got, str) and "no crops of frame 6" in got
        assert foreman.counters.get("rejected") == 1


def test_a_worker_refuses_a_transient_job_without_its_previous_crops() -> None:
    with hub() as endpoint, _node(endpoint, workers=1) as (_, workers):
        key = keys.worker_key("h", 0)
        job = patch_job(N, SIDE, seq=3, prev_seq=2, crops=_crops(3), transient=True)
        got = _ask(endpoint, key, job, PatchResult)
        assert isinstance(got, str) and "previous crops of all its patches" in got
        indices = np.arange(N, dtype=np.int32)
        job = patch_job(N, SIDE, seq=3, prev_seq=2, crops=_crops(3), prev_indices=indices,
                        prev_crops=_crops(2), transient=True)  # fmt: skip
        expected = measure_crops(JOB_SETTINGS.yaw_settings, indices, _crops(3), _crops(2))
        assert np.array_equal(
            _shifts(_ask(endpoint, key, job, PatchResult)), expected.shift_px, equal_nan=True
        )
        assert workers[0].cache.held("s") == (-2, frozenset())  # nothing cached


def test_a_foreman_without_workers_measures_a_transient_block_itself() -> None:
    indices = np.arange(N, dtype=np.int32)
    with hub() as endpoint, _node(endpoint, workers=0) as (foreman, _):
        key = keys.foreman_key("h")
        first = patch_job(N, SIDE, cls=BlockJob, seq=1, prev_seq=0, crops=_crops(1), prev_indices=indices,
                          prev_crops=_crops(0))  # fmt: skip
        assert isinstance(_ask(endpoint, key, first, BlockResult), BlockResult)
        transient = patch_job(N, SIDE, cls=BlockJob, seq=1, prev_seq=0, crops=_crops(11), transient=True)
        got = _ask(endpoint, key, transient, BlockResult)
        expected = measure_crops(JOB_SETTINGS.yaw_settings, indices, _crops(11), _crops(0))
        assert np.array_equal(_shifts(got), expected.shift_px, equal_nan=True)
        assert isinstance(got, BlockResult) and got.members == {SELF: N}
        assert wait_until(lambda: foreman.counters.get("transient_blocks") == 1)  # counted after the reply


class _Failing:
    """A stand-in session whose members answer each part with ``answers`` in turn (an error reply, a reply
    for another frame, nothing at all)."""

    def __init__(self, answers: list[Any]) -> None:
        self.answers = answers

    def get(self, key: Any, handler: Any, **_kw: Any) -> FakeChannel:
        answer = self.answers.pop(0)
        return FakeChannel([] if answer is None else [answer])


def test_each_failed_part_comes_back_as_none_counted_and_the_others_measured() -> None:
    indices = np.arange(N, dtype=np.int32)
    jobs = [patch_job(N, SIDE, seq=3, prev_seq=2, crops=_crops(3), prev_indices=indices, prev_crops=_crops(2),
                      transient=True) for _ in range(4)]  # fmt: skip
    good = measure_crops(JOB_SETTINGS.yaw_settings, indices, _crops(3), _crops(2))
    result = PatchResult(
        stream="s", seq=3, prev_seq=2, member="w", indices=indices, shift_px=good.shift_px,
        confidence=good.confidence, peak=good.peak, valid=good.valid, compute_s=0.0,
    )  # fmt: skip
    other_frame = result.model_copy(update={"seq": 4})
    error = SimpleNamespace(err=SimpleNamespace(payload=FakeBytes(b"Timeout")), ok=None)

    def ok(message: PatchResult) -> SimpleNamespace:
        payload, attachment = encode(message)
        return SimpleNamespace(err=None, ok=SimpleNamespace(payload=FakeBytes(payload),
                                                            attachment=FakeBytes(attachment)))  # fmt: skip

    session: Any = _Failing([ok(result), error, ok(other_frame), None])
    parts = [TransientPart(f"w{i}", f"k{i}", job) for i, job in enumerate(jobs)]
    counters = Counters()
    got = gather(send_parts(session, parts, 1.0), PatchResult, counters)
    assert got[0] is not None and np.array_equal(got[0].shift_px, good.shift_px, equal_nan=True)
    assert got[1:] == [None, None, None]
    assert counters.get("refine_failures") == 3
