"""The scatter's solo path over real zenoh sessions: one member in flight, blocking on its own reply channel.

Every way a solo request can end is covered: a reply, a member that never answers (zenoh's timeout is the
deadline), a member that leaves while the round waits (its query is cancelled), and nobody listening. In each
failure the share is re-dispatched within the round and every patch is still measured.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import zenoh

from common.dispatch import SELF, Dispatcher, DispatchSettings, MemberOutcome, TrustMonitor
from common.wire.codec import decode, encode
from common.wire.jobs import band_decode_pixels
from common.wire.messages import PatchJob, PatchResult
from common.wire.schema import MAX_FRAME_SIDE_PX, MAX_JOB_PIXELS
from common.yaw.patchwork import PatchMeasurement
from services.runtime.counters import Counters
from services.runtime.round import FailureReason, FrameWork, JobBand, Request, Round, RoundReport
from services.runtime.scatter import Scatter
from services.runtime.transport import TransportSettings, listening_endpoints, open_session, zbytes
from tests.builders import JOB_SETTINGS
from tests.zenoh_helpers import matched, wait_until

pytestmark = pytest.mark.zenoh

N_PATCHES = 6
KEY = "capataz/test/scatter/{member}"


@pytest.fixture()
def sessions() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    with open_session(TransportSettings(listen=("tcp/127.0.0.1:0",), admin_space=True)) as member_side:
        endpoint = next(e for e in listening_endpoints(member_side) if e.startswith("tcp/127.0.0.1:"))
        connect = TransportSettings(listen=("tcp/127.0.0.1:0",), connect=(endpoint,))
        with open_session(connect) as dispatcher_side:
            assert wait_until(lambda: member_side.info.zid() in list(dispatcher_side.info.peers_zid()))
            yield member_side, dispatcher_side


def routed(session: zenoh.Session, member: str) -> bool:
    """The dispatcher's session knows the route to ``member``'s queryable (zenoh's routing status)."""
    querier = session.declare_querier(KEY.format(member=member))
    try:
        return matched(querier)
    finally:
        querier.undeclare()


def answer(query: zenoh.Query) -> None:
    """A worker that measures nothing: zero shifts for the requested patches."""
    job = decode(zbytes(query.payload), zbytes(query.attachment), PatchJob)
    n = int(job.indices.size)
    result = PatchResult(
        stream=job.stream, seq=job.seq, prev_seq=job.prev_seq, member="worker", indices=job.indices,
        shift_px=np.zeros((n, 2)), confidence=np.ones(n), peak=np.ones(n), valid=np.ones(n, bool),
        compute_s=0.001, members={"worker": n}, speeds={"worker": 1000.0},
    )  # fmt: skip
    payload, attachment = encode(result)
    query.reply(query.key_expr, payload, attachment=attachment)
    query.drop()


def run_round(
    session: zenoh.Session, member: str, budget_s: float = 0.4, own_s: float = 0.0, band: Any = None
) -> tuple[Scatter, RoundReport]:
    """One round for ``member``; with ``own_s`` the dispatcher also computes a share, taking that long;
    ``band``: the frame's band source (:attr:`FrameWork.band`)."""
    dispatcher = Dispatcher(DispatchSettings(self_compute=own_s > 0), N_PATCHES)
    dispatcher.join(member)
    scatter = Scatter(
        session,
        dispatcher,
        lambda m: KEY.format(member=m.replace("/", "_")),
        PatchJob,
        PatchResult,
        Counters(),
    )

    def compute_self(indices: np.ndarray, moved: np.ndarray) -> PatchMeasurement:
        n = indices.size
        time.sleep(own_s)  # the dispatcher's own compute time (the behaviour under test, not a wait)
        return PatchMeasurement(indices, np.full((n, 2), 7.0), np.ones(n), np.ones(n), np.ones(n, bool))

    work = FrameWork(
        stream="s", seq=1, prev_seq=0, settings=JOB_SETTINGS, budget_s=budget_s,
        crops=lambda idx: np.zeros((idx.size, 4, 4), np.uint8),
        prev_crops=lambda idx: np.zeros((idx.size, 4, 4), np.uint8),
        compute_self=compute_self, band=band,
    )  # fmt: skip
    return scatter, scatter.run(work, dispatcher.plan(1, 0, time.monotonic()))


def covered_by(report: RoundReport) -> dict[str, Any]:
    indices = np.sort(np.concatenate([p.indices for p in report.parts]))
    assert indices.tolist() == list(range(N_PATCHES)), "every patch measured exactly once"
    return report.members


def test_a_solo_reply_completes_the_round(sessions: tuple[zenoh.Session, zenoh.Session]) -> None:
    member_side, dispatcher_side = sessions
    queryable = member_side.declare_queryable(KEY.format(member="w_0"), answer, complete=True)
    assert routed(dispatcher_side, "w_0")
    scatter, report = run_round(dispatcher_side, "w/0")
    assert covered_by(report) == {"w/0": N_PATCHES, "w/0>worker": N_PATCHES}
    assert np.all(report.parts[0].shift_px == 0.0)  # the member's answer, not the dispatcher's own
    assert report.redispatched == 0 and scatter.counters.counts()["requests_sent"] == 1
    assert "wake" not in scatter.counters.median_timings_ms()  # no callback hand-off: its own reply channel
    queryable.undeclare()


def test_a_band_the_member_would_refuse_for_what_decoding_holds_goes_as_crops(
    sessions: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """A band whose decoding would hold more than a job's pixel bound is refused by every member: the
    dispatcher sends that share's crops instead (the member measures it; no failure, no re-dispatch)."""
    member_side, dispatcher_side = sessions
    seen: list[PatchJob] = []

    def answer_and_keep(query: zenoh.Query) -> None:
        seen.append(decode(zbytes(query.payload), zbytes(query.attachment), PatchJob))
        answer(query)

    queryable = member_side.declare_queryable(KEY.format(member="w_0"), answer_and_keep, complete=True)
    assert routed(dispatcher_side, "w_0")
    side = MAX_FRAME_SIDE_PX // 2  # a band of 4096 x 4096: twice its pixels alone exceed the bound
    huge = JobBand(np.zeros(64, np.uint8), (side, side), "zstd", np.zeros((N_PATCHES, 2), np.int64))
    assert band_decode_pixels(64, huge.shape, 0) > MAX_JOB_PIXELS
    scatter, report = run_round(dispatcher_side, "w/0", band=lambda indices: huge)
    assert covered_by(report)["w/0"] == N_PATCHES and report.redispatched == 0
    assert len(seen) == 1 and seen[0].crops.shape == (N_PATCHES, 4, 4)
    assert "bands_sent" not in scatter.counters.counts()
    queryable.undeclare()


def test_a_members_round_trip_ends_at_its_replys_arrival_not_after_the_dispatchers_own_share_regression(
    sessions: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """Seen on emulated hosts (issue 29): a master computing 167 of 192 patches took 73 ms, and the member's
    reply, there after 45 ms, was read after that share: its round trip counted 73 ms, so the balancer gave
    it 25 patches where its speed was worth more."""
    member_side, dispatcher_side = sessions
    queryable = member_side.declare_queryable(KEY.format(member="w_0"), answer, complete=True)
    assert routed(dispatcher_side, "w_0")
    scatter, report = run_round(dispatcher_side, "w/0", budget_s=5.0, own_s=0.6)
    members = covered_by(report)
    assert members[SELF] > 0 and members["w/0"] > 0  # both computed: the reply waited for the own share
    speed = scatter.dispatcher.speed("w/0")
    assert speed is not None
    # the member answered at once (milliseconds): its round trip is far shorter than the 0.6 s own share
    assert members["w/0"] / speed < 0.3, (members, speed)
    queryable.undeclare()


def test_a_frozen_solo_member_misses_its_deadline_and_self_takes_the_share(
    sessions: tuple[zenoh.Session, zenoh.Session],
) -> None:
    member_side, dispatcher_side = sessions
    held: list[zenoh.Query] = []  # a member that takes the query and never answers (a frozen process)
    queryable = member_side.declare_queryable(KEY.format(member="w_0"), held.append, complete=True)
    assert routed(dispatcher_side, "w_0")
    scatter, report = run_round(dispatcher_side, "w/0")  # deadline: the whole budget (speed unknown)
    assert covered_by(report) == {SELF: N_PATCHES}
    assert report.failures == ["w/0: deadline missed"]  # zenoh's timeout reply, read as the deadline
    assert scatter.counters.counts()["deadline_misses"] == 1
    queryable.undeclare()


def test_a_solo_member_that_leaves_is_cancelled_at_once(
    sessions: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """The member's liveliness is lost while its request is in flight: the round is told at once.

    Regression (failed once on a loaded host): the leave came from a thread polling for the request to be
    sent, which could lose the race against zenoh; it now comes from the member's side when the request
    has arrived there, so "in flight" holds by construction."""
    member_side, dispatcher_side = sessions
    held: list[zenoh.Query] = []
    scatters: list[Scatter] = []

    def on_query(query: zenoh.Query) -> None:
        held.append(query)  # never answered
        if scatters:
            scatters[-1].member_left("w/0")  # liveliness lost mid-round (not before: that is in the plan)

    queryable = member_side.declare_queryable(KEY.format(member="w_0"), on_query, complete=True)
    assert routed(dispatcher_side, "w_0")
    original = Scatter.run

    def run_and_leave(self: Scatter, work: FrameWork, plan: Any) -> RoundReport:
        scatters.append(self)
        return original(self, work, plan)

    Scatter.run = run_and_leave  # type: ignore[method-assign]
    try:
        _scatter, report = run_round(dispatcher_side, "w/0", budget_s=5.0)
    finally:
        Scatter.run = original  # type: ignore[method-assign]
    assert held, "the request never reached the member"
    assert covered_by(report) == {SELF: N_PATCHES}
    # cancelled, not timed out: without the cancellation this would read "deadline missed" after 5 s
    assert report.failures == ["w/0: left (liveliness lost)"]
    queryable.undeclare()


class _LaggingToken:
    """A cancellation token whose state reads "not cancelled" until after its channel is closed."""

    def __init__(self, channel: _ClosedOnCancel) -> None:
        self.channel = channel
        self.is_cancelled = False

    def cancel(self) -> None:
        self.channel.closed = True  # zenoh closes the reply channel first ...
        self.channel.woken.append(self.is_cancelled)  # ... the round thread wakes and reads the state here
        self.is_cancelled = True


class _ClosedOnCancel:
    def __init__(self) -> None:
        self.closed = False
        self.woken: list[bool] = []

    def recv(self) -> zenoh.Reply:
        assert self.closed, "recv before the cancellation"
        raise zenoh.ZError("channel closed")


def test_solo_leave_reads_left_even_when_the_token_lags_the_closed_channel() -> None:
    """Regression (CI, loaded host): the leave was read from the token's ``is_cancelled``, which zenoh may set
    after the closed channel has woken the round thread; the round then reported "no reply"."""
    scatter = Scatter(None, Dispatcher(DispatchSettings(), N_PATCHES), str, PatchJob, PatchResult, Counters())  # type: ignore[arg-type]
    channel = _ClosedOnCancel()
    request = Request("w/0", np.arange(3), 0.0, 1.0)
    request.replies = channel
    request.cancel = _LaggingToken(channel)  # type: ignore[assignment]
    scatter._solo = request
    scatter.member_left("w/0")
    assert channel.woken == [False]  # the token did lag: the old code read "no reply" here
    work: Any = None  # not reached: the channel is closed
    failure = scatter._await_solo(request, work)
    assert failure is not None and failure.reason is FailureReason.LEFT
    assert scatter._solo is None


def test_a_leave_of_another_member_does_not_cancel_the_solo_request() -> None:
    scatter = Scatter(None, Dispatcher(DispatchSettings(), N_PATCHES), str, PatchJob, PatchResult, Counters())  # type: ignore[arg-type]
    channel = _ClosedOnCancel()
    request = Request("w/0", np.arange(3), 0.0, 1.0)
    request.cancel = _LaggingToken(channel)  # type: ignore[assignment]
    scatter._solo = request
    scatter.member_left("w/1")
    assert not channel.closed and not request.left


def test_a_solo_request_nobody_answers_fails_without_waiting(
    sessions: tuple[zenoh.Session, zenoh.Session],
) -> None:
    _member_side, dispatcher_side = sessions
    _scatter, report = run_round(dispatcher_side, "w/9", budget_s=5.0)  # no queryable on its key
    assert covered_by(report) == {SELF: N_PATCHES}
    assert report.failures == ["w/9: no reply"]  # not "deadline missed": zenoh closed the channel at once


def test_a_dispatch_only_master_counts_the_patches_a_trust_cap_left_it() -> None:
    """Two credited members, one four times faster and held at half the frame by the trust cap: the master
    computes what the slow one would have finished last with, and says so in ``cap_overflow_patches``."""
    dispatcher = Dispatcher(DispatchSettings(), 40)
    dispatcher.trust = TrustMonitor()
    for k in range(dispatcher.trust.settings.earn_frames):
        dispatcher.trust.observe([MemberOutcome(m, 13, 0) for m in ("f/fast", "f/slow")], now_s=float(k))
    for member, seconds, first in (("f/fast", 0.25, 0), ("f/slow", 1.0, 20)):
        dispatcher.join(member)
        dispatcher.record_success(member, 0, np.arange(first, first + 20), seconds)
    plan = dispatcher.plan(1, 0, time.monotonic())
    sent: list[str] = []
    scatter = SimpleNamespace(
        dispatcher=dispatcher,
        counters=Counters(),
        _send=lambda work, member, *rest: sent.append(member) or len(sent),
    )
    work = FrameWork(
        stream="s", seq=1, prev_seq=0, settings=JOB_SETTINGS, budget_s=1.0, crops=np.asarray,
        prev_crops=np.asarray, compute_self=lambda i, m: PatchMeasurement(i, i, i, i, i),
    )  # fmt: skip
    round_ = Round(scatter, work)  # type: ignore[arg-type]
    round_.dispatch(plan, round_.start_monotonic_s)
    own = plan.assignment[SELF].size
    assert sorted(sent) == ["f/fast", "f/slow"] and own > 0
    assert scatter.counters.counts()["cap_overflow_patches"] == own
    round_.dispatch(dispatcher.redistribute(plan.assignment["f/slow"], {"f/slow"}, time.monotonic(), 0))
    assert scatter.counters.counts()["cap_overflow_patches"] == own  # a re-dispatch is counted apart
