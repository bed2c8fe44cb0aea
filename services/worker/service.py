"""The worker: measures the patches it is sent, keeping each patch's previous spectrum (sticky cache)."""

from __future__ import annotations

import argparse
import time
from enum import StrEnum
from typing import Any

import zenoh
from pydantic import Field

from common.errors import CapatazError
from common.members import Role
from common.wire import keys
from common.wire.messages import PatchJob, PatchResult
from common.yaw.patchwork import PatchWorkError, SpectrumCache, measure_crops, measure_share
from services.runtime.allocator import HeapTrim
from services.runtime.cli import (
    IDLE_PROCESS_MB,
    LARGEST_SHARE_MB,
    StreamBoundSettings,
    add_stream_bound_arguments,
    add_transport_arguments,
)
from services.runtime.fields import settings_from
from services.runtime.handoff import WorkQueue
from services.runtime.options import add_options
from services.runtime.results import result_from_measurement
from services.runtime.service import ConfiguredService


def memory_budget_mb(settings: StreamBoundSettings) -> float:
    """A worker's whole-process memory budget in MB (2**20 bytes): its cache's bound (``--cache-mb``), the
    idle process and one largest job being computed. Each further job waiting in its queue adds its payload
    (at most 32 MB as received and decoded); a foreman or master sends a worker one job at a time."""
    return settings.cache_mb + IDLE_PROCESS_MB + LARGEST_SHARE_MB


def heap_mark_mb(settings: StreamBoundSettings) -> float:
    """Past this resident memory a worker hands its freed heap pages back after a job
    (:class:`~services.runtime.allocator.HeapTrim`): its budget less one largest share's working set."""
    return memory_budget_mb(settings) - LARGEST_SHARE_MB


class Handoff(StrEnum):
    """How a query reaches the compute thread."""

    #: zenoh's bounded FIFO channel, drained by the compute thread (no Python callback thread between)
    CHANNEL = "channel"
    #: a Python callback decodes and hands off to a bounded queue (full -> "busy" error reply)
    CALLBACK = "callback"


class WorkerSettings(StreamBoundSettings):
    """A worker's own settings (the runtime's come with the transport)."""

    #: capacity of the bounded hand-off (zenoh FIFO channel or job queue)
    queue: int = Field(default=8, ge=1, description="bounded job queue capacity")
    #: emulated slower CPU: every computation is done this many times (results of the extra ones unused)
    cpu_factor: int = Field(
        default=1,
        ge=1,
        description="emulate a CPU this many times slower (repeat every computation); for benchmarks",
    )
    handoff: Handoff = Field(
        default=Handoff.CHANNEL,
        description="queries reach the compute thread through a zenoh FIFO channel, or a callback + bounded "
        "queue",
    )


