"""The worker's default (channel) hand-off without a network: jobs that wait behind others expire, and the
job queue shows the backlog. A stand-in channel and queries replace zenoh's."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from common.wire.codec import decode, encode, read_error_reply
from common.wire.messages import PatchJob
from common.wire.schema import MAX_BUDGET_S
from common.yaw.patchwork import PatchMeasurement
from services.runtime.transport import TransportSettings
from services.worker import service as worker_module
from services.worker.service import Handoff, WorkerService, WorkerSettings
from tests.builders import patch_job
from tests.services.fakes import FakeBytes, FakeChannel

#: how long the stand-in computation of a job takes (a lower bound, whatever the host's load)
COMPUTE_S = 0.05


class _Query:
    """A query as the worker sees it; records how it was answered."""

    key_expr = "capataz/test/worker"

    def __init__(self, seq: int, budget_s: float) -> None:
        payload, attachment = encode(patch_job(seq=seq, prev_seq=seq - 1, budget_s=budget_s))
        self.payload, self.attachment = FakeBytes(payload), FakeBytes(attachment)
        self.answer: str | None = None

    def reply(self, _key: Any, _payload: bytes, attachment: bytes | None = None) -> None:
        self.answer = "result"

    def reply_err(self, payload: bytes) -> None:
        self.answer = read_error_reply(payload)

    def drop(self) -> None:
        pass


@pytest.fixture()
def slow_worker(monkeypatch: pytest.MonkeyPatch) -> tuple[WorkerService, list[int]]:
    """A worker whose computation takes ``COMPUTE_S``; records its job-queue depth during each one."""
    worker = WorkerService("h", 0, TransportSettings(), WorkerSettings())
    depths: list[int] = []

    def measure_share(*args: Any) -> PatchMeasurement:
        depths.append(worker.queue_depths()["jobs"])
        time.sleep(COMPUTE_S)
        n = args[5].size
        return PatchMeasurement(args[5], np.zeros((n, 2)), np.ones(n), np.ones(n), np.ones(n, bool))

    monkeypatch.setattr(worker_module, "measure_share", measure_share)
    return worker, depths


def serve(worker: WorkerService, queries: list[_Query]) -> None:
    worker._queryable = type("Queryable", (), {"handler": FakeChannel(queries)})()
    worker._serve_channel()  # returns when the stand-in channel is closed


def test_worker_expiry_check_fires_in_the_default_channel_handoff(
    slow_worker: tuple[WorkerService, list[int]],
) -> None:
    """Regression: the channel hand-off passed ``time.monotonic()`` as the job's arrival, just before the
    check, so a job that waited behind another longer than its budget was still computed."""
    worker, _depths = slow_worker
    assert worker.handoff == "channel"  # the default
    first, late = _Query(1, budget_s=MAX_BUDGET_S), _Query(2, budget_s=COMPUTE_S / 5)
    serve(worker, [first, late])
    assert first.answer == "result"
    assert late.answer is not None and late.answer.startswith("expired:")  # waited >= COMPUTE_S behind first
    assert worker.counters.get("expired") == 1 and worker.counters.get("jobs") == 1


def test_worker_queue_depth_is_not_always_zero_in_the_channel_handoff(
    slow_worker: tuple[WorkerService, list[int]],
) -> None:
    """Regression: in the channel hand-off the job queue was never used, so its depth always read 0."""
    worker, depths = slow_worker
    queries = [_Query(seq, budget_s=MAX_BUDGET_S) for seq in range(1, 5)]
    serve(worker, queries)
    assert depths == [3, 2, 1, 0]  # the backlog behind each job as it is computed
    assert all(q.answer == "result" for q in queries) and worker.counters.get("queries") == 4


def test_a_full_job_queue_leaves_queries_in_the_channel_and_refuses_none(
    slow_worker: tuple[WorkerService, list[int]],
) -> None:
    worker, depths = slow_worker
    worker.queue_capacity = 2
    worker.queue = worker_module.WorkQueue(2)
    queries = [_Query(seq, budget_s=MAX_BUDGET_S) for seq in range(1, 6)]
    serve(worker, queries)
    assert depths == [2, 2, 2, 1, 0] and all(q.answer == "result" for q in queries)
    assert worker.counters.get("busy") == 0


def test_a_malformed_query_in_the_channel_is_answered_and_the_rest_computed(
    slow_worker: tuple[WorkerService, list[int]],
) -> None:
    worker, _depths = slow_worker
    bad = _Query(1, budget_s=MAX_BUDGET_S)
    bad.attachment = FakeBytes(b"\x93not-a-header")
    good = _Query(2, budget_s=MAX_BUDGET_S)
    serve(worker, [_Query(1, budget_s=MAX_BUDGET_S), bad, good])
    assert bad.answer is not None and bad.answer.startswith("malformed:")
    assert good.answer == "result" and worker.counters.get("malformed") == 1
    assert decode(good.payload.to_bytes(), good.attachment.to_bytes(), PatchJob).seq == 2


def test_the_handoff_is_an_enum_and_a_bad_one_is_one_clear_error() -> None:
    worker = WorkerService("h", 0, TransportSettings(), WorkerSettings(handoff="callback"))  # type: ignore[arg-type]
    assert worker.handoff is Handoff.CALLBACK
    with pytest.raises(ValidationError, match="handoff"):
        WorkerSettings(handoff="pigeon")  # type: ignore[arg-type]
