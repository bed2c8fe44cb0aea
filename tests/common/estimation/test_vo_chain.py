"""The VO chain step shared by the estimator and the truth-attitude replay, and the coupling's small
explicit-state pieces (vision tilt, manoeuvre acceleration)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st

from common.errors import InputError
from common.estimation.measurements import (
    SENSOR_ORDER,
    FrameMeasurement,
    ImuMeasurement,
    RangeMeasurement,
    Sensor,
    YawMeasurement,
    sensor_of,
)
from common.estimation.replay import vo_with_true_attitude
from common.estimation.tilt import ManoeuvreTrack, VisionTilt
from common.estimation.vo import (
    MotionModel,
    PreparedFrame,
    VoPose,
    VoSettings,
    estimate_relative_motion,
    track_features,
)
from common.estimation.vo_chain import (
    VoChainSettings,
    prepare_view,
    shifted,
    smoothed_vo_altitude,
    start_vo_chain,
    with_altitude,
    with_pose,
)
from common.metrics import rpe_translation
from common.sim.flight import Flight


def test_one_sensor_order_with_the_range_first() -> None:
    assert sorted(SENSOR_ORDER, key=SENSOR_ORDER.__getitem__) == [
        Sensor.RANGE, Sensor.IMU, Sensor.YAW, Sensor.CAMERA
    ]  # fmt: skip
    image = np.zeros((8, 8), dtype=np.uint8)
    kinds = [
        ImuMeasurement(0.0, np.zeros(3), np.zeros(3)),
        RangeMeasurement(0.0, 1.0),
        YawMeasurement(0.0, 0.0),
        FrameMeasurement(0.0, image),
    ]
    assert [sensor_of(m) for m in kinds] == [Sensor.IMU, Sensor.RANGE, Sensor.YAW, Sensor.CAMERA]
    with pytest.raises(InputError):
        sensor_of("not a measurement")  # type: ignore[arg-type]


def test_keyframe_chain_on_truth_rectified_frames_stays_within_millimetres(flight_b: Flight) -> None:
    """A keyframe shared by frames (moved on beyond 30 px of flow) gives the same metric path as the
    consecutive chain within millimetres over 2 s of the turn."""
    start, stop = 400, 440
    truth = flight_b.p_world_body_m[start:stop, :2]
    consecutive = vo_with_true_attitude(flight_b, start, stop)
    keyframes = vo_with_true_attitude(flight_b, start, stop, chain_settings=VoChainSettings(max_flow_px=30.0))
    assert float(np.linalg.norm(consecutive[-1, :2] - truth[-1])) < 1e-3
    assert float(np.linalg.norm(keyframes[-1, :2] - truth[-1])) < 3e-3
    with pytest.raises(InputError):
        VoChainSettings(max_flow_px=-1.0)


def test_default_feature_budget_beats_the_former_200_on_the_slow_turn_entry(flight_b: Flight) -> None:
    """The default budget (400 corners) against the former 200 on the truth-attitude chain over 10 s of the
    turn entry (slow rotation, sub-pixel flow): a smaller relative error per metre and final error."""
    start, stop = 150, 350
    truth = flight_b.p_world_body_m[start:stop]
    errors = {}
    for settings in (VoSettings(), VoSettings(max_features=200)):
        p = vo_with_true_attitude(flight_b, start, stop, settings=settings)
        rpe = rpe_translation(p[:, :2], truth[:, :2], 1.0, truth).mean_pct
        errors[settings.max_features] = (rpe, float(np.linalg.norm(p[-1, :2] - truth[-1, :2])))
    assert VoSettings().max_features == 400
    assert errors[400][0] < 0.8 * errors[200][0], errors
    assert errors[400][1] < errors[200][1] and errors[400][1] < 3.3e-3, errors


def test_backward_pass_at_full_resolution_keeps_the_pyramid_tracks_and_rejects_occluded_ones(
    flight_b: Flight,
) -> None:
    """The forward-backward check's way back starts at the feature itself: without the pyramid (the
    default) it keeps the tracks the pyramid keeps (two frames apart in the turn), and a track that lands
    in a patch of noise (an occluder in the newer frame) does not close its round trip either way."""
    i, j = 400, 402
    views = [
        prepare_view(
            flight_b.frame(k), flight_b.camera.K, flight_b.R_body_camera,
            (float(flight_b.euler_rad[k, 0]), float(flight_b.euler_rad[k, 1])), VoSettings(),
        )
        for k in (i, j)
    ]  # fmt: skip
    assert VoSettings().fb_lk_levels == 0
    kept = {}
    for levels in (0, VoSettings().lk_levels):
        p0, _ = track_features(views[0], views[1], VoSettings(fb_lk_levels=levels))
        kept[levels] = {(float(x), float(y)) for x, y in p0}
    pyramid = kept[VoSettings().lk_levels]
    assert pyramid <= kept[0] and len(kept[0]) <= 1.01 * len(pyramid), (len(kept[0]), len(pyramid))
    noisy = views[1].image.copy()
    block = np.random.default_rng(0).integers(0, 256, size=(200, 200), dtype=np.uint8)
    noisy[100:300, 200:400] = block
    occluded = PreparedFrame(noisy, views[1].features_px, views[1].inner_mask)
    n_inside = {}
    for levels in (0, VoSettings().lk_levels):
        p0, p1 = track_features(views[0], occluded, VoSettings(fb_lk_levels=levels))
        inside = (p1[:, 0] > 200) & (p1[:, 0] < 400) & (p1[:, 1] > 100) & (p1[:, 1] < 300)
        n_inside[levels] = int(inside.sum())
        assert len(p0) > 0.6 * len(pyramid), (len(p0), len(pyramid))
    # about 50 features started in the block: a few survive by chance (a way back that hardly moves from
    # its start closes too), as with the pyramid; RANSAC drops them and the motion stays the clean pair's
    assert n_inside[0] <= 5 and n_inside[VoSettings().lk_levels] <= 5, n_inside
    K = flight_b.camera.K
    clean = estimate_relative_motion(views[0], views[1], K, VoSettings(), model=MotionModel.LEVEL_FREE_YAW)
    hit = estimate_relative_motion(views[0], occluded, K, VoSettings(), model=MotionModel.LEVEL_FREE_YAW)
    assert np.allclose(hit.t_over_d, clean.t_over_d, atol=2e-4), (hit.t_over_d, clean.t_over_d)


def test_shifted_and_with_pose_keep_keyframe_and_newest_frame_consistent(flight_b: Flight) -> None:
    frame = prepare_view(flight_b.frame(0), flight_b.camera.K, flight_b.R_body_camera, None, VoSettings())
    pose = VoPose(np.eye(3), np.array([1.0, 2.0, 3.0]))
    chain = start_vo_chain(frame, pose, 3.0)
    moved = shifted(chain, np.array([0.5, -1.0, 0.0]))
    assert np.allclose(moved.pose.p_n_camera_m, [1.5, 1.0, 3.0])
    assert np.allclose(moved.keyframe.pose.p_n_camera_m, [1.5, 1.0, 3.0])
    other = with_pose(chain, VoPose(np.eye(3), np.zeros(3)))
    assert other.keyframe.pose is other.pose  # the newest frame is the keyframe: both move


def test_vision_tilt_is_an_information_weighted_forgetting_mean() -> None:
    tilt = VisionTilt()
    assert tilt.normal_xy() is None
    normal = np.array([0.01, -0.02, 1.0])
    tilt = tilt.updated(0.0, np.array([0.01, 0.0, 0.0]), normal, window_s=5.0, min_information=1e-3)
    assert tilt.normal_xy() is None  # 1e-4 of information: not yet
    for k in range(1, 20):
        tilt = tilt.updated(0.05 * k, np.array([0.01, 0.0, 0.0]), normal, window_s=5.0, min_information=1e-3)
    assert np.allclose(tilt.normal_xy(), [0.01, -0.02])
    forgotten = tilt.updated(50.0, np.zeros(3), normal, window_s=5.0, min_information=1e-3)
    assert forgotten.information < 1e-4 * tilt.information


def test_manoeuvre_track_fits_the_acceleration_of_its_window() -> None:
    track = ManoeuvreTrack()
    for k in range(20):
        t = 0.05 * k
        track = track.updated(t, 0.5 * 0.4 * t * t, -0.5 * 0.2 * t * t, window_s=0.6)
    assert track.fitted and len(track.samples) in (12, 13)  # 0.6 s of 20 Hz samples, the edge by rounding
    assert track.accel_world_m_s2 == pytest.approx((0.4, -0.2, 0.0), abs=1e-6)
    cleared = track.cleared()
    assert not cleared.fitted and cleared.accel_world_m_s2 == track.accel_world_m_s2
    assert math.isfinite(cleared.accel_world_m_s2[0])


def test_manoeuvre_track_of_sparse_frames_keeps_enough_positions_for_the_fit() -> None:
    """Regression (issue 11): with frames 4 or more apart (a busy host's estimator skipping frames) the
    0.6 s window held fewer than 5 VO positions, the turn's acceleration stayed 0 and paper C's flight
    ended 4.4 cm off (every 4th frame; 0.80 cm now, 0.77 cm with every frame)."""
    track = ManoeuvreTrack()
    for k in range(10):
        t = 0.25 * k  # 4 frames a second
        track = track.updated(t, 0.5 * 0.4 * t * t, -0.5 * 0.2 * t * t, window_s=0.6)
    assert track.fitted and len(track.samples) == 5
    assert track.accel_world_m_s2 == pytest.approx((0.4, -0.2, 0.0), abs=1e-6)


def test_level_share_weighs_the_chains_and_distrusts_a_level_chain_that_disagrees() -> None:
    from common.estimation.tilt import level_share

    # at the origin the free chain has no drift yet: all free; far along with a certain tilt: mostly level
    assert level_share(3.0, 0.001, 3.0, 0.001, 0.004, 0.0) == 0.0
    far = level_share(3.0, math.radians(0.02), 3.0, math.radians(0.02), 0.004, 10.0)
    assert far > 0.9
    # the same, but the chains 10 cm apart while their stds allow a few centimetres: toward the free chain
    assert level_share(3.0, math.radians(0.02), 3.0, math.radians(0.02), 0.004, 10.0, 0.1**2) < 0.3
    assert level_share(3.0, 0.0, 3.0, 0.0, 0.0, 0.0) == 1.0


@hypothesis_settings(max_examples=200, deadline=None)
@given(
    keyframe_altitude_m=st.floats(0.2, 20.0),
    t_z=st.floats(-0.2, 0.2),
    filter_altitude_m=st.floats(0.2, 20.0),
    dt_s=st.floats(1e-3, 1.0),
    tau_s=st.floats(1e-3, 30.0),
    elapsed_s=st.floats(0.0, 60.0),
)
def test_smoothed_vo_altitude_lies_between_the_vo_ratio_and_the_filter(
    keyframe_altitude_m: float,
    t_z: float,
    filter_altitude_m: float,
    dt_s: float,
    tau_s: float,
    elapsed_s: float,
) -> None:
    predicted = keyframe_altitude_m * (1.0 + t_z)
    out = smoothed_vo_altitude(keyframe_altitude_m, t_z, filter_altitude_m, dt_s, tau_s, elapsed_s)
    low, high = sorted((predicted, filter_altitude_m))
    assert low - 1e-9 <= out <= high + 1e-9
    # the pull toward the filter is dt / tau of the gap (all of it once dt >= tau); tau is the time the
    # chain has run while that is shorter
    tau = min(tau_s, elapsed_s) if elapsed_s >= dt_s else dt_s
    expected_gap = (filter_altitude_m - predicted) * max(0.0, 1.0 - dt_s / tau)
    assert filter_altitude_m - out == pytest.approx(expected_gap, abs=1e-9)


def test_smoothed_vo_altitude_follows_the_vo_ratio_and_falls_back_to_the_filter_on_bad_input() -> None:
    # a 1 % climb seen by the pair, the filter 2 cm low, pulled 1/60 of the way per frame (3 s at 20 fps)
    assert smoothed_vo_altitude(2.0, 0.01, 2.0, 0.05, 3.0) == pytest.approx(2.02 - 0.02 / 60.0)
    # a chain 0.5 s old: a running mean so far (1/10 of the way), the first pair takes the filter's
    assert smoothed_vo_altitude(2.0, 0.01, 2.0, 0.05, 3.0, elapsed_s=0.5) == pytest.approx(2.02 - 0.02 / 10.0)
    assert smoothed_vo_altitude(2.0, 0.01, 2.0, 0.05, 3.0, elapsed_s=0.05) == pytest.approx(2.0)
    assert smoothed_vo_altitude(2.0, 0.01, 2.0, 0.05, 3.0, elapsed_s=math.nan) == pytest.approx(2.0)
    for dt_s in (0.0, -0.05, math.nan):
        assert smoothed_vo_altitude(2.0, 0.01, 1.9, dt_s, 3.0) == 1.9  # first frame, reordered stamp
    assert smoothed_vo_altitude(2.0, -1.5, 1.9, 0.05, 3.0) == 1.9  # a ratio below the ground


def test_with_altitude_sets_the_scale_of_the_next_pair(flight_b: Flight) -> None:
    vo_settings = VoSettings()
    frame = prepare_view(
        flight_b.frame(0), flight_b.camera.K, flight_b.R_body_camera, (0.0, 0.0), vo_settings
    )
    chain = with_altitude(start_vo_chain(frame, VoPose(np.eye(3), np.zeros(3)), 3.5), 3.6)
    assert chain.altitude_m == 3.6 and chain.keyframe.altitude_m == 3.6
