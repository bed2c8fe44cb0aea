"""The pure parts of ``capataz loadtest``: fault schedules, service-level objectives, latency statistics and
the per-fault analysis of a run (no I/O, no clocks: records in, frozen results out)."""

from __future__ import annotations

import enum
import itertools
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from common.dispatch import SELF
from common.errors import InputError
from common.geometry import wrap_angle_rad


class LoadtestError(InputError):
    """A fault schedule, an objective or a load-test setting is invalid."""


class FaultAction(enum.Enum):
    KILL = "kill"  # SIGKILL (restarted at once unless it is a master: the standby takes over)
    STOP = "stop"  # SIGSTOP for the given duration, then SIGCONT
    HOSTILE = "hostile"  # a burst of hostile but valid messages on the stream's keys


TARGETS = ("worker", "foreman", "router", "master")
HOSTILE_KINDS = ("seq", "restart", "size", "uav", "future", "settings", "streams", "sender")

_FAULT = re.compile(
    r"^(?P<action>kill|stop|hostile):(?P<target>[a-z]+)@(?P<at>[0-9.]+)s(?:\+(?P<dur>[0-9.]+)s)?$"
)


@dataclass(frozen=True)
class Fault:
    """One scheduled fault: ``kill:worker@20s``, ``stop:foreman@30s+6s``, ``hostile:seq@10s``."""

    action: FaultAction
    target: str
    at_s: float
    duration_s: float = 0.0

    @property
    def label(self) -> str:
        text = f"{self.action.value}:{self.target}@{self.at_s:g}s"
        return text + (f"+{self.duration_s:g}s" if self.duration_s else "")


def parse_fault(text: str) -> Fault:
    """One fault from its text form; raises :class:`LoadtestError` naming what is wrong."""
    match = _FAULT.match(text.strip())
    if match is None:
        raise LoadtestError(
            f"fault {text!r}: expected ACTION:TARGET@Ts[+Ds], e.g. kill:worker@20s, stop:foreman@30s+6s"
        )
    action = FaultAction(match["action"])
    target = match["target"]
    allowed = HOSTILE_KINDS if action is FaultAction.HOSTILE else TARGETS
    if target not in allowed:
        raise LoadtestError(f"fault {text!r}: target must be one of {', '.join(allowed)}")
    at_s = float(match["at"])
    duration_s = float(match["dur"]) if match["dur"] else 0.0
    if action is FaultAction.STOP and duration_s <= 0:
        raise LoadtestError(f"fault {text!r}: a stop needs a duration (+6s)")
    if action is not FaultAction.STOP and duration_s:
        raise LoadtestError(f"fault {text!r}: only a stop takes a duration")
    if not (math.isfinite(at_s) and math.isfinite(duration_s)):
        raise LoadtestError(f"fault {text!r}: times must be finite")
    return Fault(action, target, at_s, duration_s)


def parse_schedule(items: Iterable[str]) -> tuple[Fault, ...]:
    """Faults from command-line items or file lines (comma or whitespace separated, ``#`` comments)."""
    faults = []
    for item in items:
        for token in re.split(r"[,\s]+", item.split("#", 1)[0]):
            if token:
                faults.append(parse_fault(token))
    return tuple(sorted(faults, key=lambda f: f.at_s))


class Metric(enum.Enum):
    P99_MS = "p99_ms"
    P95_MS = "p95_ms"
    P50_MS = "p50_ms"
    LOST_PCT = "lost_pct"
    GAP_S = "gap_s"
    YAW_JUMP_DEG = "yaw_jump_deg"
    LOST_PER_FAULT = "lost_per_fault"


_SLO = re.compile(r"^(?P<metric>[a-z0-9_]+)\s*(?P<op><=|<)\s*(?P<value>[0-9.eE+-]+)$")


