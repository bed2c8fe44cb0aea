"""Homography-based visual odometry of a downward camera, paper C section II-B (Algorithms 1-2, eqs. 9-10).

Per pair of frames (k-1, k): Shi-Tomasi features on k-1, pyramidal Lucas-Kanade to k with a
forward-backward check, a RANSAC homography, its decomposition (``cv2.decomposeHomographyMat``, Malis &
Vargas) keeping the physically valid solution (all points in front of both views, plane normal closest to
the expected ground normal), the metric translation from the altitude, and the composition of eqs. 9-10.

Frame convention of a decomposition: ``X_k = R_k_km1 X_km1 + t``, ``t = T/d * d`` with ``d`` the distance of
camera k-1 to the ground plane and ``n`` the plane normal in camera k-1 (pointing from the camera to the
ground, ``n^T X = d`` on the plane). ``t`` is then the position of camera k-1 seen from camera k, the
paper's ``t_{k,k-1}^k``.

Frames are prepared once (:func:`prepare_frame`: features and mask): each prepared frame is "k" for one
pair and "k-1" for the next. (OpenCV 5's Python binding no longer accepts prebuilt LK pyramids.)
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from common.bounds import Bounded, bounded
from common.errors import InputError
from common.estimation.homography import (
    VoError,
    calibrated_homography,
    choose_decomposition,
    decompose_with_known_normal,
    level_motion_from_matches,
    rotation_about_optical_axis,
)
from common.images import check_grey_image
from common.types import FloatArray, U8Array


class MotionModel(enum.Enum):
    """How a pair's homography is turned into a motion."""

    #: ``cv2.decomposeHomographyMat``, physically valid solution (any pair; the paper's traditional VO).
    FREE = "free"
    #: The plane normal is known (``expected_normal``; the optical axis for rectified pairs): R from the
    #: homography's plane directions, ``T/d`` linear (:func:`decompose_with_known_normal`). The free
    #: decomposition is ill-conditioned when the translation is along the normal (climbs and descents).
    KNOWN_NORMAL = "known_normal"
    #: Both views level (rectified): rotation about the optical axis and ``n = e3``, least squares on the
    #: homography's inliers (no tilt/translation ambiguity left).
    LEVEL = "level"
    #: :attr:`LEVEL`'s similarity for the translation, the rotation about the optical axis of the free
    #: decomposition for the yaw. A residual tilt ``d`` of the rectified views (the EKF's tilt error)
    #: shears the flow by ``|t|/h * d`` and biases the similarity's rotation by half of it on every pair
    #: (a yaw drift that builds up); the free decomposition models the plane normal and has no such bias.
    LEVEL_FREE_YAW = "level_free_yaw"


@dataclass(frozen=True)
class VoSettings(Bounded):
    """Feature, flow and homography parameters (pixels unless named otherwise)."""

    #: 400 instead of 200: the pairs' rotation and scale rest on twice the corners, spread wider. The
    #: truth-attitude chain (paper C's flight, seed 3) went from RPE 0.299 to 0.094 %/m and yaw RMSE 0.219
    #: to 0.069 deg (seed 15: 0.534 -> 0.405 %/m, final 1.09 -> 0.64 cm); the VO step costs about 1.2x
    #: (thread time, shared host; ``capataz bench estimator`` times both).
    max_features: int = bounded(400, ge=8)
    quality_level: float = bounded(0.01, gt=0.0)
    min_distance_px: float = bounded(15.0, gt=0.0)
    block_size_px: int = 7
    #: Lucas-Kanade window (px). 11 instead of 15: VO step -21 % (paper C seed 0) to -29 % (agile seed 1) in
    #: thread time, truth-attitude chain RPE per metre 0.260 vs 0.236 % (paper C, 500 frames) and 0.028
    #: vs 0.030 % (agile, 500 frames), measured on the same shared host in one run.
    lk_window_px: int = bounded(11, ge=5)
    lk_levels: int = bounded(2, ge=0)
    lk_iterations: int = 20
    lk_epsilon_px: float = 0.01
    #: Forward-backward check: a track is kept if tracking back lands within this of its start.
    fb_max_error_px: float = bounded(0.3, gt=0.0)
    #: Pyramid levels of the backward pass. It starts at the feature's own position, where a track worth
    #: keeping must land within ``fb_max_error_px``: the full-resolution level alone tells (a track whose
    #: way back needs the pyramid is off anyway). 0 instead of ``lk_levels``: VO step 6.15 -> 5.12 ms
    #: (thread time, 400 corners, paper C frames 400-460, medians of 6 interleaved passes, shared host).
    fb_lk_levels: int = bounded(0, ge=0)
    ransac_threshold_px: float = bounded(1.0, gt=0.0)
    min_inliers: int = bounded(12, ge=4)
    #: Gaussian pre-smoothing (sigma, px) of each frame before features and flow; it reduces the
    #: "pixel locking" bias of Lucas-Kanade's interpolation on sub-pixel motions (0 = none).
    presmooth_sigma_px: float = 0.0
    #: Detect the Shi-Tomasi features on the image downsampled by 2**detect_level (0: full resolution);
    #: level 1 costs a quarter and the flow still tracks them at full resolution.
    detect_level: int = 1
    #: Features closer than this to a mask edge (or the image edge) are not used.
    mask_margin_px: int = 8

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.lk_window_px % 2 == 0:
            raise InputError(f"VoSettings.lk_window_px must be odd and >= 5, got {self.lk_window_px}")


