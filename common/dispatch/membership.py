"""Who is alive and what a dispatcher must change to match: liveliness events in, join/leave/capacity out.

One pure core for both dispatchers (the master's over workers or foremen, a foreman's over its node's
workers), which used to keep membership two ways (a snapshot with a version, and a change log):

- :func:`on_liveliness` folds one liveliness event into a :class:`Roster` (state in, state out). A member
  that joins again after leaving gets a new *incarnation*: it restarted and holds none of its old state.
- :func:`seats` says which members a dispatcher of a given role should have, with their capacity (a
  foreman's is the number of workers alive on its node, at least 1; a worker's is 1).
- :func:`changes` compares those seats with the ones last applied to a dispatcher: joins, leaves (a new
  incarnation is a leave and a join, so its indices are reassigned and its failures forgotten) and
  capacity changes. :func:`apply_changes` applies them to a :class:`~common.dispatch.Dispatcher`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import NamedTuple

from common.dispatch.dispatcher import Dispatcher
from common.members import MemberId, Role


class Seat(NamedTuple):
    """A member's place in a dispatcher: its capacity and the incarnation it was given the seat in."""

    capacity: float
    incarnation: int


@dataclass(frozen=True)
class Roster:
    """Members whose liveliness token is alive, the incarnation of each name, and a change counter."""

    alive: Mapping[str, MemberId] = field(default_factory=lambda: MappingProxyType({}))
    #: joins seen per member name (kept after it leaves, so that a re-join gets a new number)
    incarnations: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    #: bumped on every change: a dispatcher brought up to date at this version needs nothing
    version: int = 0


@dataclass(frozen=True)
class MembershipChanges:
    """What a dispatcher must do to match the roster (leaves first, then joins, then capacities)."""

    left: tuple[str, ...] = ()
    joined: tuple[tuple[str, float], ...] = ()
    resized: tuple[tuple[str, float], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.left or self.joined or self.resized)


def on_liveliness(roster: Roster, member: MemberId, joined: bool) -> Roster:
    """The roster after ``member``'s token appeared (``joined``) or vanished; repeats change nothing."""
    alive = dict(roster.alive)
    incarnations = dict(roster.incarnations)
    if joined:
        if member.name in alive:
            return roster  # the same token seen twice (history and live): not a restart
        alive[member.name] = member
        incarnations[member.name] = incarnations.get(member.name, 0) + 1
    else:
        if member.name not in alive:
            return roster
        del alive[member.name]
    return Roster(MappingProxyType(alive), MappingProxyType(incarnations), roster.version + 1)


def seats(roster: Roster, role: Role) -> dict[str, Seat]:
    """Members of ``role`` a dispatcher should have: a worker weighs 1, a foreman the workers of its node."""
    workers_per_node: dict[str, int] = {}
    for member in roster.alive.values():
        if member.role is Role.WORKER:
            workers_per_node[member.node] = workers_per_node.get(member.node, 0) + 1
    wanted: dict[str, Seat] = {}
    for name, member in roster.alive.items():
        if member.role is not role:
            continue
        capacity = float(max(1, workers_per_node.get(member.node, 0))) if role is Role.FOREMAN else 1.0
        wanted[name] = Seat(capacity, roster.incarnations[name])
    return wanted


def changes(applied: Mapping[str, Seat], wanted: Mapping[str, Seat]) -> MembershipChanges:
    """The joins, leaves and capacity changes that turn the ``applied`` seats into the ``wanted`` ones."""
    left = [n for n, seat in applied.items() if n not in wanted or wanted[n].incarnation != seat.incarnation]
    joined = [(n, s.capacity) for n, s in wanted.items() if n not in applied or n in left]
    resized = [
        (n, s.capacity)
        for n, s in wanted.items()
        if n in applied and n not in left and applied[n].capacity != s.capacity
    ]
    return MembershipChanges(tuple(sorted(left)), tuple(sorted(joined)), tuple(sorted(resized)))


def apply_changes(dispatcher: Dispatcher, todo: MembershipChanges) -> None:
    """Apply ``todo`` to ``dispatcher`` (leaves first: a restarted member re-joins with a clean slate)."""
    for name in todo.left:
        dispatcher.leave(name)
    for name, capacity in todo.joined:
        dispatcher.join(name, capacity)
    for name, capacity in todo.resized:
        dispatcher.set_capacity(name, capacity)
