"""Admission of a stream's samples at the wire: epochs, sequence and time-stamp jumps (pure, no I/O).

Two gates, both state in, decision out:

- :class:`FrameGate` for a camera stream: a frame whose UAV, size or encoding differs from the stream's, whose
  sender differs from the one that opened the epoch (where the transport tells the sender: zenoh's
  ``source_info``, ``None`` = declared none), or whose ``seq`` / ``stamp_s`` jumps beyond a bound (forward
  or backward), is **refused** and never adopted on its own. Refused frames that agree with each other (one
  sender, one size, increasing seq and stamps) and arrive ``confirm_frames`` in a row with no frame of the
  current epoch in between, or while the current epoch is silent for ``silence_s``, start a **new epoch**
  (a camera restarted from seq 0, a reconfigured camera); another sender's frames only the latter way.
  One hostile frame thus never moves the stream, and a real restart costs ``confirm_frames - 1`` frames.
- :class:`StampGuard` for one sensor's time stamps: a stamp further in the future than the stream's recent
  stamps plus the wall-clock time elapsed since (plus ``max_ahead_s``) is refused, as is a stamp ahead of
  the wall clock itself when the stream runs on wall-clock time. The same confirmation rule adopts a real
  clock jump. No single sample can move the guard, so no single sample can freeze a filter behind it.

:class:`StreamTable` bounds per-stream state (foremen, workers) by count and age.

Clocks in names: ``now_s`` is a monotonic reading of the receiver, ``wall_s`` its ``time.time()``.
"""

from __future__ import annotations

import enum
import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Generic, TypeVar

from common.bounds import Bounded, bounded
from common.errors import InputError

#: Stamps within this many seconds of the wall clock are taken as wall-clock stamps (checked against it).
WALL_CLOCK_WINDOW_S = 30 * 24 * 3600.0


def _from_the_future(stamp_s: float, wall_s: float, max_future_s: float) -> bool:
    """True when ``stamp_s`` is a wall-clock stamp more than ``max_future_s`` ahead of the wall clock."""
    return abs(stamp_s - wall_s) < WALL_CLOCK_WINDOW_S and stamp_s > wall_s + max_future_s


class GateVerdict(enum.Enum):
    """What a gate decided about one sample."""

    ACCEPT = "accept"  # continues the current epoch
    NEW_EPOCH = "new_epoch"  # first sample, or a confirmed restart: the consumer re-initialises
    REFUSE = "refuse"


@dataclass(frozen=True)
class Decision:
    verdict: GateVerdict
    #: counter name of a refusal (``foreign_uav``, ``wrong_size``, ``seq_jump``, ...); "" when admitted
    reason: str = ""
    detail: str = ""
    #: frames between the previous admitted one and this one (seq gap, within one epoch)
    gap: int = 0

    @property
    def admitted(self) -> bool:
        return self.verdict is not GateVerdict.REFUSE


@dataclass(frozen=True)
class StreamClockSettings(Bounded):
    """How far a stream's stamps may run ahead: the bounds both gates share."""

    #: fastest a stream's clock may run against the wall clock (replays faster than real time)
    max_rate: float = bounded(4.0, gt=0.0)
    #: stamps this far ahead of the wall clock are refused (wall-clock streams only)
    max_future_s: float = bounded(1.0, gt=0.0)


@dataclass(frozen=True)
class FrameGateSettings(StreamClockSettings):
    """Bounds of a camera stream."""

    #: largest forward seq step accepted within an epoch (a longer gap is a jump)
    max_seq_jump: int = bounded(200, ge=1)
    #: largest stamp advance beyond ``max_rate`` x the wall-clock time elapsed since the previous frame (s)
    max_stamp_jump_s: float = bounded(5.0, gt=0.0)
    #: refused frames that agree, in a row, needed to start a new epoch
    confirm_frames: int = bounded(3, ge=1)
    #: after this long without a frame of the current epoch, one consistent frame starts a new epoch
    silence_s: float = bounded(1.0, gt=0.0)


@dataclass(frozen=True)
class FrameKey:
    """What must stay the same within a stream epoch."""

    width: int
    height: int
    encoding: str


@dataclass(frozen=True)
class _Last:
    seq: int
    stamp_s: float
    now_s: float


@dataclass(frozen=True)
class _Run:
    """Frames that follow each other: their key, their sender (None: it declared none) and the newest one."""

    key: FrameKey
    source: str | None
    last: _Last


