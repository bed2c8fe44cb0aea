"""The master's ledger of published yaw: only sessions that led count (a take-over's starting yaw)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from common.wire.messages import Frame
from services.master.published import (
    ANONYMOUS,
    PublishedLedger,
    PublishedYaw,
    PublishVerdict,
    YawAnchor,
    session_of,
    take_over_anchor,
)

LEADER, FORGER = "aa11", "ff99"


def test_yaw_of_the_own_and_a_resolved_leader_session_is_trusted_others_refused_and_counted() -> None:
    ledger = PublishedLedger("me", capacity=8)
    ledger.trust(LEADER)
    assert ledger.record(PublishedYaw(1, 0.1, 0.5, LEADER), leaders_resolved=True) is PublishVerdict.TRUSTED
    assert ledger.record(PublishedYaw(2, 0.2, 0.6, "me"), leaders_resolved=True) is PublishVerdict.TRUSTED
    assert ledger.record(PublishedYaw(2, 0.2, 9.0, FORGER), leaders_resolved=True) is PublishVerdict.REFUSED
    assert (
        ledger.record(PublishedYaw(3, 0.3, 9.0, ANONYMOUS), leaders_resolved=False) is PublishVerdict.REFUSED
    )
    assert ledger.refused == 2
    assert {s: (y.stamp_s, y.yaw_rad) for s, y in ledger.trusted_yaws().items()} == {
        1: (0.1, 0.5),
        2: (0.2, 0.6),
    }
    newest = ledger.newest_trusted()
    assert newest is not None and newest.yaw_rad == 0.6


def test_yaw_of_a_session_not_resolved_yet_waits_and_counts_once_it_answers_as_the_leader() -> None:
    ledger = PublishedLedger("me", capacity=8)
    assert ledger.record(PublishedYaw(1, 0.1, 0.5, LEADER), leaders_resolved=False) is PublishVerdict.PENDING
    assert ledger.record(PublishedYaw(1, 0.1, 9.0, FORGER), leaders_resolved=False) is PublishVerdict.PENDING
    assert ledger.trusted_yaws() == {} and ledger.newest_trusted() is None
    ledger.trust(LEADER)
    assert {s: (y.stamp_s, y.yaw_rad) for s, y in ledger.trusted_yaws().items()} == {1: (0.1, 0.5)}


def test_the_newest_trusted_yaw_is_the_last_to_arrive_even_after_a_camera_restart() -> None:
    ledger = PublishedLedger("me", capacity=8)
    ledger.trust(LEADER)
    ledger.record(PublishedYaw(50, 5.0, 1.0, LEADER), leaders_resolved=True)
    ledger.record(PublishedYaw(0, 6.0, 1.2, LEADER), leaders_resolved=True)  # a new epoch from seq 0
    newest = ledger.newest_trusted()
    assert newest is not None and newest.yaw_rad == 1.2


forged = st.lists(
    st.tuples(
        st.integers(0, 40), st.floats(-10, 10), st.sampled_from([FORGER, ANONYMOUS, "bb22"]), st.booleans()
    ),
    max_size=200,
)


@given(forged)
def test_no_forged_sequence_changes_what_a_take_over_starts_from(
    items: list[tuple[int, float, str, bool]],
) -> None:
    ledger = PublishedLedger("me", capacity=16)
    ledger.trust(LEADER)
    for seq in range(10):
        ledger.record(PublishedYaw(seq, seq / 10, seq * 0.01, LEADER), leaders_resolved=False)
    before = (ledger.trusted_yaws(), ledger.newest_trusted())
    for seq, yaw, session, resolved in items:
        ledger.record(PublishedYaw(seq, seq / 10, yaw, session), leaders_resolved=resolved)
    assert (ledger.trusted_yaws(), ledger.newest_trusted()) == before


def test_the_session_of_a_declared_source_is_its_zid() -> None:
    assert session_of("aa11/7") == "aa11" and session_of(None) == ANONYMOUS


def test_a_take_over_continues_the_newest_kept_frame_whose_yaw_was_published_with_its_variance() -> None:
    pixels = np.zeros((4, 4), np.uint8)
    recent = [
        (0, Frame(uav="u", seq=seq, stamp_s=seq / 10, width=4, height=4, pixels=pixels)) for seq in range(5)
    ]
    published = {
        1: PublishedYaw(1, 0.1, 0.3, LEADER, 2e-6),
        2: PublishedYaw(2, 0.2, 0.4, LEADER, 3e-6),
        4: PublishedYaw(4, 9.9, 0.9, LEADER, 5e-6),  # seq 4 of another epoch: its stamp differs
    }
    found = take_over_anchor(recent, published)
    assert found is not None
    epoch, frame, anchor = found
    assert (epoch, frame.seq) == (0, 2) and anchor == YawAnchor(0.4, 3e-6)
    assert take_over_anchor(recent, {}) is None
