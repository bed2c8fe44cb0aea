"""Liveliness events arrive on zenoh's callback thread, plans are made on the dispatching thread: this
hands the roster (:mod:`common.dispatch.membership`) from one to the other and brings a dispatcher up to
date before each plan. Used by the master and the foreman alike."""

from __future__ import annotations

import threading

from common.dispatch.dispatcher import Dispatcher
from common.dispatch.membership import (
    MembershipChanges,
    Roster,
    Seat,
    apply_changes,
    changes,
    on_liveliness,
    seats,
)
from common.wire.keys import MemberId, Role
from services.runtime.counters import Counters
from services.runtime.scatter import Scatter


class LiveMembers:
    """The roster of one dispatching service and the seats last applied to its dispatcher."""

    def __init__(self, role: Role) -> None:
        #: the role of the members that get work (workers, or foremen for the master's second tier)
        self.role = role
        self._lock = threading.Lock()
        self._roster = Roster()
        self._applied: tuple[Dispatcher | None, int, dict[str, Seat]] = (None, -1, {})

    def on_event(
        self, member: MemberId, joined: bool, counters: Counters | None = None, scatter: Scatter | None = None
    ) -> bool:
        """Fold a liveliness event in (callback thread; never blocks for long); True if anything changed.

        A member of :attr:`role` is counted (``members_joined`` / ``members_left``), and when it left, the
        ``scatter`` cancels what it waits for from it at once (the dispatcher learns it at the next plan).
        """
        with self._lock:
            before = self._roster
            self._roster = on_liveliness(before, member, joined)
            changed = self._roster is not before
        if member.role is self.role:
            if counters is not None:
                counters.inc("members_joined" if joined else "members_left")
            if not joined and scatter is not None:
                scatter.member_left(member.name)
        return changed

    def alive(self) -> tuple[str, ...]:
        with self._lock:
            return tuple(sorted(self._roster.alive))

    def update(self, dispatcher: Dispatcher) -> MembershipChanges:
        """Bring ``dispatcher`` up to date (dispatching thread); nothing to do if the roster is unchanged."""
        with self._lock:
            roster = self._roster
            applied_to, version, applied = self._applied
        if applied_to is dispatcher and version == roster.version:
            return MembershipChanges()
        wanted = seats(roster, self.role)
        todo = changes(applied if applied_to is dispatcher else {}, wanted)
        if applied_to is not dispatcher:  # a new dispatcher: whatever it holds that is not wanted goes
            todo = MembershipChanges(
                tuple(sorted(set(dispatcher.members) - set(wanted))), todo.joined, todo.resized
            )
        apply_changes(dispatcher, todo)
        with self._lock:
            self._applied = (dispatcher, roster.version, wanted)
        return todo