@dataclass(frozen=True)
class PreparedFrame:
    """A frame ready for the pair step: its Shi-Tomasi features and (eroded) valid mask."""

    image: U8Array
    features_px: npt.NDArray[np.float32]
    inner_mask: U8Array | None


@dataclass(frozen=True)
class RelativeMotion:
    """Motion between frames k-1 and k from one homography (Algorithm 2)."""

    R_k_km1: FloatArray
    t_over_d: FloatArray
    #: ``T/d`` of the free decomposition (equal to ``t_over_d`` for :attr:`MotionModel.FREE`).
    t_over_d_free: FloatArray
    normal_km1: FloatArray
    #: Plane normal of the free decomposition (in camera k-1; equal to ``normal_km1`` for FREE).
    normal_km1_free: FloatArray
    H_k_km1: FloatArray
    n_features: int
    n_tracked: int
    n_inliers: int


@dataclass(frozen=True)
class VoPose:
    """Pose of the (possibly rectified) camera in the navigation frame n (= world, ENU)."""

    R_n_camera: FloatArray
    p_n_camera_m: FloatArray


def _inner_mask(mask: U8Array | None, shape: tuple[int, int], margin_px: int) -> U8Array:
    """The mask (or the whole image) eroded by ``margin_px``."""
    full = np.full(shape, 255, dtype=np.uint8) if mask is None else np.asarray(mask, dtype=np.uint8)
    if full.shape != shape:
        raise InputError(f"mask must have the image shape {shape}, got {full.shape}")
    if margin_px <= 0:
        return full
    if mask is None:
        out = np.zeros(shape, dtype=np.uint8)
        out[margin_px:-margin_px, margin_px:-margin_px] = 255
        return out
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * margin_px + 1, 2 * margin_px + 1))
    eroded = cv2.erode(full, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return np.asarray(eroded, dtype=np.uint8)


def prepare_frame(image: npt.ArrayLike, mask: npt.ArrayLike | None, settings: VoSettings) -> PreparedFrame:
    """Shi-Tomasi features (inside ``mask`` shrunk by the margin)."""
    img = check_grey_image(image, "image", min_side_px=8)
    if settings.presmooth_sigma_px > 0.0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), settings.presmooth_sigma_px), dtype=np.uint8)
    inner = _inner_mask(None if mask is None else np.asarray(mask), img.shape, settings.mask_margin_px)
    detect_img, detect_mask = img, inner
    for _ in range(settings.detect_level):
        detect_img = np.asarray(cv2.pyrDown(detect_img), dtype=np.uint8)
        detect_mask = np.asarray(detect_mask[::2, ::2], dtype=np.uint8)[
            : detect_img.shape[0], : detect_img.shape[1]
        ]
    scale = float(2**settings.detect_level)
    corners = cv2.goodFeaturesToTrack(
        detect_img,
        maxCorners=settings.max_features,
        qualityLevel=settings.quality_level,
        minDistance=settings.min_distance_px / scale,
        mask=detect_mask,
        blockSize=settings.block_size_px,
    )
    if corners is not None and scale != 1.0:
        # pyrDown's 5-tap kernel is centred: level pixel i is full-resolution pixel 2i (not 2i + 0.5)
        corners = corners * scale
    features = (
        np.zeros((0, 1, 2), dtype=np.float32) if corners is None else np.asarray(corners, dtype=np.float32)
    )
    return PreparedFrame(image=img, features_px=features, inner_mask=inner)


