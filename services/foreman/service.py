"""The foreman: one per node; splits each block among its node's workers with the one Dispatcher.

It follows its workers' liveliness (``capataz/alive/worker/{node}/*``), keeps the crops of the last
block so that a share moved to another worker (or re-dispatched after a failure) can carry the
previous patches, and may compute a share itself (``--compute``). Blocks are served one at a time by
one thread that drains the queryable's bounded zenoh FIFO channel (decoding there: a malformed block gets
an error reply and is counted).
"""

from __future__ import annotations

import argparse
import copy
import threading
import time
from typing import Any

import numpy as np
import zenoh
from pydantic import Field

from common.dispatch import (
    SELF,
    Dispatcher,
    DispatchSettings,
    Plan,
    TrustMonitor,
    TrustSettings,
)
from common.errors import CapatazError
from common.members import Role
from common.streams import StreamTable
from common.wire import keys
from common.wire.messages import BlockJob, BlockResult, PatchJob, PatchResult
from common.yaw.measurement import PatchMeasurement, merge_measurements
from common.yaw.patchwork import CropStore, SpectrumCache, measure_crops, measure_share
from services.runtime.allocator import HeapTrim
from services.runtime.cli import (
    IDLE_PROCESS_MB,
    LARGEST_SHARE_MB,
    StreamBoundSettings,
    add_dispatch_arguments,
    add_stream_bound_arguments,
    add_transport_arguments,
    dispatch_from_args,
)
from services.runtime.fields import settings_from
from services.runtime.membership import LiveMembers
from services.runtime.results import result_from_measurement
from services.runtime.round import FrameWork
from services.runtime.scatter import Scatter
from services.runtime.service import ConfiguredService
from services.runtime.transient import TransientPart, gather, send_parts, transient_job

#: Upper bound of patch indices a foreman accepts.
MAX_PATCHES = 1 << 16


class _StreamState:
    """What a foreman keeps per stream: its own dispatcher (sticky shares, held history, suspensions), round,
    and the roster as applied to that dispatcher (the crops are in the foreman's one :class:`CropStore`)."""

    def __init__(
        self, session: zenoh.Session, dispatch: DispatchSettings, counters: Any, live: LiveMembers
    ) -> None:
        self.dispatcher = Dispatcher(dispatch, MAX_PATCHES)
        # no fit here to vet workers against (the master vets the foreman's whole block): share caps only
        self.dispatcher.trust = TrustMonitor(TrustSettings(earn_frames=0))
        self.scatter = Scatter(session, self.dispatcher, keys.work_key_of, PatchJob, PatchResult, counters)
        # a copy of the node's roster (the roster itself is immutable; events are fed to every copy): one
        # LiveMembers per dispatcher, so alternating streams never re-join (and un-suspend) members
        self.live = copy.copy(live)


class ForemanSettings(StreamBoundSettings):
    """A foreman's own settings (the runtime's come with the transport)."""

    #: how its dispatcher shares blocks among the node's workers
    dispatch: DispatchSettings = Field(default_factory=DispatchSettings)
    #: capacity of the blocks' zenoh FIFO channel
    queue: int = Field(default=2, ge=1)


#: what one largest block holds while it is served, beyond the idle process and the stores' bounds: its
#: payload as zenoh received it and as decoded, the share's job encoded for a worker, the crops just stored
#: (the one stream the crop store may hold beyond its bound) (VmHWM less the idle VmRSS of a foreman whose
#: stores keep nothing, serving blocks of 2**24 pixels: 128 MB;
#: tests/integration/test_member_memory_budget.py)
LARGEST_BLOCK_MB = 144.0


def memory_budget_mb(settings: ForemanSettings) -> float:
    """A foreman's whole-process memory budget in MB (2**20 bytes): its stores' bound (``--cache-mb``: half
    spectra, half previous crops), the idle process, one largest block being served and one largest share
    computed by itself (with ``--compute``, or when none of its workers is alive). A block waiting in its
    queue adds its payload (at most 32 MB); a master sends a foreman one block at a time."""
    return settings.cache_mb + IDLE_PROCESS_MB + LARGEST_BLOCK_MB + LARGEST_SHARE_MB


def store_bytes(settings: ForemanSettings) -> tuple[int, int]:
    """The bounds of a foreman's two stores in bytes, ``(spectra, previous crops)``: ``--cache-mb`` across all
    streams, half each."""
    budget = int(settings.cache_mb * 2**20)
    return budget // 2, budget - budget // 2


def relay_memory_mb(settings: ForemanSettings) -> float:
    """What a foreman that computes nothing itself holds at most, in MB: the crops' half of ``--cache-mb``,
    the idle process and one largest block (the spectra's half and the share's working set stay unused)."""
    return store_bytes(settings)[1] / 2**20 + IDLE_PROCESS_MB + LARGEST_BLOCK_MB


