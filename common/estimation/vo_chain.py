"""The visual-odometry chain, shared by the estimator and the truth-attitude replay.

A step prepares the new frame (orthogonally rectified with a given roll and pitch, section III-C, or raw),
estimates the motion against the chain's **keyframe** (Algorithms 1-2, the flow seeded with the keyframe's
last homography) and composes the keyframe's pose with the translation scaled by the keyframe's altitude
(eqs. 9-10). Paper C chains consecutive frames; a keyframe shared by many frames adds up far fewer pair
errors per metre (its errors do not accumulate until the keyframe changes). The keyframe moves to the newest
frame when the flow from it exceeds ``VoChainSettings.max_flow_px`` or too few of its features remain
inliers; with ``max_flow_px = 0`` every frame is a keyframe (paper C's chain). State in, state out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.bounds import Bounded, bounded
from common.estimation.homography import VoError
from common.estimation.rectify import rectify_frame
from common.estimation.vo import (
    MotionModel,
    PreparedFrame,
    RelativeMotion,
    VoPose,
    VoSettings,
    compose_pose,
    estimate_relative_motion,
    median_flow_px,
    metric_translation,
    prepare_frame,
)
from common.types import FloatArray, U8Array


@dataclass(frozen=True)
class VoChainSettings(Bounded):
    """When the keyframe moves on."""

    #: Median flow (px) from the keyframe beyond which the newest frame becomes the keyframe (0: always).
    max_flow_px: float = bounded(0.0, ge=0.0)
    #: ... or when fewer than this share of the keyframe's features are inliers.
    min_inlier_share: float = bounded(0.5, ge=0.0, le=1.0)


@dataclass(frozen=True)
class Keyframe:
    """The frame the chain measures from: prepared, its pose, its altitude (the scale), and the homography
    from it to the newest frame (the next flow's seed)."""

    frame: PreparedFrame
    pose: VoPose
    altitude_m: float
    H_to_latest_px: FloatArray


@dataclass(frozen=True)
class VoChainState:
    """The chain after a frame: its keyframe, the newest frame and its pose and altitude."""

    keyframe: Keyframe
    frame: PreparedFrame
    pose: VoPose
    altitude_m: float


def start_vo_chain(frame: PreparedFrame, pose: VoPose, altitude_m: float) -> VoChainState:
    """A chain whose first keyframe is ``frame`` at ``pose``."""
    return VoChainState(Keyframe(frame, pose, float(altitude_m), np.eye(3)), frame, pose, float(altitude_m))


@dataclass(frozen=True)
class VoStep:
    """One step: the new chain state, the motion from the keyframe it was measured from, the
    displacement since that keyframe of the motion model's pose and of the free decomposition, and the
    pair's median flow (px: how far the motion moves the keyframe's features)."""

    state: VoChainState
    motion: RelativeMotion
    keyframe_frame: PreparedFrame
    keyframe_pose: VoPose
    displacement_m: FloatArray
    displacement_free_m: FloatArray
    flow_px: float


def prepare_view(
    image: U8Array,
    K: FloatArray,
    R_body_camera: FloatArray,
    roll_pitch_rad: tuple[float, float] | None,
    settings: VoSettings,
) -> PreparedFrame:
    """The frame ready for the chain: rectified with ``roll_pitch_rad`` (None: the raw frame).
    Raises :class:`~common.estimation.rectify.RectificationError` when the tilt is too large."""
    if roll_pitch_rad is None:
        return prepare_frame(image, None, settings)
    rect = rectify_frame(
        image, K, roll_pitch_rad[0], roll_pitch_rad[1], R_body_camera, border_px=settings.mask_margin_px
    )
    return prepare_frame(rect.image, rect.valid_mask, settings)


def advance_vo_chain(
    chain: VoChainState,
    frame: PreparedFrame,
    altitude_m: float,
    K: FloatArray,
    settings: VoSettings,
    model: MotionModel,
    chain_settings: VoChainSettings | None = None,
) -> VoStep:
    """Motion from the keyframe to ``frame`` and the composed pose. If the keyframe is not the newest frame
    and its pair fails, the newest frame is tried as the keyframe; raises
    :class:`~common.estimation.vo.VoError` when no pair gives a motion."""
    cs = chain_settings or VoChainSettings()
    kf = chain.keyframe
    for name, h in (
        ("altitude", altitude_m),
        ("keyframe altitude", kf.altitude_m),
        ("last altitude", chain.altitude_m),
    ):
        if not (math.isfinite(h) and h > 0.0):  # a diverged filter: no metric scale, a failed pair
            raise VoError(f"the {name} {h:.4g} m gives no metric scale")
    try:
        motion = estimate_relative_motion(
            kf.frame, frame, K, settings, model=model, guess_H_px=kf.H_to_latest_px
        )
    except VoError:
        if kf.frame is chain.frame:
            raise
        kf = Keyframe(chain.frame, chain.pose, chain.altitude_m, np.eye(3))
        motion = estimate_relative_motion(kf.frame, frame, K, settings, model=model)
    pose = compose_pose(kf.pose, motion.R_k_km1, metric_translation(motion.t_over_d, kf.altitude_m))
    t_free = metric_translation(motion.t_over_d_free, kf.altitude_m)
    displacement_free = -pose.R_n_camera @ t_free
    flow_px = median_flow_px(motion.H_k_km1, kf.frame.features_px)
    moved_on = (
        cs.max_flow_px <= 0.0
        or flow_px > cs.max_flow_px
        or motion.n_inliers < cs.min_inlier_share * max(motion.n_features, 1)
    )
    altitude = float(altitude_m)
    new_kf = (
        Keyframe(frame, pose, altitude, np.eye(3))
        if moved_on
        else Keyframe(kf.frame, kf.pose, kf.altitude_m, motion.H_k_km1)
    )
    return VoStep(
        VoChainState(new_kf, frame, pose, altitude),
        motion,
        kf.frame,
        kf.pose,
        pose.p_n_camera_m - kf.pose.p_n_camera_m,
        displacement_free,
        flow_px,
    )


def with_pose(chain: VoChainState, pose: VoPose) -> VoChainState:
    """The chain with the newest frame's pose replaced (and the keyframe's, if it is the newest frame): for
    a caller that corrects the pose (e.g. blends the translation models)."""
    kf = chain.keyframe
    if kf.frame is chain.frame:
        kf = Keyframe(kf.frame, pose, kf.altitude_m, kf.H_to_latest_px)
    return VoChainState(kf, chain.frame, pose, chain.altitude_m)


def smoothed_vo_altitude(
    keyframe_altitude_m: float,
    t_z_over_d: float,
    filter_altitude_m: float,
    dt_s: float,
    tau_s: float,
    elapsed_s: float = math.inf,
) -> float:
    """The newest frame's altitude for the chain's scale: the keyframe's times the pair's height ratio
    ``1 + t_z`` (level views: ``d_k = d_{k-1} (1 + T_z/d)``), pulled toward the filter's altitude by
    ``dt / tau`` (a complementary filter: the VO's precise ratio from frame to frame, the filter's absolute
    altitude over seconds; the filter's altitude alone jitters with the rangefinder's noise from one frame
    to the next, and each pair's translation is scaled by it). For the first ``tau_s`` of a chain
    (``elapsed_s``: how long it has run) the time constant is the time elapsed, a running mean of the
    filter's altitude, so a start does not carry the first frame's altitude error for ``tau_s``."""
    predicted = keyframe_altitude_m * (1.0 + t_z_over_d)
    if not (math.isfinite(predicted) and predicted > 0.0 and math.isfinite(dt_s) and dt_s > 0.0):
        return float(filter_altitude_m)
    tau = min(tau_s, elapsed_s) if elapsed_s >= dt_s else dt_s
    pull = min(1.0, dt_s / tau)
    return float(predicted + pull * (filter_altitude_m - predicted))


def with_altitude(chain: VoChainState, altitude_m: float) -> VoChainState:
    """The chain with the newest frame's altitude (the scale of the next pair when it is the keyframe)
    replaced."""
    kf = chain.keyframe
    if kf.frame is chain.frame:
        kf = Keyframe(kf.frame, kf.pose, float(altitude_m), kf.H_to_latest_px)
    return VoChainState(kf, chain.frame, chain.pose, float(altitude_m))


def shifted(chain: VoChainState, offset_m: FloatArray) -> VoChainState:
    """The chain moved by ``offset_m`` (3,) in the navigation frame (keyframe and newest frame alike)."""
    o = np.asarray(offset_m, dtype=np.float64).reshape(3)
    kf = chain.keyframe
    kf_pose = VoPose(kf.pose.R_n_camera, kf.pose.p_n_camera_m + o)
    pose = VoPose(chain.pose.R_n_camera, chain.pose.p_n_camera_m + o)
    return VoChainState(
        Keyframe(kf.frame, kf_pose, kf.altitude_m, kf.H_to_latest_px), chain.frame, pose, chain.altitude_m
    )
