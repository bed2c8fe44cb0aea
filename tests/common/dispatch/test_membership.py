"""Liveliness events -> roster -> the joins, leaves and capacities a dispatcher needs (one core for the master
and the foreman)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from common.dispatch import Dispatcher, DispatchSettings
from common.dispatch import membership as m
from common.wire.keys import MemberId, Role

MEMBERS = [MemberId(Role.WORKER, node, i) for node in ("a", "b") for i in range(3)] + [
    MemberId(Role.FOREMAN, node, 0) for node in ("a", "b")
]
events = st.lists(st.tuples(st.sampled_from(MEMBERS), st.booleans()), max_size=40)


def fold(roster: m.Roster, evs: list[tuple[MemberId, bool]]) -> m.Roster:
    for member, joined in evs:
        roster = m.on_liveliness(roster, member, joined)
    return roster


@given(events, st.sampled_from([Role.WORKER, Role.FOREMAN]), st.integers(0, 40))
def test_a_dispatcher_brought_up_to_date_has_exactly_the_alive_members(
    evs: list[tuple[MemberId, bool]], role: Role, cut: int
) -> None:
    dispatcher = Dispatcher(DispatchSettings(), 16)
    applied: dict[str, m.Seat] = {}
    roster = m.Roster()
    for part in (evs[:cut], evs[cut:]):  # brought up to date twice, with events in between
        roster = fold(roster, part)
        wanted = m.seats(roster, role)
        m.apply_changes(dispatcher, m.changes(applied, wanted))
        applied = wanted
        assert set(dispatcher.members) == {n for n, m in roster.alive.items() if m.role is role}
    assert not m.changes(applied, applied)  # up to date: nothing to do


@given(events)
def test_an_event_seen_twice_changes_nothing_the_second_time(evs: list[tuple[MemberId, bool]]) -> None:
    roster = m.Roster()
    for member, joined in evs:
        once = m.on_liveliness(roster, member, joined)
        assert m.on_liveliness(once, member, joined) is once
        assert once.version == roster.version + (once is not roster)
        roster = once


def test_a_member_that_restarted_between_two_plans_leaves_and_joins_again() -> None:
    """The master's snapshot missed a leave + join between two frames: the restarted worker kept its
    indices (its spectra gone) and its failures. A new incarnation is now a leave and a join."""
    worker = MEMBERS[0]
    roster = m.on_liveliness(m.Roster(), worker, True)
    applied = m.seats(roster, Role.WORKER)
    roster = m.on_liveliness(m.on_liveliness(roster, worker, False), worker, True)
    todo = m.changes(applied, m.seats(roster, Role.WORKER))
    assert todo == m.MembershipChanges(left=(worker.name,), joined=((worker.name, 1.0),))


def test_a_foremans_capacity_is_the_number_of_workers_alive_on_its_node() -> None:
    foreman_a = MemberId(Role.FOREMAN, "a", 0)
    roster = fold(m.Roster(), [(foreman_a, True), (MEMBERS[0], True), (MEMBERS[1], True), (MEMBERS[3], True)])
    assert m.seats(roster, Role.FOREMAN) == {foreman_a.name: m.Seat(2.0, 1)}
    applied = m.seats(roster, Role.FOREMAN)
    roster = m.on_liveliness(roster, MEMBERS[1], False)
    assert m.changes(applied, m.seats(roster, Role.FOREMAN)) == m.MembershipChanges(
        resized=((foreman_a.name, 1.0),)
    )
    roster = m.on_liveliness(roster, MEMBERS[0], False)  # no worker left: still weighs 1 (it may compute)
    assert m.seats(roster, Role.FOREMAN)[foreman_a.name].capacity == 1.0