@dataclass(frozen=True)
class FrameGateState:
    """The stream as the gate knows it."""

    epoch: int = -1
    #: the current epoch's frames (None: nothing admitted yet)
    current: _Run | None = None
    #: the refused frames that agree with each other so far (a candidate epoch), and how many they are
    candidate: _Run | None = None
    candidate_count: int = 0
    refused: dict[str, int] = field(default_factory=dict)


def _follows(prev: _Last, seq: int, stamp_s: float, now_s: float, settings: FrameGateSettings) -> str:
    """'' when (seq, stamp_s) plausibly follows ``prev``; else the reason it does not."""
    step = seq - prev.seq
    if step <= 0:
        return "seq_backward"
    if step > settings.max_seq_jump:
        return "seq_jump"
    if stamp_s <= prev.stamp_s:
        return "stamp_backward"
    if _ahead(stamp_s, prev.stamp_s, prev.now_s, now_s, settings.max_stamp_jump_s, settings.max_rate):
        return "stamp_jump"
    return ""


def admit_frame(
    state: FrameGateState,
    settings: FrameGateSettings,
    expected_uav: str,
    uav: str,
    seq: int,
    stamp_s: float,
    key: FrameKey,
    now_s: float,
    wall_s: float,
    source: str | None = None,
) -> tuple[FrameGateState, Decision]:
    """Decide about one frame of the stream ``expected_uav`` sent by ``source`` (the sender as the transport
    tells it, None when it does not); returns the new state and the decision.

    A second sender within an epoch is refused (``foreign_sender``); its frame starts a new epoch only once
    the epoch's sender has been silent for ``silence_s`` (a camera restarted in a new session), never by
    ``confirm_frames`` in a row: frames that agree with each other are what a flooding forger sends."""

    def refuse(
        reason: str, detail: str, new: FrameGateState | None = None
    ) -> tuple[FrameGateState, Decision]:
        base = new if new is not None else state
        counts = dict(base.refused)
        counts[reason] = counts.get(reason, 0) + 1
        return replace(base, refused=counts), Decision(GateVerdict.REFUSE, reason, detail)

    if uav != expected_uav:
        return refuse("foreign_uav", f"frame of {uav!r} on {expected_uav!r}'s stream")
    if not math.isfinite(stamp_s):
        return refuse("bad_stamp", f"stamp {stamp_s}")
    if _from_the_future(stamp_s, wall_s, settings.max_future_s):
        return refuse("future_stamp", f"stamp {stamp_s - wall_s:.3f} s ahead of the wall clock")
    last = _Last(seq, stamp_s, now_s)
    run = _Run(key, source, last)
    current = state.current
    if current is None:
        return FrameGateState(epoch=state.epoch + 1, current=run, refused=state.refused), Decision(
            GateVerdict.NEW_EPOCH
        )
    if source != current.source:
        why = "foreign_sender"
        detail = f"frame of sender {source or 'anonymous'} in the epoch of {current.source or 'anonymous'}"
    elif key == current.key:
        why = _follows(current.last, seq, stamp_s, now_s, settings)
        if not why:
            gap = seq - current.last.seq - 1
            accepted = replace(state, current=replace(current, last=last), candidate=None, candidate_count=0)
            return accepted, Decision(GateVerdict.ACCEPT, gap=gap)
        detail = (
            f"seq {seq} stamp {stamp_s:.6f} after seq {current.last.seq} stamp {current.last.stamp_s:.6f}"
        )
    else:
        why = (
            "wrong_size"
            if (key.width, key.height) != (current.key.width, current.key.height)
            else "wrong_encoding"
        )
        detail = (
            f"{key.width}x{key.height} {key.encoding} on a {current.key.width}x{current.key.height} stream"
        )
    # not the current epoch: a candidate for a new one?
    agrees = (
        state.candidate is not None
        and state.candidate.key == key
        and state.candidate.source == source
        and not _follows(state.candidate.last, seq, stamp_s, now_s, settings)
    )
    count = state.candidate_count + 1 if agrees else 1
    silent = now_s - current.last.now_s > settings.silence_s
    restart = why in ("seq_backward", "stamp_backward", "wrong_size", "wrong_encoding", "foreign_sender")
    # another sender's frames agreeing with each other is what a flooding forger sends: only silence counts
    confirmed = count >= settings.confirm_frames and why != "foreign_sender"
    if confirmed or (silent and restart):
        return FrameGateState(epoch=state.epoch + 1, current=run, refused=state.refused), Decision(
            GateVerdict.NEW_EPOCH, why, detail
        )
    return refuse(why, detail, replace(state, candidate=run, candidate_count=count))


