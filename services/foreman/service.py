"""The foreman: one per node; splits each block among its node's workers with the one Dispatcher.

It follows its workers' liveliness (``capataz/alive/worker/{node}/*``), keeps the crops of the last
block so that a share moved to another worker (or re-dispatched after a failure) can carry the
previous patches, and may compute a share itself (``--compute``). Blocks are served one at a time by
one thread that drains the queryable's bounded zenoh FIFO channel (decoding there: a malformed block gets
an error reply and is counted).
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from typing import Any

import numpy as np
import zenoh

from common import keys
from common.dispatch import SELF, Balance, Dispatcher, DispatchSettings, SpeedSource
from common.dispatch.patchwork import PatchWorkError, SpectrumCache, measure_share, merge_measurements
from common.errors import CapatazError
from common.messages import (
    BlockJob,
    BlockResult,
    PatchJob,
    PatchResult,
    RawMessage,
    WireError,
    encode,
    read_raw,
    reheader,
)
from common.transport import (
    ServiceRuntime,
    TransportSettings,
    add_transport_arguments,
    transport_from_args,
    zbytes,
)
from services.master.scatter import FrameWork, Scatter, result_from_measurement
from services.worker.service import WorkerService

#: Upper bound of patch indices a foreman accepts.
MAX_PATCHES = 1 << 16


class CropStore:
    """Crops of the two newest frames of each stream, by patch index.

    A share moved to another worker, or re-dispatched after a failure, needs the previous frame's crops;
    two frames are kept because a second block of frame k (re-dispatched by the master) still refers to
    frame k-1 after the first block of frame k was stored.
    """

    def __init__(self, frames: int = 2) -> None:
        self._frames: dict[str, dict[int, dict[int, np.ndarray]]] = {}
        self._keep = frames

    def add(self, stream: str, seq: int, indices: np.ndarray, crops: np.ndarray) -> None:
        frames = self._frames.setdefault(stream, {})
        if frames and seq < min(frames) and len(frames) >= self._keep:
            return  # older than everything kept
        entry = frames.setdefault(seq, {})
        entry.update(zip(indices.tolist(), crops, strict=True))
        for old in sorted(frames)[: -self._keep]:
            del frames[old]

    def get(self, stream: str, seq: int, indices: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        if indices.size == 0:
            return np.zeros((0, *shape), dtype=np.uint8)
        entry = self._frames.get(stream, {}).get(seq)
        if entry is None:
            raise PatchWorkError(f"no crops of frame {seq} of {stream}")
        try:
            return np.stack([entry[int(i)] for i in indices])
        except KeyError as exc:
            raise PatchWorkError(f"no crop of patch {exc} in frame {seq} of {stream}") from None


def forwardable_result(raw: RawMessage, stream: str, seq: int, indices: np.ndarray) -> PatchResult:
    """A worker's whole-block reply, checked at the header level only, as a :class:`PatchResult`.

    The arrays stay unvalidated views of the worker's payload, which the foreman forwards unchanged to
    the master (who decodes and validates it fully); here only what the foreman itself relies on is
    checked: the frame, the indices (equal to the job's, so no merge is needed), a row per index in every
    array, and the types of the fields the scatter reads. Raises :class:`WireError`.
    """
    fields = raw.fields
    n = int(indices.size)
    if fields.get("stream") != stream or fields.get("seq") != seq:
        raise WireError(f"reply for frame {fields.get('seq')!r}/{fields.get('stream')!r} does not match")
    for key, array in raw.arrays.items():
        if array.shape[0] != n:
            raise WireError(f"{raw.type_name}.{key}: {array.shape[0]} rows for {n} indices")
    if not np.array_equal(raw.arrays["indices"], indices):
        raise WireError(f"{raw.type_name}.indices: not the indices of the request")
    members = fields.get("members", {})
    speeds = fields.get("speeds", {})
    if not (
        isinstance(members, dict)
        and all(isinstance(k, str) and type(v) is int and v >= 0 for k, v in members.items())
    ):
        raise WireError(f"{raw.type_name}.members: must map member names to patch counts")
    if not (
        isinstance(speeds, dict)
        and all(
            isinstance(k, str) and type(v) in (int, float) and math.isfinite(v) for k, v in speeds.items()
        )
    ):
        raise WireError(f"{raw.type_name}.speeds: must map member names to finite speeds")
    values = {k: v for k, v in fields.items() if k in PatchResult.model_fields}
    values.update(raw.arrays, members=members, speeds=speeds)
    return PatchResult.model_construct(**values)


class ForwardingScatter(Scatter):
    """The foreman's scatter: a worker's reply to the WHOLE block is kept raw, to be forwarded unchanged.

    Set :attr:`block_indices` before each round; after it, :attr:`forward` holds the raw reply when one
    worker measured the whole block (checked at the header level by :func:`forwardable_result`), else
    None. Replies to parts of a block are decoded and validated as usual (they get merged here).
    """

    block_indices: np.ndarray | None = None
    forward: RawMessage | None = None

    def run(self, work: FrameWork, plan: Any) -> Any:
        self.forward = None
        return super().run(work, plan)

    def _accept(self, request: Any, reply: zenoh.Reply, work: FrameWork) -> None:
        block = self.block_indices
        sample = reply.ok if reply.err is None else None
        if (
            sample is None
            or block is None
            or request.indices.size != block.size
            or not np.array_equal(request.indices, block)
        ):
            super()._accept(request, reply, work)
            return
        try:
            raw = read_raw(zbytes(sample.payload), zbytes(sample.attachment), self.result_type)
            result = forwardable_result(raw, work.stream, work.seq, request.indices)
        except WireError as exc:
            self.counters.inc("malformed_replies")
            request.error = f"malformed reply: {exc}"
            return
        request.result = result
        self.forward = raw


class ForemanService(ServiceRuntime):
    role = keys.Role.FOREMAN

    def __init__(
        self,
        node: str,
        transport: TransportSettings,
        dispatch: DispatchSettings,
        stats_period_s: float = 1.0,
        queue_capacity: int = 2,
    ) -> None:
        super().__init__(node, 0, transport, stats_period_s)
        self.dispatch_settings = dispatch
        self.dispatcher = Dispatcher(dispatch, MAX_PATCHES)
        self.queue_capacity = queue_capacity
        self._queryable: Any = None
        self.cache = SpectrumCache()
        self.crops_prev = CropStore()
        self._membership: list[tuple[bool, str]] = []
        self._membership_lock = threading.Lock()
        self._worker = WorkerService(node, 0, transport)  # only for its settings cache
        self.scatter: ForwardingScatter | None = None
        self._last_shares: dict[str, float] = {}
        self._entities: list[Any] = []

    def start(self, session: zenoh.Session) -> None:
        self.scatter = ForwardingScatter(
            session, self.dispatcher, self._worker_key, PatchJob, PatchResult, self.counters
        )
        self._entities.append(
            session.liveliness().declare_subscriber(
                keys.alive_node_workers(self.node), self._on_alive, history=True
            )
        )
        # blocks reach the block thread through zenoh's own bounded FIFO (no Python callback thread between)
        self._queryable = session.declare_queryable(
            keys.foreman_key(self.node), zenoh.handlers.FifoChannel(self.queue_capacity), complete=True
        )
        self.spawn(self._serve, "blocks")

    def stop(self) -> None:
        if self._queryable is not None:
            self._queryable.undeclare()  # the block thread's recv() then raises and it exits
            self._queryable = None

    @staticmethod
    def _worker_key(member: str) -> str:
        _role, node, index = member.split("/")
        return keys.worker_key(node, int(index))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            member = keys.parse_alive_key(str(sample.key_expr))
        except CapatazError as exc:
            self.count_error("bad_liveliness", "ignoring liveliness key", exc)
            return
        joined = sample.kind == zenoh.SampleKind.PUT
        with self._membership_lock:
            self._membership.append((joined, member.name))
        if not joined and self.scatter is not None:
            self.scatter.member_left(member.name)
        self.counters.inc("members_joined" if joined else "members_left")

    def _apply_membership(self) -> None:
        with self._membership_lock:
            changes, self._membership = self._membership, []
        for joined, name in changes:
            if joined:
                self.dispatcher.join(name)
            else:
                self.dispatcher.leave(name)

    def shares(self) -> dict[str, float]:
        return dict(self._last_shares)

    def _serve(self) -> None:
        handler = self._queryable.handler
        while not self.stop_event.is_set():
            try:
                query = handler.recv()
            except zenoh.ZError:
                return  # queryable undeclared: shutting down
            t_recv = time.perf_counter()
            self.counters.inc("queries")
            job = self.decode_query(query, BlockJob)
            self.counters.time_ms("decode", (time.perf_counter() - t_recv) * 1e3)
            if job is None:
                continue
            try:
                payload, attachment = self._compute_block(job)
                t_rep = time.perf_counter()
            except (CapatazError, ValueError) as exc:
                self.count_error("rejected", f"block {job.stream}/{job.seq} rejected", exc)
                self.reply_error(query, "rejected", f"{type(exc).__name__}: {exc}")
                continue
            try:
                query.reply(query.key_expr, payload, attachment=attachment)
            except Exception as exc:
                self.count_error("reply_failures", "cannot send reply", exc)
            finally:
                query.drop()
            self.counters.time_ms("reply", (time.perf_counter() - t_rep) * 1e3)
            self.counters.time_ms("handle", (time.perf_counter() - t_recv) * 1e3)

    def _compute_block(self, job: BlockJob) -> tuple[bytes, bytes]:
        """Measure a block with the node's workers; return the encoded :class:`BlockResult`.

        When one worker measured the whole block, its reply's payload is forwarded unchanged under a new
        header (see :func:`forward_block_result`); otherwise the parts are merged and encoded.
        """
        assert self.scatter is not None
        t0 = time.perf_counter()
        settings = self._worker.settings_for(job.settings)
        self.crops_prev.add(job.stream, job.prev_seq, job.prev_indices, job.prev_crops)
        crop_shape = tuple(job.crops.shape[1:])
        block_indices = job.indices
        rows = {i: r for r, i in enumerate(block_indices.tolist())}

        def crops(indices: np.ndarray) -> np.ndarray:
            if indices.size == block_indices.size and np.array_equal(indices, block_indices):
                return job.crops  # the whole block to one member: forward it as it came
            return job.crops[[rows[i] for i in indices.tolist()]] if indices.size else job.crops[:0]

        def prev_crops(indices: np.ndarray) -> np.ndarray:
            return self.crops_prev.get(job.stream, job.prev_seq, indices, crop_shape)

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

        self._apply_membership()
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
        plan = self.dispatcher.plan(job.seq, job.prev_seq, time.monotonic(), job.indices)
        t_plan = time.perf_counter()
        # forwarding needs the worker's rows in the merged (ascending) order: the job's, when ascending
        ascending = job.indices.size < 2 or bool((job.indices[1:] > job.indices[:-1]).all())
        self.scatter.block_indices = job.indices if ascending else None
        report = self.scatter.run(work, plan)
        forward = self.scatter.forward if len(report.parts) == 1 else None
        self.counters.time_ms("prepare", (t_plan - t0) * 1e3)
        self.counters.time_ms("round", (time.perf_counter() - t_plan) * 1e3)
        self.crops_prev.add(job.stream, job.seq, job.indices, job.crops)
        measurement = merge_measurements(report.parts, job.indices) if forward is None else None
        elapsed = time.perf_counter() - t0
        self._last_shares = plan.shares()
        self.counters.inc("blocks")
        self.counters.inc("patches", int(job.indices.size))
        self.counters.time_ms("block", elapsed * 1e3)
        active = set(self.dispatcher.active(time.monotonic()))
        speeds = {m: s for m, s in self.dispatcher.speeds().items() if m in active}
        if forward is not None:
            self.counters.inc("forwarded")
            return forward_block_result(forward, job, self.name, elapsed, report.members, speeds)
        assert measurement is not None
        result = result_from_measurement(
            BlockResult, job, self.name, measurement, elapsed, report.members, speeds
        )
        return encode(result)


def forward_block_result(
    raw: RawMessage,
    job: BlockJob,
    member: str,
    compute_s: float,
    members: dict[str, int],
    speeds: dict[str, float],
) -> tuple[bytes, bytes]:
    """``(payload, attachment)`` of the :class:`BlockResult` of a block one worker measured whole.

    The worker's payload (the result arrays) travels on unchanged; only the header is rebuilt with the
    foreman's fields, as :func:`result_from_measurement` would set them.
    """
    fields = {
        "stream": job.stream,
        "seq": job.seq,
        "prev_seq": job.prev_seq,
        "member": member,
        "compute_s": compute_s,
        "members": members,
        "speeds": speeds,
    }
    return raw.payload, reheader(raw, BlockResult, fields)


def add_dispatch_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--balance", choices=[b.value for b in Balance], default="time", help="share balancing"
    )
    parser.add_argument(
        "--compute",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="compute a share itself besides its members (the paper's configuration)",
    )
    parser.add_argument("--min-deadline-ms", type=float, default=300.0, help="smallest per-request deadline")
    parser.add_argument(
        "--speed",
        choices=[v.value for v in SpeedSource],
        default=SpeedSource.ROUND_TRIP.value,
        help="speed measure for time balancing: workers' own figures, or round-trip patches/s",
    )


def dispatch_from_args(args: argparse.Namespace) -> DispatchSettings:
    return DispatchSettings(
        balance=Balance(args.balance),
        self_compute=args.compute,
        min_deadline_s=args.min_deadline_ms / 1e3,
        speed_source=SpeedSource(args.speed),
    )


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("foreman", help="a foreman: splits blocks among its node's workers")
    add_transport_arguments(parser)
    add_dispatch_arguments(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    return ForemanService(
        args.node, transport_from_args(args), dispatch_from_args(args), args.stats_period
    ).run()


__all__ = ["SELF", "ForemanService", "register"]
