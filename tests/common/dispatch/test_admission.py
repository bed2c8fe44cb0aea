"""One frame source per stream and liveliness churn limited per key (pure)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from common.dispatch.admission import ANONYMOUS, AdmissionSettings, ChurnLimiter, SourceLock


def test_a_flood_of_anonymous_frames_cannot_replace_the_declared_camera() -> None:
    lock = SourceLock(AdmissionSettings(hold_s=1.0))
    admitted = []
    for k in range(200):  # the camera at 20 fps, forged anonymous frames at 100 fps
        now = k * 0.01
        if k % 5 == 0:
            admitted.append(("camera", lock.admit("zid1/7", now)))
        admitted.append(("forger", lock.admit(None, now)))
    camera = [ok for who, ok in admitted if who == "camera"]
    assert all(camera) and len(camera) == 40
    assert lock.dropped[ANONYMOUS] == 200
    assert not any(ok for who, ok in admitted if who == "forger")


def test_the_lock_moves_to_another_source_only_after_the_first_goes_silent() -> None:
    lock = SourceLock(AdmissionSettings(hold_s=1.0))
    assert lock.admit("a/1", 0.0)
    assert not lock.admit("b/2", 0.5)
    assert lock.admit("b/2", 1.6)  # a/1 silent for more than hold_s
    assert not lock.admit("a/1", 1.7)
    assert lock.dropped == {"b/2": 1, "a/1": 1}


def test_frames_without_a_declared_source_are_accepted_when_nobody_declares_one() -> None:
    lock = SourceLock()
    assert all(lock.admit(None, k * 0.05) for k in range(20))


def test_a_churning_liveliness_key_is_quarantined_and_leaves_are_always_applied() -> None:
    churn = ChurnLimiter(AdmissionSettings(max_changes=4, window_s=10.0, quarantine_s=30.0))
    results = [churn.allow("foreman/x/0", joined=k % 2 == 0, now_s=k * 0.1) for k in range(10)]
    assert all(results[:4])
    assert churn.quarantined(1.0) == {"foreman/x/0"}
    assert not churn.allow("foreman/x/0", joined=True, now_s=1.5)
    assert churn.allow("foreman/x/0", joined=False, now_s=1.6)
    assert churn.quarantined(40.0) == frozenset()
    assert churn.allow("foreman/steady/0", joined=True, now_s=1.0)


@given(st.lists(st.integers(0, 10_000), min_size=1, max_size=300))
def test_memory_stays_bounded_under_a_flood_of_new_keys_and_sources(ids: list[int]) -> None:
    settings = AdmissionSettings(max_tracked=16)
    churn, lock = ChurnLimiter(settings), SourceLock(settings)
    lock.admit("camera/1", 0.0)
    for k, i in enumerate(ids):
        churn.allow(f"worker/n{i}/0", joined=True, now_s=k * 0.001)
        lock.admit(f"forged/{i}", k * 0.001)
    assert len(churn._changes) <= 16 and len(lock.dropped) <= 16