@dataclass(frozen=True)
class StampGuardSettings(StreamClockSettings):
    """Bounds of one sensor's time stamps."""

    #: a stamp may run ahead of the stream's previous stamp by the wall-clock time elapsed plus this (s)
    max_ahead_s: float = bounded(2.0, gt=0.0)
    #: refused stamps that agree with each other, in a row, needed to adopt a jumped clock
    confirm_samples: int = bounded(5, ge=1)


@dataclass(frozen=True)
class StampGuardState:
    #: newest accepted stamp and the receiver's monotonic time then
    stamp_s: float = -math.inf
    now_s: float = 0.0
    candidate_stamp_s: float = math.nan
    candidate_now_s: float = 0.0
    candidate_count: int = 0


def _ahead(
    stamp_s: float, ref_stamp_s: float, ref_now_s: float, now_s: float, bound_s: float, rate: float
) -> bool:
    """True when ``stamp_s`` runs ahead of ``ref_stamp_s`` by more than ``rate`` x the receiver's elapsed time
    plus ``bound_s``."""
    return stamp_s - ref_stamp_s > rate * max(0.0, now_s - ref_now_s) + bound_s


def check_stamp(
    state: StampGuardState, settings: StampGuardSettings, stamp_s: float, now_s: float, wall_s: float
) -> tuple[StampGuardState, Decision]:
    """Admit or refuse one sensor stamp; ``NEW_EPOCH`` when a jumped clock was confirmed."""
    if not math.isfinite(stamp_s):
        return state, Decision(GateVerdict.REFUSE, "bad_stamp", f"stamp {stamp_s}")
    if _from_the_future(stamp_s, wall_s, settings.max_future_s):
        return state, Decision(
            GateVerdict.REFUSE, "future_stamp", f"{stamp_s - wall_s:.3f} s ahead of the wall clock"
        )
    ahead = _ahead(stamp_s, state.stamp_s, state.now_s, now_s, settings.max_ahead_s, settings.max_rate)
    if state.stamp_s == -math.inf or not ahead:
        newest = max(state.stamp_s, stamp_s)
        return StampGuardState(stamp_s=newest, now_s=now_s if newest == stamp_s else state.now_s), Decision(
            GateVerdict.ACCEPT
        )
    agrees = (
        state.candidate_count > 0
        and not _ahead(
            stamp_s,
            state.candidate_stamp_s,
            state.candidate_now_s,
            now_s,
            settings.max_ahead_s,
            settings.max_rate,
        )
        and stamp_s >= state.candidate_stamp_s
    )
    count = state.candidate_count + 1 if agrees else 1
    if count >= settings.confirm_samples:
        return StampGuardState(stamp_s=stamp_s, now_s=now_s), Decision(GateVerdict.NEW_EPOCH, "clock_jump")
    detail = f"stamp {stamp_s:.6f} is {stamp_s - state.stamp_s:.3f} s after the stream's newest"
    return replace(state, candidate_stamp_s=stamp_s, candidate_now_s=now_s, candidate_count=count), Decision(
        GateVerdict.REFUSE, "future_stamp", detail
    )


V = TypeVar("V")


class StreamTable(Generic[V]):
    """Per-stream state bounded by count and age: the least recently used stream beyond ``max_streams``, and
    every stream unused for ``max_age_s``, is evicted (so thousands of stream names cost bounded memory)."""

    def __init__(self, max_streams: int, max_age_s: float) -> None:
        if max_streams < 1 or not (math.isfinite(max_age_s) and max_age_s > 0):
            raise InputError(f"max_streams must be >= 1 and max_age_s > 0, got {max_streams}, {max_age_s}")
        self.max_streams = max_streams
        self.max_age_s = max_age_s
        self._items: OrderedDict[str, tuple[float, V]] = OrderedDict()
        self.evicted = 0

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, stream: object) -> bool:
        return stream in self._items

    def values(self) -> list[V]:
        return [value for _, value in self._items.values()]

    def get(self, stream: str, now_s: float, create: Callable[[], V]) -> V:
        """The state of ``stream`` (created when absent), marked as used at ``now_s``."""
        item = self._items.pop(stream, None)
        value = create() if item is None else item[1]
        self._items[stream] = (now_s, value)
        self._evict(now_s)
        return value

    def peek(self, stream: str) -> V | None:
        item = self._items.get(stream)
        return None if item is None else item[1]

    def _evict(self, now_s: float) -> None:
        while len(self._items) > self.max_streams:
            self._items.popitem(last=False)
            self.evicted += 1
        while self._items:
            oldest = next(iter(self._items.values()))[0]
            if now_s - oldest <= self.max_age_s:
                break
            self._items.popitem(last=False)
            self.evicted += 1