def track_features(
    prev: PreparedFrame, curr: PreparedFrame, settings: VoSettings, guess_H_px: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Pyramidal LK from k-1 to k and back; keeps tracks whose round trip closes within ``fb_max_error_px``
    and that land inside frame k's (eroded) valid mask. Returns matched ``(N, 2)`` pixel arrays.

    ``guess_H_px`` (a homography k-1 -> k, e.g. the last one of a keyframe) starts the flow at the
    features' predicted positions: large displacements from a keyframe stay within LK's reach."""
    pts0 = prev.features_px
    if len(pts0) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    flags = 0
    guess = None
    if guess_H_px is not None:
        guess = np.asarray(cv2.perspectiveTransform(pts0, np.asarray(guess_H_px, dtype=np.float64)))
        guess = guess.astype(np.float32)
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    window = (settings.lk_window_px, settings.lk_window_px)
    criteria = (
        cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
        settings.lk_iterations,
        settings.lk_epsilon_px,
    )
    pts1, st1, _ = cv2.calcOpticalFlowPyrLK(
        prev.image, curr.image, pts0, guess,  # type: ignore[arg-type]
        winSize=window, maxLevel=settings.lk_levels, criteria=criteria, flags=flags,
    )  # fmt: skip
    back, st2, _ = cv2.calcOpticalFlowPyrLK(
        curr.image, prev.image, pts1, pts0.copy(),
        winSize=window, maxLevel=settings.fb_lk_levels, criteria=criteria,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )  # fmt: skip
    p0 = pts0.reshape(-1, 2).astype(np.float64)
    p1 = pts1.reshape(-1, 2).astype(np.float64)
    fb = np.linalg.norm(back.reshape(-1, 2) - p0, axis=1)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb < settings.fb_max_error_px)
    h_px, w_px = curr.image.shape
    xi = np.round(p1[:, 0]).astype(np.int64)
    yi = np.round(p1[:, 1]).astype(np.int64)
    inside = (xi >= 0) & (xi < w_px) & (yi >= 0) & (yi < h_px)
    ok &= inside
    if curr.inner_mask is not None:
        ok[ok] &= curr.inner_mask[yi[ok], xi[ok]] > 0
    return p0[ok], p1[ok]


#: How far :func:`track_features` over-reads a sub-pixel shift, as a share of the shift, by its size (px):
#: the tracker's reading over the true shift, minus 1, on the simulator's noise-free renders of paper C's
#: ground at 3.8 m (``capataz bench flow``, its ``rendered`` rows). A bilinear Lucas-Kanade reads fine
#: detail's sub-pixel motion long (``docs/methods.md``); from about half a pixel it reads true.
SUBPIXEL_FLOW_PX = (0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 1.0)
SUBPIXEL_OVER_READ = (0.136, 0.124, 0.106, 0.076, 0.050, 0.012, 0.0)


def subpixel_over_read(flow_px: float) -> float:
    """The share of a pair's motion the tracker over-reads at a median flow of ``flow_px`` (interpolated in
    :data:`SUBPIXEL_OVER_READ`; below its first shift its first share, from 1 px on 0); 0 for a flow that is
    not known (not finite)."""
    if not math.isfinite(flow_px):
        return 0.0
    return float(np.interp(max(flow_px, 0.0), SUBPIXEL_FLOW_PX, SUBPIXEL_OVER_READ, right=0.0))


def median_flow_px(H_px: FloatArray, features_px: npt.NDArray[np.float32]) -> float:
    """The median distance (px) the homography ``H_px`` moves ``features_px`` (0 without features)."""
    pts = features_px.reshape(-1, 2).astype(np.float64)
    if len(pts) == 0:
        return 0.0
    mapped = np.c_[pts, np.ones(len(pts))] @ np.asarray(H_px, dtype=np.float64).T
    return float(np.median(np.linalg.norm(mapped[:, :2] / mapped[:, 2:3] - pts, axis=1)))


def estimate_relative_motion(
    prev: PreparedFrame,
    curr: PreparedFrame,
    K: npt.ArrayLike,
    settings: VoSettings,
    expected_normal: npt.ArrayLike = (0.0, 0.0, 1.0),
    model: MotionModel = MotionModel.FREE,
    guess_H_px: FloatArray | None = None,
) -> RelativeMotion:
    """Rotation, ``T/d`` and plane normal between frames k-1 and k (paper C Algorithm 2).

    ``model`` selects the free decomposition (any pair) or the level ones (rectified pairs);
    ``guess_H_px`` seeds the flow (:func:`track_features`).
    """
    Km = np.asarray(K, dtype=np.float64)
    p0, p1 = track_features(prev, curr, settings, guess_H_px)
    if len(p0) < settings.min_inliers:
        raise VoError(f"only {len(p0)} tracks survived (need {settings.min_inliers})")
    H, inliers = cv2.findHomography(p0, p1, cv2.RANSAC, settings.ransac_threshold_px)
    if H is None or inliers is None:
        raise VoError("homography estimation failed")
    keep = inliers.ravel().astype(bool)
    n_inliers = int(keep.sum())
    if n_inliers < settings.min_inliers:
        raise VoError(f"only {n_inliers} homography inliers (need {settings.min_inliers})")
    # least-squares refinement on the inliers only
    H_ls, _ = cv2.findHomography(p0[keep], p1[keep], 0)
    if H_ls is not None and np.all(np.isfinite(H_ls)):
        H = H_ls
    normal_ref = np.asarray(expected_normal, dtype=np.float64).reshape(3)
    normal_ref = normal_ref / np.linalg.norm(normal_ref)
    n_solutions, rotations, translations, normals = cv2.decomposeHomographyMat(H, Km)
    if n_solutions == 1:
        # OpenCV reports a pure rotation when |H^T H - I| < 1e-3, i.e. for translations below about
        # 0.05 % of the altitude (2 mm per frame at 4 m); keep them with the expected normal.
        R, t_over_d = decompose_with_known_normal(calibrated_homography(H, Km), normal_ref)
        normal = normal_ref
    else:
        best = choose_decomposition(rotations, translations, normals, Km, p0[keep], p1[keep], normal_ref)
        R = np.asarray(rotations[best], dtype=np.float64)
        t_over_d = np.asarray(translations[best], dtype=np.float64).reshape(3)
        normal = np.asarray(normals[best], dtype=np.float64).reshape(3)
    t_over_d_free = t_over_d
    normal_free = normal
    if model is MotionModel.KNOWN_NORMAL:
        R, t_over_d = decompose_with_known_normal(calibrated_homography(H, Km), normal_ref)
        normal = normal_ref
    elif model in (MotionModel.LEVEL, MotionModel.LEVEL_FREE_YAW):
        R_level_fit, t_over_d = level_motion_from_matches(p0[keep], p1[keep], Km)
        R = R_level_fit if model is MotionModel.LEVEL else rotation_about_optical_axis(R)
        normal = np.array([0.0, 0.0, 1.0])
    return RelativeMotion(
        R_k_km1=R,
        t_over_d=t_over_d,
        t_over_d_free=t_over_d_free,
        normal_km1=normal,
        normal_km1_free=normal_free,
        H_k_km1=np.asarray(H / H[2, 2], dtype=np.float64),
        n_features=len(prev.features_px),
        n_tracked=len(p0),
        n_inliers=n_inliers,
    )


def metric_translation(t_over_d: npt.ArrayLike, distance_m: float) -> FloatArray:
    """``t_{k,k-1}^k = T/d * h``: the metric translation from the plane distance (paper C Algorithm 1).

    ``cv2.decomposeHomographyMat`` already works in normalised coordinates (the ``P^-1`` of the paper).
    """
    if not (math.isfinite(distance_m) and distance_m > 0.0):
        raise InputError(f"distance_m must be finite and > 0, got {distance_m}")
    return np.asarray(t_over_d, dtype=np.float64).reshape(3) * float(distance_m)


def compose_pose(pose_km1: VoPose, R_k_km1: npt.ArrayLike, t_k_km1_m: npt.ArrayLike) -> VoPose:
    """Visual-odometry composition, paper C eqs. 9-10:
    ``R_k^n = R_{k-1}^n (R_{k-1}^k)^T`` and ``t_{n,k}^n = t_{n,k-1}^n - R_k^n t_{k,k-1}^k``."""
    R_n_k = pose_km1.R_n_camera @ np.asarray(R_k_km1, dtype=np.float64).T
    p_n_k = pose_km1.p_n_camera_m - R_n_k @ np.asarray(t_k_km1_m, dtype=np.float64).reshape(3)
    return VoPose(R_n_camera=R_n_k, p_n_camera_m=p_n_k)