class WorkerService(ConfiguredService[WorkerSettings]):
    """One worker process: a queryable, a bounded job queue, one compute thread."""

    role = Role.WORKER

    def setup(self) -> None:
        # within its memory budget: past its cache and idle size, freed heap pages leave after a job
        self.heap = HeapTrim.for_service(heap_mark_mb(self.settings))
        self.handoff = self.settings.handoff
        self.queue_capacity = self.settings.queue
        self.cpu_factor = self.settings.cpu_factor
        self.queue: WorkQueue[tuple[zenoh.Query, PatchJob, float]] = WorkQueue(self.queue_capacity)
        self.cache = SpectrumCache(
            max_streams=self.settings.max_streams,
            max_age_s=self.settings.stream_ttl_s,
            max_bytes=int(self.settings.cache_mb * 2**20),
        )
        self._queryable: Any = None

    def start(self, session: zenoh.Session) -> None:
        key = keys.worker_key(self.node, self.index)
        if self.handoff is Handoff.CHANNEL:
            # zenoh's own bounded FIFO, drained by the compute thread: no Python callback thread in between
            self._queryable = session.declare_queryable(
                key, zenoh.handlers.FifoChannel(self.queue_capacity), complete=True
            )
            self.spawn(self._serve_channel, "compute")
        else:
            self._queryable = session.declare_queryable(key, self._on_query, complete=True)
            self.spawn(self._serve, "compute")

    def stop(self) -> None:
        if self.handoff is Handoff.CHANNEL and self._queryable is not None:
            self._queryable.undeclare()  # the compute thread's recv() then raises and it exits
            self._queryable = None
        for query, _job, _received_monotonic_s in self.queue.drain():
            self.reply_error(query, "shutdown", f"{self.name} is shutting down")

    def _serve_channel(self) -> None:
        """The compute thread of the channel hand-off: jobs in arrival order, each checked for expiry.

        A job is stamped when this thread first sees it. Blocking in ``recv`` (idle) that is its arrival;
        before each job the thread also moves the queries already waiting in zenoh's channel into
        :attr:`queue` (stamped then), so a job that waits behind others is seen to wait, and the queue depth
        is the real backlog. The stamp is an upper bound of the arrival, so expiry never fires early.
        Regression: the job used to be stamped just before its expiry check, which then never fired, and
        the job queue always read 0 in this mode.
        """
        channel = self._queryable.handler
        while not self.stop_event.is_set():
            item = self.queue.take(0.0)
            if item is None:
                try:
                    query = channel.recv()
                except zenoh.ZError:
                    return  # queryable undeclared: shutting down
                item = self._admit(query)
                if item is None:
                    continue
            self._pull_waiting(channel)
            self._handle(*item)
            self.counters.time_ms("handle", (time.monotonic() - item[2]) * 1e3)

    def _admit(self, query: zenoh.Query) -> tuple[zenoh.Query, PatchJob, float] | None:
        """Count and decode a query (a bad one gets an error reply); the job with its seen time, or None."""
        seen_monotonic_s = time.monotonic()
        self.counters.inc("queries")
        job = self.decode_query(query, PatchJob)
        self.counters.time_ms("decode", (time.monotonic() - seen_monotonic_s) * 1e3)
        return None if job is None else (query, job, seen_monotonic_s)

    def _pull_waiting(self, channel: Any) -> None:
        """Move queries waiting in zenoh's channel into :attr:`queue` while it has room (the rest stays in
        the channel, which then holds the session back as before: no job is refused here)."""
        while self.queue.depth() < self.queue_capacity:
            try:
                query = channel.try_recv()
            except zenoh.ZError:
                return
            if query is None:
                return
            item = self._admit(query)
            if item is not None:
                self.queue.offer(item)

    def queue_depths(self) -> dict[str, int]:
        return {"jobs": self.queue.depth()}

    def _on_query(self, query: zenoh.Query) -> None:
        # decode here (cheap, counts malformed input at once), compute in the worker thread
        self.counters.inc("queries")
        job = self.decode_query(query, PatchJob)
        if job is None:
            return
        if not self.queue.offer((query, job, time.monotonic())):
            self.counters.inc("busy")
            self.reply_error(query, "busy", f"{self.name}: job queue full")

    def _serve(self) -> None:
        while not self.stop_event.is_set():
            item = self.queue.take(0.1)
            if item is not None:
                self._handle(*item)

    def _handle(self, query: zenoh.Query, job: PatchJob, received_monotonic_s: float) -> None:
        if time.monotonic() - received_monotonic_s > job.budget_s:
            self.counters.inc("expired")
            self.reply_error(query, "expired", f"{self.name}: job waited longer than its budget")
            return
        t0 = time.perf_counter()
        evicted_before = self.cache.evicted  # this thread alone stores into the cache
        try:
            settings = job.settings.yaw_settings
            for _ in range(self.cpu_factor - 1):
                measure_share(
                    SpectrumCache(), settings, job.stream, job.seq, job.seq,
                    job.indices, job.crops, job.indices, job.crops,
                )  # fmt: skip
            if job.transient:  # a turning pair's second pass: its previous crops came with it, nothing kept
                if job.prev_indices.size != job.indices.size:
                    raise PatchWorkError("a transient job brings the previous crops of all its patches")
                measurement = measure_crops(settings, job.indices, job.crops, job.prev_crops)
            else:
                measurement = measure_share(
                    self.cache,
                    settings,
                    job.stream,
                    job.seq,
                    job.prev_seq,
                    job.indices,
                    job.crops,
                    job.prev_indices,
                    job.prev_crops,
                )
        except (PatchWorkError, CapatazError, ValueError) as exc:
            self.count_error("rejected", f"job {job.stream}/{job.seq} rejected", exc)
            self.reply_error(query, "rejected", f"{type(exc).__name__}: {exc}")
            return
        elapsed = time.perf_counter() - t0
        n = int(job.indices.size)
        speed = n / elapsed if elapsed > 0 else 0.0
        self.reply(
            query,
            result_from_measurement(
                PatchResult, job, self.name, measurement, elapsed, {self.name: n}, {self.name: speed}
            ),
        )
        self.counters.inc("jobs")  # after the reply: not on the requester's path
        self.counters.inc("patches", n)
        if self.cache.evicted > evicted_before:
            self.counters.inc("spectra_evicted", self.cache.evicted - evicted_before)
        self.counters.time_ms("compute", elapsed * 1e3)
        if self.heap.after_job():
            self.counters.inc("heap_trims")


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("worker", help="a worker: measures patch shifts for a master or foreman")
    add_transport_arguments(parser)
    add_options(parser, WorkerSettings, ("queue", "cpu_factor", "handoff"))
    add_stream_bound_arguments(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    return WorkerService.from_args(args, settings_from(WorkerSettings, args)).run()
