"""What ``capataz loadtest`` observes of a run: the frames each stream sent (:class:`StreamLog`), the yaw of
every frame with its arrival time (:class:`YawLog`) and every service's counters (:class:`StatsLog`)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import zenoh

from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import YawEstimate
from common.wire.schema import WireError
from services.runtime.transport import zbytes
from services.tools.loadtest.plan import FrameRecord
from services.tools.probe import decode_stats


@dataclass
class StreamLog:
    uav: str
    sent: dict[int, tuple[float, float]] = field(default_factory=dict)  # seq -> (stamp, true yaw)
    #: frames of the warm-up (before the clock starts), as ``sent``
    warm: dict[int, tuple[float, float]] = field(default_factory=dict)
    received: dict[int, tuple[float, float]] = field(default_factory=dict)  # seq -> (arrival, yaw)
    #: seq -> patches per member the master addressed (``self``: its own), from the yaw's ``members``
    computed: dict[int, dict[str, int]] = field(default_factory=dict)
    duplicates: int = 0
    reported_dropped: int = 0

    def records(self, warm_up: bool = False) -> list[FrameRecord]:
        """The measured frames (``warm_up``: those of the warm-up) and what came of each."""
        out = []
        for seq, (stamp, true_yaw) in sorted((self.warm if warm_up else self.sent).items()):
            got = self.received.get(seq)
            out.append(FrameRecord(seq, stamp, got[0] if got else None, got[1] if got else None, true_yaw))
        return out


class YawLog:
    """Every yaw of every stream with its arrival (wall clock, the frames' clock)."""

    def __init__(self, session: zenoh.Session, logs: dict[str, StreamLog]) -> None:
        self.logs = logs
        self.lock = threading.Condition()
        self.malformed = 0
        self._sub = session.declare_subscriber(f"{keys.ROOT}/uav/*/yaw", self._on_yaw)

    def _on_yaw(self, sample: zenoh.Sample) -> None:
        arrival = time.time()
        try:
            estimate = decode(zbytes(sample.payload), zbytes(sample.attachment), YawEstimate)
        except WireError:
            self.malformed += 1
            return
        log = self.logs.get(estimate.uav)
        if log is None or (estimate.seq not in log.sent and estimate.seq not in log.warm):
            return
        with self.lock:
            if estimate.seq in log.received:
                log.duplicates += 1
            else:
                log.received[estimate.seq] = (arrival, estimate.yaw_rad)
                # not foreman>worker
                log.computed[estimate.seq] = {m: n for m, n in estimate.members.items() if ">" not in m}
            log.reported_dropped = max(log.reported_dropped, estimate.dropped_frames)
            self.lock.notify_all()

    def close(self) -> None:
        self._sub.undeclare()


class StatsLog:
    """The newest counters each service published (``capataz/stats/**``), to tell where frames were lost."""

    def __init__(self, session: zenoh.Session) -> None:
        self.latest: dict[str, dict[str, int]] = {}
        #: when each service's newest counters arrived (this host's monotonic clock)
        self.arrived_monotonic_s: dict[str, float] = {}
        self._base: dict[str, dict[str, int]] = {}
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(keys.STATS_ALL, self._on_stats)

    def _on_stats(self, sample: zenoh.Sample) -> None:
        stats = decode_stats(sample)
        if stats is None:
            return
        name = stats.member
        with self._lock:
            self.latest[name] = dict(stats.counters)
            self.arrived_monotonic_s[name] = time.monotonic()

    def wait_fresh(self, since_monotonic_s: float, timeout_s: float) -> bool:
        """Wait (bounded) until every service seen so far has published counters after ``since_monotonic_s``
        (a stats period is 1 s; a loaded host delays it): True when all have."""
        deadline = time.monotonic() + timeout_s
        while True:
            with self._lock:
                stale = [n for n, t in self.arrived_monotonic_s.items() if t <= since_monotonic_s]
            if not stale or time.monotonic() >= deadline:
                return not stale
            time.sleep(0.05)

    def mark(self) -> None:
        """Counters from now on (a service's counts before the run are subtracted)."""
        with self._lock:
            self._base = {name: dict(counts) for name, counts in self.latest.items()}

    def since_mark(self) -> dict[str, dict[str, int]]:
        """Each service's non-zero counter changes since :meth:`mark` (a restarted one: since its start)."""
        out = {}
        with self._lock:
            for name, counts in sorted(self.latest.items()):
                base = self._base.get(name, {})
                if any(v < base.get(k, 0) for k, v in counts.items()):
                    base = {}  # restarted during the run: its counters started again from 0
                changed = {k: v - base.get(k, 0) for k, v in sorted(counts.items()) if v != base.get(k, 0)}
                if changed:
                    out[name] = changed
        return out

    def close(self) -> None:
        self._sub.undeclare()
