"""The foreman's crop store (previous-frame crops stay available for a second block of the same frame), the
speed measure its time balancing uses, and its own check of a block's settings."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest
import zenoh

from common.dispatch import Dispatcher, DispatchSettings, SpeedSource
from common.wire import keys
from common.wire.codec import decode, encode, read_error_reply
from common.wire.messages import BlockJob, PatchJob, PatchResult
from common.yaw.patchwork import CropStore, PatchWorkError
from services.foreman.service import ForemanService, ForemanSettings
from services.runtime.counters import Counters
from services.runtime.round import FrameWork
from services.runtime.scatter import Scatter
from services.runtime.transport import open_session, zbytes
from services.worker.service import WorkerService, WorkerSettings
from tests.builders import JOB_SETTINGS, patch_job
from tests.services.fakes import FakeBytes, FakeChannel
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until


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


class _Reply:
    def __init__(self, payload: bytes, attachment: bytes) -> None:
        self.err = None
        self.ok = type("Sample", (), {"payload": FakeBytes(payload), "attachment": FakeBytes(attachment)})()


class _Workers:
    """A stand-in session: each get is answered at once by a worker that reports ``reported`` patches/s."""

    def __init__(self, reported: float, delay_s: float) -> None:
        self.reported = reported
        self.delay_s = delay_s

    def get(self, key_expr: Any, handler: Any, payload: bytes, attachment: bytes, **_kw: Any) -> Any:
        key = str(key_expr)  # a zenoh.KeyExpr, as the scatter sends
        job = decode(payload, attachment, PatchJob)
        time.sleep(self.delay_s)
        n = job.indices.size
        result = PatchResult(
            stream=job.stream, seq=job.seq, prev_seq=job.prev_seq, member=key, indices=job.indices,
            shift_px=np.zeros((n, 2)), confidence=np.ones(n), peak=np.ones(n), valid=np.ones(n, bool),
            compute_s=0.001, members={key: int(n)}, speeds={key: self.reported},
        )  # fmt: skip
        reply = _Reply(*encode(result))
        if isinstance(handler, zenoh.handlers.FifoChannel):  # a solo request blocks on its own channel
            return FakeChannel([reply])
        handler.callback(reply)
        return None


@pytest.mark.parametrize("source", list(SpeedSource))
def test_time_balancing_uses_the_chosen_speed_measure(source: SpeedSource) -> None:
    dispatcher = Dispatcher(DispatchSettings(speed_source=source, ema_alpha=1.0), 8)
    dispatcher.join("worker/a/0")
    scatter = Scatter(
        _Workers(reported=1e6, delay_s=0.02), dispatcher, str, PatchJob, PatchResult, Counters()
    )  # type: ignore[arg-type]
    work = FrameWork(
        stream="s", seq=1, prev_seq=0, settings=JOB_SETTINGS, budget_s=1.0,
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


@pytest.mark.zenoh
def test_a_block_with_invalid_settings_is_rejected_before_any_worker_sees_it() -> None:
    """A block whose yaw settings do not parse is answered with an error by the foreman itself: its worker
    gets no query, so it is not blamed (suspended) for the master's mistake."""
    with hub() as endpoint:
        _reject_a_block_with_invalid_settings(endpoint)


def _reject_a_block_with_invalid_settings(endpoint: str) -> None:
    foreman = ForemanService("h", 0, peer(endpoint), ForemanSettings())
    worker = WorkerService("h", 0, peer(endpoint), WorkerSettings())
    threads = [threading.Thread(target=s.run, daemon=True) for s in (foreman, worker)]
    for thread in threads:
        thread.start()
    try:
        assert foreman.started.wait(WAIT_S) and worker.started.wait(WAIT_S)
        assert wait_until(lambda: foreman.counters.get("members_joined") >= 1)
        assert foreman.counters.get("members_joined") == 1
        settings = {**JOB_SETTINGS.model_dump(mode="json"), "colour": 1}
        block = patch_job(
            4, 32, cls=BlockJob, validate=False, settings=settings,
            prev_indices=np.arange(4, dtype=np.int32), prev_crops=np.zeros((4, 32, 32), np.uint8),
        )  # fmt: skip
        payload, attachment = encode(block)
        with open_session(peer(endpoint)) as session:
            querier = session.declare_querier(keys.foreman_key("h"), timeout=WAIT_S)
            assert matched(querier)  # routing knows the foreman's queryable: the get is not lost
            reply = querier.get(payload=payload, attachment=attachment).recv()
            querier.undeclare()
        assert reply.err is not None
        assert "malformed: BlockJob: settings.colour" in read_error_reply(zbytes(reply.err.payload))
        assert foreman.counters.get("malformed") == 1
        assert worker.counters.get("queries") == 0  # never asked
        assert foreman.counters.get("redispatched") == 0
    finally:
        for service in (foreman, worker):
            service.request_stop()
        for thread in threads:
            thread.join(5.0)