class ForemanService(ConfiguredService[ForemanSettings]):
    role = Role.FOREMAN

    def setup(self) -> None:
        # within its relay memory: past its crops and idle size, freed heap pages leave after a block
        self.heap = HeapTrim.for_service(relay_memory_mb(self.settings) - LARGEST_BLOCK_MB)
        self.dispatch_settings = self.settings.dispatch
        self.queue_capacity = self.settings.queue
        self._queryable: Any = None
        max_streams, ttl_s = self.settings.max_streams, self.settings.stream_ttl_s
        spectra_bytes, crop_bytes = store_bytes(self.settings)
        self.cache = SpectrumCache(max_streams=max_streams, max_age_s=ttl_s, max_bytes=spectra_bytes)
        self.crops = CropStore(max_bytes=crop_bytes)
        #: per-stream state, bounded by count and age (a stream's dispatcher knows what its workers hold)
        self.streams: StreamTable[_StreamState] = StreamTable(max_streams, ttl_s)
        self._streams_lock = threading.Lock()
        #: the node's workers, from liveliness (each stream's dispatcher is brought up to date from a copy)
        self.live = LiveMembers(Role.WORKER)
        self._last_shares: dict[str, float] = {}
        self._entities: list[Any] = []

    def start(self, session: zenoh.Session) -> None:
        self._entities.append(
            session.liveliness().declare_subscriber(
                keys.alive_node_workers(self.node), self._on_alive, history=True
            )
        )
        # blocks reach the block thread through zenoh's own bounded FIFO (no Python callback thread between)
        self._queryable = session.declare_queryable(
            keys.foreman_key(self.node), zenoh.handlers.FifoChannel(self.queue_capacity), complete=True
        )
        self.spawn(lambda: self.serve_queries(self._queryable, BlockJob, self._answer_block), "blocks")

    def stop(self) -> None:
        if self._queryable is not None:
            self._queryable.undeclare()  # the block thread's recv() then raises and it exits
            self._queryable = None

    def _on_alive(self, sample: zenoh.Sample) -> None:
        event = self.member_event(sample)
        if event is None:
            return
        member, joined = event
        with self._streams_lock:
            self.live.on_event(member, joined, self.counters)
            states = self.streams.values()
        for state in states:
            state.live.on_event(member, joined, None, state.scatter)

    def _stream(self, stream: str) -> _StreamState:
        assert self.session is not None
        session = self.session
        with self._streams_lock:
            before = self.streams.evicted
            state = self.streams.get(
                stream,
                time.monotonic(),
                lambda: _StreamState(session, self.dispatch_settings, self.counters, self.live),
            )
            evicted = self.streams.evicted - before
        if evicted:
            self.counters.inc("streams_evicted", evicted)
        return state

    def shares(self) -> dict[str, float]:
        return dict(self._last_shares)

    def _answer_block(self, query: zenoh.Query, job: BlockJob, received_perf_s: float) -> None:
        evicted_before = (self.cache.evicted, self.crops.evicted)  # this thread alone stores into both
        try:
            if job.transient:
                result, plan = self._transient_block(job), None
            else:
                result, plan = self._compute_block(job)
            t_rep = time.perf_counter()
        except (CapatazError, ValueError) as exc:  # a raw ValueError is a bug: counted apart, traceback
            self.count_failure("rejected", f"block {job.stream}/{job.seq} rejected", exc)
            self.reply_error(query, "rejected", f"{type(exc).__name__}: {exc}")
            self._count_evictions(*evicted_before)
            return
        self.reply(query, result)
        # bookkeeping after the reply is on its way: none of it is needed to answer this block
        if plan is not None:  # a transient block's crops are frame k turned back: not frame k's
            self.crops.add(job.stream, job.seq, job.indices, job.crops)
            self._last_shares = plan.shares()
        self.counters.inc("transient_blocks" if plan is None else "blocks")
        self.counters.inc("patches", int(job.indices.size))
        self._count_evictions(*evicted_before)
        self.counters.time_ms("block", result.compute_s * 1e3)
        self.counters.time_ms("reply", (time.perf_counter() - t_rep) * 1e3)
        self.counters.time_ms("handle", (time.perf_counter() - received_perf_s) * 1e3)
        if self.heap.after_job():
            self.counters.inc("heap_trims")

    def _count_evictions(self, spectra_before: int, crops_before: int) -> None:
        """Count the streams the two stores evicted since ``*_before`` (their ``evicted`` then)."""
        for counter, evicted in (("spectra_evicted", self.cache.evicted - spectra_before),
                                 ("crops_evicted", self.crops.evicted - crops_before)):  # fmt: skip
            if evicted:
                self.counters.inc(counter, evicted)

    def _compute_block(self, job: BlockJob) -> tuple[BlockResult, Plan]:
        """Split the block among the workers (and itself), gather; only what the reply needs."""
        t0 = time.perf_counter()
        settings = job.settings.yaw_settings  # valid: checked at decode, before any worker sees the block
        stream = self._stream(job.stream)
        dispatcher = stream.dispatcher
        if job.prev_indices.size:  # previous crops of patches this foreman did not hold (moved shares)
            self.crops.add(job.stream, job.prev_seq, job.prev_indices, job.prev_crops)
        crop_shape = tuple(job.crops.shape[1:])
        block_indices = job.indices
        rows: dict[int, int] = {}

        def crops(indices: np.ndarray) -> np.ndarray:
            if indices.size == block_indices.size and np.array_equal(indices, block_indices):
                return job.crops  # the whole block to one member: forward it as it came
            if not rows:
                rows.update((i, r) for r, i in enumerate(block_indices.tolist()))
            return job.crops[[rows[i] for i in indices.tolist()]] if indices.size else job.crops[:0]

        def prev_crops(indices: np.ndarray) -> np.ndarray:
            return self.crops.get(job.stream, job.prev_seq, indices, crop_shape)

        def compute_self(indices: np.ndarray, moved: np.ndarray) -> Any:
            return measure_share(
                self.cache,
                settings,
                job.stream,
                job.seq,
                job.prev_seq,
                indices,
                crops(indices),
                moved,
                prev_crops(moved),
            )

        stream.live.update(dispatcher)
        # workers get most of the budget; the rest is for re-dispatching a failed share here
        work = FrameWork(
            stream=job.stream,
            seq=job.seq,
            prev_seq=job.prev_seq,
            settings=job.settings,
            budget_s=max(0.05, 0.5 * job.budget_s),
            crops=crops,
            prev_crops=prev_crops,
            compute_self=compute_self,
        )
        plan = dispatcher.plan(job.seq, job.prev_seq, time.monotonic(), job.indices)
        t_plan = time.perf_counter()
        report = stream.scatter.run(work, plan)
        self.counters.time_ms("prepare", (t_plan - t0) * 1e3)
        self.counters.time_ms("round", (time.perf_counter() - t_plan) * 1e3)
        measurement = merge_measurements(report.parts, job.indices)
        elapsed = time.perf_counter() - t0
        active = set(dispatcher.active(time.monotonic()))
        speeds = {m: s for m, s in dispatcher.speeds().items() if m in active}
        result = result_from_measurement(
            BlockResult, job, self.name, measurement, elapsed, report.members, speeds
        )
        assert isinstance(result, BlockResult)
        return result, plan

    def _transient_block(self, job: BlockJob) -> BlockResult:
        """A turning pair's second pass (``job.transient``): the block spread over the node's active workers
        with the previous crops this foreman holds (a worker keeps no crops), each part a transient job; what
        no worker takes (none alive, or the foreman computes too) or a worker failed, measured here."""
        t0 = time.perf_counter()
        assert self.session is not None
        settings = job.settings.yaw_settings
        if job.prev_indices.size:
            prev_crops = job.prev_crops
        else:
            prev_crops = self.crops.get(job.stream, job.prev_seq, job.indices, tuple(job.crops.shape[1:]))
        stream = self._stream(job.stream)
        stream.live.update(stream.dispatcher)
        members = stream.dispatcher.active(time.monotonic())
        shares = [(m, r) for m, r in zip(members, np.array_split(np.arange(job.indices.size), len(members)),
                                         strict=True) if r.size]  # fmt: skip
        away = [(m, r) for m, r in shares if m != SELF]
        budget_s = max(0.05, 0.5 * job.budget_s)
        sent = send_parts(self.session, [
            TransientPart(m, keys.work_key_of(m), transient_job(
                PatchJob, job, job.indices[r], job.crops[r], prev_crops[r], budget_s))
            for m, r in away
        ], budget_s)  # fmt: skip
        counts: dict[str, int] = {}

        def here(r: np.ndarray) -> PatchMeasurement:
            counts[SELF] = counts.get(SELF, 0) + int(r.size)
            return measure_crops(settings, job.indices[r], job.crops[r], prev_crops[r])

        measured = [here(r) for m, r in shares if m == SELF]  # while the workers measure theirs
        for (member, r), got in zip(away, gather(sent, PatchResult, self.counters), strict=True):
            if got is not None:
                counts[member] = int(r.size)
            measured.append(here(r) if got is None else got)
        measurement = merge_measurements(measured, job.indices)
        result = result_from_measurement(
            BlockResult, job, self.name, measurement, time.perf_counter() - t0, counts, {}
        )
        assert isinstance(result, BlockResult)
        return result


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("foreman", help="a foreman: splits blocks among its node's workers")
    add_transport_arguments(parser)
    add_dispatch_arguments(
        parser, compute_help="compute a share itself besides its members (the paper's configuration)"
    )
    add_stream_bound_arguments(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    settings = settings_from(ForemanSettings, args, dispatch=dispatch_from_args(args))
    return ForemanService.from_args(args, settings).run()


__all__ = ["SELF", "ForemanService", "ForemanSettings", "register"]
