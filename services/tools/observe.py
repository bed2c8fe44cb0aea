"""Watching a running cluster from a session of our own: who is alive, yaw estimates and members' stats.

:class:`AliveWatch` keeps the members that hold a liveliness token (``capataz up`` waits on it at start-up,
the network harness's agent reports it, ``capataz status`` lists it);
:class:`YawCollector` keeps every yaw estimate of a UAV by frame (tests, the demo, benchmarks, ``up``);
:class:`StatsWatch` keeps each member's latest :class:`~common.wire.messages.Stats`, when it arrived and
the first of a window: ``capataz up`` reports dropped frames and refused inputs per member at the end from
it, ``capataz status`` its rates and members, ``capataz metrics`` its exporter's series
(:func:`refused_count` and :func:`dropped_count` sum those counters for all three).
"""

from __future__ import annotations

import statistics
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import TypeVar

import zenoh

from common.errors import CapatazError
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Stats, YawEstimate
from common.wire.schema import WireError, WireModel
from services.runtime.transport import zbytes

#: counters that mean "an input was refused" (malformed, foreign, out of range, no room) in any service,
#: besides the input gate's ``refused_<sensor>_<reason>`` (:func:`is_refusal`)
REFUSED_COUNTERS = frozenset(
    {"malformed", "rejected", "bad_samples", "bad_frames", "bad_images", "wrong_uav", "queue_full", "busy",
     "malformed_replies", "bad_liveliness"}
)  # fmt: skip


def is_refusal(counter: str) -> bool:
    """True for a counter of refused inputs: one of :data:`REFUSED_COUNTERS` or the input gate's
    ``refused_<sensor>_<reason>`` (and a filter's ``refused_<sensor>_<stale|duplicate|overflow>``)."""
    return counter in REFUSED_COUNTERS or counter.startswith("refused_")


#: counters that mean "a frame was dropped" (latest-wins hand-off replaced an unread frame, a full backlog)
DROPPED_COUNTERS = frozenset({"frames_dropped", "dropped_frames", "backlog_overflow"})


def refused_count(counters: Mapping[str, int]) -> int:
    """Inputs a member refused, over all its refusal counters (:func:`is_refusal`)."""
    return sum(v for k, v in counters.items() if is_refusal(k))


def dropped_count(counters: Mapping[str, int]) -> int:
    """Frames a member dropped unread, over all its drop counters (:data:`DROPPED_COUNTERS`)."""
    return sum(v for k, v in counters.items() if k in DROPPED_COUNTERS)


M = TypeVar("M", bound=WireModel)


class _Watch:
    """A subscriber's decoding: a message that does not decode is counted in :attr:`malformed`, not raised."""

    malformed = 0

    def _decoded(self, sample: zenoh.Sample, expected: type[M]) -> M | None:
        try:
            return decode(zbytes(sample.payload), zbytes(sample.attachment), expected)
        except WireError:
            self.malformed += 1
            return None


def _wait(
    cond: threading.Condition,
    done: Callable[[], bool],
    timeout_s: float,
    check: Callable[[], None] | None = None,
) -> bool:
    """Wait on ``cond`` until ``done()`` (True) or ``timeout_s`` passed (False); ``check`` runs on every
    wake-up (at least every 0.2 s) while not done, and may raise to give up early."""
    deadline = time.monotonic() + timeout_s
    with cond:
        while not done():
            if check is not None:
                check()
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            cond.wait(min(left, 0.2))
        return True


class AliveWatch:
    """The members (``role/node/i``) that hold a liveliness token now, and when each was first seen alive
    (``time.monotonic()``); a token whose key is not a member's is passed over."""

    def __init__(self, session: zenoh.Session) -> None:
        self._cond = threading.Condition()
        self._alive: set[str] = set()
        self.first_seen_s: dict[str, float] = {}
        self._sub = session.liveliness().declare_subscriber(keys.ALIVE_ALL, self._on_alive, history=True)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            name = keys.parse_alive_key(str(sample.key_expr)).name
        except CapatazError:
            return
        with self._cond:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(name)
                self.first_seen_s.setdefault(name, time.monotonic())
            else:
                self._alive.discard(name)
            self._cond.notify_all()

    def names(self) -> set[str]:
        with self._cond:
            return set(self._alive)

    def wait_for(self, names: set[str], timeout_s: float, check: Callable[[], None] | None = None) -> bool:
        """Wait until every one of ``names`` is alive (True) or ``timeout_s`` passed (False); ``check`` runs
        on every wake-up (at least every 0.2 s) and may raise to give up early."""
        return _wait(self._cond, lambda: names <= self._alive, timeout_s, check)

    def close(self) -> None:
        self._sub.undeclare()


