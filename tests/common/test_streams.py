"""Stream admission at the wire: hostile frames and stamps are refused and counted, restarts are new
epochs."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from common.streams import (
    FrameGateSettings,
    FrameGateState,
    FrameKey,
    GateVerdict,
    StampGuardSettings,
    StampGuardState,
    admit_frame,
    check_stamp,
)

KEY = FrameKey(752, 480, "mono8")
GATE = FrameGateSettings()
FPS = 20.0
#: the receiver's wall clock: the simulated streams' stamps (from 0) are far from it
WALL = 1.7e9


def run_stream(state: FrameGateState, seqs: range, t0: float = 0.0, seq0: int = 0) -> FrameGateState:
    """A well-behaved stream: seq k at stamp k/FPS, received at the same monotonic time."""
    for k in seqs:
        state, decision = admit_frame(state, GATE, "uav0", "uav0", k, t0 + (k - seq0) / FPS, KEY,
                                      t0 + (k - seq0) / FPS, WALL)  # fmt: skip
        assert decision.admitted, decision
    return state


def test_the_first_frame_starts_epoch_zero_and_a_steady_stream_is_accepted() -> None:
    state, decision = admit_frame(FrameGateState(), GATE, "uav0", "uav0", 7, 0.0, KEY, 0.0, WALL)
    assert decision.verdict is GateVerdict.NEW_EPOCH and state.epoch == 0
    state = run_stream(state, range(8, 50), seq0=7)
    assert state.epoch == 0 and state.current is not None and state.current.last.seq == 49


def test_seq_2_pow_53_is_refused_counted_and_never_adopted() -> None:
    state = run_stream(FrameGateState(), range(0, 20))
    state, decision = admit_frame(state, GATE, "uav0", "uav0", 2**53, 20 / FPS, KEY, 20 / FPS, WALL)
    assert decision.verdict is GateVerdict.REFUSE and decision.reason == "seq_jump"
    assert state.refused == {"seq_jump": 1}
    state = run_stream(state, range(20, 60))  # the real frames go on, in the same epoch
    assert state.epoch == 0


def test_a_timestamp_jump_is_refused() -> None:
    state = run_stream(FrameGateState(), range(0, 20))
    state, decision = admit_frame(state, GATE, "uav0", "uav0", 20, 1e5, KEY, 20 / FPS, WALL)
    assert decision.reason == "stamp_jump" and not decision.admitted
    state = run_stream(state, range(20, 40))
    assert state.epoch == 0


def test_a_camera_restart_from_seq_0_is_a_new_epoch_after_confirmation() -> None:
    state = run_stream(FrameGateState(), range(0, 100))
    t = 100 / FPS + 0.2  # restarted at once: the old stream stops, the new one counts from 0
    verdicts = []
    for k in range(5):
        state, decision = admit_frame(state, GATE, "uav0", "uav0", k, t + k / FPS, KEY, t + k / FPS, WALL)
        verdicts.append(decision.verdict)
    assert verdicts[: GATE.confirm_frames - 1] == [GateVerdict.REFUSE] * (GATE.confirm_frames - 1)
    assert verdicts[GATE.confirm_frames - 1] is GateVerdict.NEW_EPOCH
    assert verdicts[GATE.confirm_frames :] == [GateVerdict.ACCEPT] * (5 - GATE.confirm_frames)
    assert state.epoch == 1


def test_a_restart_after_silence_is_adopted_with_its_first_frame() -> None:
    state = run_stream(FrameGateState(), range(0, 100))
    t = 100 / FPS + GATE.silence_s + 0.5
    state, decision = admit_frame(state, GATE, "uav0", "uav0", 0, t, KEY, t, WALL)
    assert decision.verdict is GateVerdict.NEW_EPOCH and state.epoch == 1


def test_frames_of_another_size_encoding_or_uav_are_refused() -> None:
    state = run_stream(FrameGateState(), range(0, 10))
    for key, uav, reason in (
        (FrameKey(64, 64, "mono8"), "uav0", "wrong_size"),
        (FrameKey(4096, 4096, "mono8"), "uav0", "wrong_size"),
        (FrameKey(752, 480, "rgb8"), "uav0", "wrong_encoding"),
        (KEY, "uav1", "foreign_uav"),
    ):
        state, decision = admit_frame(state, GATE, "uav0", uav, 10, 10 / FPS, key, 10 / FPS, WALL)
        assert decision.reason == reason and not decision.admitted
    state = run_stream(state, range(10, 20))
    assert state.epoch == 0


def test_a_wall_clock_stream_refuses_future_stamps() -> None:
    state, decision = admit_frame(FrameGateState(), GATE, "uav0", "uav0", 0, WALL + 3600, KEY, 0.0, WALL)
    assert decision.reason == "future_stamp" and state.epoch == -1


@settings(max_examples=200, deadline=None)
@given(
    hostile=st.lists(
        st.tuples(
            # a seq that cannot continue the stream (backwards, or a jump beyond the bound): a frame that
            # looks exactly like the next one cannot be told apart without the sender's identity
            st.one_of(st.integers(0, 3), st.integers(10_000, 2**60)),
            st.floats(-1e9, 1e9, allow_nan=False),
            st.sampled_from(["uav0", "uav1"]),
            st.sampled_from([KEY, FrameKey(64, 64, "mono8")]),
        ),
        max_size=3,
    ),
    at=st.integers(5, 30),
)
def test_hostile_frames_between_real_ones_never_change_the_epoch(
    hostile: list[tuple[int, float, str, FrameKey]], at: int
) -> None:
    """A real stream interleaved with hostile frames (one between two real ones) stays in its epoch."""
    state = run_stream(FrameGateState(), range(0, at))
    for k in range(at, at + 3 * len(hostile) + 3):
        if hostile and k % 3 == 0:
            seq, stamp, uav, key = hostile.pop()
            state, _ = admit_frame(state, GATE, "uav0", uav, seq, stamp, key, k / FPS, WALL)
        state = run_stream(state, range(k, k + 1), seq0=0)
    assert state.epoch == 0


def test_a_future_imu_stamp_is_refused_and_does_not_move_the_stream() -> None:
    guard = StampGuardSettings()
    state = StampGuardState()
    for k in range(400):
        state, decision = check_stamp(state, guard, k / 400, k / 400, WALL)
        assert decision.admitted
    for _ in range(2):
        state, decision = check_stamp(state, guard, 1e5, 1.0, WALL)
        assert decision.reason == "future_stamp" and not decision.admitted
    for k in range(400, 800):
        state, decision = check_stamp(state, guard, k / 400, k / 400, WALL)
        assert decision.verdict is GateVerdict.ACCEPT
    assert math.isclose(state.stamp_s, 799 / 400)


def test_a_real_clock_jump_is_adopted_after_confirmation() -> None:
    guard = StampGuardSettings()
    state = StampGuardState()
    state, _ = check_stamp(state, guard, 0.0, 0.0, WALL)
    verdicts = []
    for k in range(guard.confirm_samples):
        state, decision = check_stamp(state, guard, 1000.0 + k / 400, 0.1 + k / 400, WALL)
        verdicts.append(decision.verdict)
    assert verdicts[-1] is GateVerdict.NEW_EPOCH and set(verdicts[:-1]) == {GateVerdict.REFUSE}


CAMERA = "c0f38f87c807831a60afb7eff97c3938/6"
OTHER = "9d0c3e5a5b1f4e0f8a1b2c3d4e5f6a7b/6"


def sender_of(state: FrameGateState) -> str | None:
    """The sender of the current epoch."""
    assert state.current is not None
    return state.current.source


def run_sender(state: FrameGateState, seqs: range, source: str | None, t0: float = 0.0) -> FrameGateState:
    for k in seqs:
        t = t0 + k / FPS
        state, decision = admit_frame(state, GATE, "uav0", "uav0", k, t, KEY, t, WALL, source)
        assert decision.admitted, decision
    return state


@settings(max_examples=200, deadline=None)
@given(at=st.integers(5, 40), n=st.integers(1, 6), other=st.sampled_from([OTHER, None]))
def test_a_second_sender_within_an_epoch_is_refused_and_counted(at: int, n: int, other: str | None) -> None:
    """Frames of another sender that look exactly like the camera's next ones (same seq, stamp, size, UAV)
    are refused and counted, one at a time between the camera's, and never move the epoch."""
    state = run_sender(FrameGateState(), range(0, at), CAMERA)
    assert sender_of(state) == CAMERA
    for k in range(at, at + n):
        t = k / FPS
        state, decision = admit_frame(state, GATE, "uav0", "uav0", k, t, KEY, t, WALL, other)
        assert decision.verdict is GateVerdict.REFUSE and decision.reason == "foreign_sender"
        state = run_sender(state, range(k, k + 1), CAMERA)
    assert state.epoch == 0 and sender_of(state) == CAMERA and state.refused == {"foreign_sender": n}


def test_a_camera_restarted_in_a_new_session_is_a_new_epoch_once_the_old_one_is_silent() -> None:
    state = run_sender(FrameGateState(), range(0, 100), CAMERA)
    last_s = 99 / FPS
    # the new session counts from 0 at once: refused (counted) however many agree, until the old sender
    # has been silent for silence_s; then its next frame starts the epoch
    verdicts = []
    k = 0
    while True:
        t = last_s + 0.05 + k / FPS
        state, decision = admit_frame(state, GATE, "uav0", "uav0", k, t, KEY, t, WALL, OTHER)
        verdicts.append(decision.verdict)
        if decision.admitted:
            break
        k += 1
    assert verdicts[-1] is GateVerdict.NEW_EPOCH and set(verdicts[:-1]) == {GateVerdict.REFUSE}
    assert t - last_s > GATE.silence_s and t - last_s <= GATE.silence_s + 1 / FPS + 0.05
    assert state.epoch == 1 and sender_of(state) == OTHER and state.refused == {"foreign_sender": k}
    # the old session's frames are now another sender's
    state, decision = admit_frame(state, GATE, "uav0", "uav0", 100, t, KEY, t, WALL, CAMERA)
    assert decision.reason == "foreign_sender"