@dataclass(frozen=True)
class Objective:
    """A threshold on a run's metric: ``p99_ms<=50``, ``lost_pct<0.1``, ``yaw_jump_deg<=1``."""

    metric: Metric
    strict: bool
    limit: float

    @property
    def label(self) -> str:
        return f"{self.metric.value}{'<' if self.strict else '<='}{self.limit:g}"

    def met(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        return value < self.limit if self.strict else value <= self.limit


def parse_objective(text: str) -> Objective:
    match = _SLO.match(text.strip())
    if match is None:
        raise LoadtestError(f"objective {text!r}: expected METRIC<=VALUE or METRIC<VALUE, e.g. p99_ms<=50")
    try:
        metric = Metric(match["metric"])
    except ValueError:
        names = ", ".join(m.value for m in Metric)
        raise LoadtestError(f"objective {text!r}: metric must be one of {names}") from None
    limit = float(match["value"])
    if not math.isfinite(limit):
        raise LoadtestError(f"objective {text!r}: the limit must be finite")
    return Objective(metric, match["op"] == "<", limit)


#: The issue's objectives: p99 <= 50 ms and nothing lost (4 streams); capacity: p99 <= 100 ms, < 0.1 % lost.
DEFAULT_OBJECTIVES = ("p99_ms<=50", "lost_pct<=0")
CAPACITY_OBJECTIVES = ("p99_ms<=100", "lost_pct<0.1")
FAULT_OBJECTIVES = ("lost_per_fault<=1", "gap_s<=0.5", "yaw_jump_deg<=1")


@dataclass(frozen=True)
class Latency:
    p50: float
    p95: float
    p99: float
    max: float
    count: int


def latency_stats(latencies_ms: Sequence[float]) -> Latency:
    """Percentiles (linear interpolation) of end-to-end latencies; NaN when there are none."""
    values = np.asarray(latencies_ms, dtype=np.float64)
    if values.size == 0:
        nan = float("nan")
        return Latency(nan, nan, nan, nan, 0)
    p50, p95, p99 = np.percentile(values, [50, 95, 99])
    return Latency(float(p50), float(p95), float(p99), float(values.max()), int(values.size))


@dataclass(frozen=True)
class FrameRecord:
    """One published frame of a stream and what came of it."""

    seq: int
    sent_s: float  # publisher's clock (the frame's wall-clock stamp)
    received_s: float | None = None  # when its yaw arrived (same clock); None = lost
    yaw_rad: float | None = None
    true_yaw_rad: float = 0.0


@dataclass(frozen=True)
class FaultOutcome:
    fault: Fault
    #: frames sent from the fault until recovery (or the next fault) that never got a yaw
    lost: int
    #: longest time between two consecutive yaws around the fault (s)
    gap_s: float
    #: from the fault to the last frame lost or late because of it (s)
    recovery_s: float
    #: largest |published yaw change - true yaw change| between consecutive yaws around the fault (deg)
    yaw_discontinuity_deg: float


def yaw_jumps_deg(records: Sequence[FrameRecord]) -> list[tuple[float, float]]:
    """(send time, |published - true yaw change| in deg) for each pair of consecutive received yaws whose
    truth is known."""
    got = [
        r
        for r in records
        if r.received_s is not None and r.yaw_rad is not None and math.isfinite(r.true_yaw_rad)
    ]
    out = []
    for a, b in itertools.pairwise(got):
        assert a.yaw_rad is not None and b.yaw_rad is not None
        error = float(wrap_angle_rad((b.yaw_rad - a.yaw_rad) - (b.true_yaw_rad - a.true_yaw_rad)))
        out.append((b.sent_s, abs(math.degrees(error))))
    return out


def gaps_s(records: Sequence[FrameRecord]) -> list[tuple[float, float]]:
    """(arrival time, time since the previous yaw) for each received yaw, in arrival order."""
    arrivals = sorted(r.received_s for r in records if r.received_s is not None)
    return [(b, b - a) for a, b in itertools.pairwise(arrivals)]


def analyse_fault(records: Sequence[FrameRecord], fault: Fault, t0_s: float, until_s: float) -> FaultOutcome:
    """The fault's effect on one stream: frames sent in ``[fault, until)`` (``t0_s`` = the run's start).

    ``recovery_s`` runs from the fault to the last frame that was lost or late (latency above three times
    the median of the 2 s before the fault, and at least 50 ms above it): 0 when nothing was.
    """
    start = t0_s + fault.at_s
    window = [r for r in records if start - 0.5 <= r.sent_s < until_s]
    after = [r for r in window if r.sent_s >= start]
    lost = sum(1 for r in after if r.received_s is None)
    before = [r.received_s - r.sent_s for r in records if start - 2.0 <= r.sent_s < start and r.received_s]
    baseline = float(np.median(before)) if before else 0.0
    late_s = max(3.0 * baseline, baseline + 0.05)
    troubled = [
        (r.sent_s if r.received_s is None else r.received_s) - start
        for r in after
        if r.received_s is None or r.received_s - r.sent_s > late_s
    ]
    recovery = max(troubled, default=0.0)
    gap = max((g for t, g in gaps_s(window) if t >= start), default=0.0)
    jump = max((j for t, j in yaw_jumps_deg(window) if t >= start), default=0.0)
    if not any(math.isfinite(r.true_yaw_rad) for r in window):
        jump = math.nan  # no truth (a replayed recording): not judged
    return FaultOutcome(fault, lost, gap, recovery, jump)


@dataclass(frozen=True)
class StreamSummary:
    uav: str
    published: int
    received: int
    lost: int
    reported_dropped: int
    latency: Latency
    max_gap_s: float
    max_yaw_jump_deg: float


def summarise(
    uav: str, records: Sequence[FrameRecord], reported_dropped: int, settle_s: float
) -> StreamSummary:
    """Counts (all frames), latency and continuity (frames sent after ``settle_s``; the load test's warm-up
    comes before its records, so it passes 0).

    ``max_yaw_jump_deg`` is NaN when the truth is unknown (a replayed recording): continuity is not judged."""
    end_settle_s = records[0].sent_s + settle_s if records else 0.0
    steady = [r for r in records if r.sent_s >= end_settle_s]
    jumps = [j for _, j in yaw_jumps_deg(steady)]
    truth = any(math.isfinite(r.true_yaw_rad) for r in records)
    latencies = [1e3 * (r.received_s - r.sent_s) for r in steady if r.received_s is not None]
    received = sum(1 for r in records if r.received_s is not None)
    return StreamSummary(
        uav=uav,
        published=len(records),
        received=received,
        lost=len(records) - received,
        reported_dropped=reported_dropped,
        latency=latency_stats(latencies),
        max_gap_s=max((g for _, g in gaps_s(steady)), default=0.0),
        max_yaw_jump_deg=max(jumps, default=0.0) if truth else math.nan,
    )


def _finite_max(values: Sequence[float]) -> float:
    """The largest finite value; NaN when there is none (nothing was judged)."""
    return max((v for v in values if math.isfinite(v)), default=math.nan)


def metric_values(
    streams: Sequence[StreamSummary], faults: Sequence[Sequence[FaultOutcome]]
) -> dict[Metric, float]:
    """The run's value of each metric: the worst stream (latency percentiles: over all frames pooled is not
    available here, so the worst stream's), the lost share over all streams, the worst fault."""
    published = sum(s.published for s in streams)
    lost = sum(s.lost for s in streams)
    outcomes = [o for per_stream in faults for o in per_stream]
    nan = float("nan")
    return {
        Metric.P50_MS: max((s.latency.p50 for s in streams), default=nan),
        Metric.P95_MS: max((s.latency.p95 for s in streams), default=nan),
        Metric.P99_MS: max((s.latency.p99 for s in streams), default=nan),
        Metric.LOST_PCT: 100.0 * lost / published if published else nan,
        Metric.GAP_S: max([s.max_gap_s for s in streams] + [o.gap_s for o in outcomes], default=nan),
        Metric.YAW_JUMP_DEG: _finite_max(
            [s.max_yaw_jump_deg for s in streams] + [o.yaw_discontinuity_deg for o in outcomes]
        ),
        Metric.LOST_PER_FAULT: float(max((o.lost for o in outcomes), default=0)),
    }


@dataclass(frozen=True)
class ObjectiveResult:
    objective: Objective
    value: float
    met: bool


def evaluate(objectives: Sequence[Objective], values: dict[Metric, float]) -> list[ObjectiveResult]:
    """Each objective against the run's values (a metric without a value is not met)."""
    out = []
    for objective in objectives:
        value = values.get(objective.metric, float("nan"))
        out.append(ObjectiveResult(objective, value, objective.met(value)))
    return out


def next_capacity(tried: dict[int, bool], limit: int) -> int | None:
    """The next stream count of a capacity search (doubling, then bisection between the largest pass and the
    smallest fail); None when it is found. ``tried``: stream count -> objectives met."""
    if not tried:
        return 1
    passed = [n for n, ok in tried.items() if ok]
    failed = [n for n, ok in tried.items() if not ok]
    best = max(passed, default=0)
    worst = min((n for n in failed if n > best), default=None)
    if worst is None:
        nxt = min(limit, max(1, best * 2))
        return None if nxt in tried else nxt
    if worst - best <= 1:
        return None
    return (best + worst) // 2


def capacity_of(tried: dict[int, bool]) -> int:
    """The most streams that met the objectives, below the smallest count that failed."""
    failed = [n for n, ok in tried.items() if not ok]
    ceiling = min(failed, default=10**9)
    return max((n for n, ok in tried.items() if ok and n < ceiling), default=0)


@dataclass(frozen=True)
class ComputeShare:
    """Who computed a stream's frames: the cluster (foremen and their workers) or the master alone."""

    #: frames with a measurement (a new epoch's first frame has none)
    frames: int
    #: frames the master computed entirely itself
    frames_alone: int
    #: patches the cluster computed / all patches (0 when nothing was measured)
    cluster_share: float
    #: each member's patches / all patches (the master as ``self``): where the balancer put the work
    by_member: Mapping[str, float]


def compute_share(computed: Iterable[Mapping[str, int]]) -> ComputeShare:
    """From each frame's patches per member the master addressed (``self``: its own; not a foreman's
    workers)."""
    frames = alone = total = 0
    patches: dict[str, int] = {}
    for members in computed:
        all_patches = sum(members.values())
        if all_patches <= 0:
            continue
        frames += 1
        alone += members.get(SELF, 0) >= all_patches
        total += all_patches
        for member, n in members.items():
            patches[member] = patches.get(member, 0) + n
    own = patches.get(SELF, 0)
    by_member = {m: n / total for m, n in sorted(patches.items())} if total else {}
    return ComputeShare(frames, alone, 1.0 - own / total if total else 0.0, by_member)