def median_timings_ms(estimates: Iterable[YawEstimate]) -> dict[str, float]:
    """Each of the master's stage timings' median (``total``: frame in to yaw out, ms) over ``estimates``."""
    stages: dict[str, list[float]] = {}
    for estimate in estimates:
        for stage, ms in estimate.timings_ms.items():
            stages.setdefault(stage, []).append(ms)
    return {stage: statistics.median(v) for stage, v in sorted(stages.items())}


class YawCollector(_Watch):
    """Subscribes to a UAV's yaw and keeps every estimate by frame seq (for tests, the demo, benches)."""

    def __init__(self, session: zenoh.Session, uav: str) -> None:
        self.estimates: dict[int, YawEstimate] = {}
        self.arrival_s: dict[int, float] = {}
        self.malformed = 0
        self._cond = threading.Condition()
        self._sub = session.declare_subscriber(keys.yaw_key(uav), self._on_yaw)

    def _on_yaw(self, sample: zenoh.Sample) -> None:
        estimate = self._decoded(sample, YawEstimate)
        if estimate is None:
            return
        with self._cond:
            self.estimates[estimate.seq] = estimate
            self.arrival_s[estimate.seq] = time.monotonic()
            self._cond.notify_all()

    def wait_for(self, count: int, timeout_s: float) -> bool:
        return _wait(self._cond, lambda: len(self.estimates) >= count, timeout_s)

    def newest(self) -> int:
        with self._cond:
            return max(self.estimates, default=-1)

    def close(self) -> None:
        self._sub.undeclare()


class StatsWatch(_Watch):
    """The latest stats message of every member (``role/node/i``) from ``capataz/stats/**``, when each
    arrived (``time.monotonic()``) and the first of each since :meth:`start_window` (rates over a window)."""

    def __init__(self, session: zenoh.Session) -> None:
        self._lock = threading.Lock()
        self.latest: dict[str, Stats] = {}
        self.arrival_s: dict[str, float] = {}
        self.window_first: dict[str, Stats] = {}
        self.messages = 0
        self.malformed = 0
        self._sub = session.declare_subscriber(keys.STATS_ALL, self._on_stats)

    def _on_stats(self, sample: zenoh.Sample) -> None:
        stats = self._decoded(sample, Stats)
        if stats is None:
            return
        name = stats.member
        with self._lock:
            self.messages += 1
            self.window_first.setdefault(name, stats)
            self.latest[name] = stats
            self.arrival_s[name] = time.monotonic()

    def start_window(self) -> None:
        """A window starts: each member's first message of it is its latest one so far."""
        with self._lock:
            self.window_first = dict(self.latest)

    def forget(self, silent_s: float, keep: frozenset[str] = frozenset()) -> None:
        """Drop the members (but those in ``keep``) whose last stats are older than ``silent_s``."""
        now = time.monotonic()
        with self._lock:
            for name in [n for n, t in self.arrival_s.items() if now - t > silent_s and n not in keep]:
                del self.latest[name], self.arrival_s[name]
                self.window_first.pop(name, None)

    def snapshot(self) -> dict[str, Stats]:
        with self._lock:
            return dict(self.latest)

    def window(self) -> tuple[dict[str, Stats], dict[str, Stats], dict[str, float]]:
        """Copies of the window's first stats, the latest stats and their arrival times, by member."""
        with self._lock:
            return dict(self.window_first), dict(self.latest), dict(self.arrival_s)

    def close(self) -> None:
        self._sub.undeclare()


def member_rows(
    names: list[str],
    alive_after_s: Mapping[str, float],
    stats: Mapping[str, Stats],
    exit_codes: Mapping[str, int | None],
) -> list[dict[str, object]]:
    """One summary row per member: start-up time, inputs, dropped frames, refused inputs, exit code."""
    rows: list[dict[str, object]] = []
    for name in names:
        counters = stats[name].counters if name in stats else {}
        rows.append(
            {
                "member": name,
                "start-up s": alive_after_s.get(name, float("nan")),
                "inputs": counters.get("frames_in") or counters.get("queries", 0),
                "dropped": dropped_count(counters),
                "refused": refused_count(counters),
                "exit": exit_codes.get(name, "-"),
            }
        )
    return rows
