"""Accuracy metrics against ground truth: yaw errors (paper A's eq. 8 and plain statistics) and trajectory
errors (evo's APE and RPE, translation part)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import wrap_angle_rad
from common.types import FloatArray


def check_angle_series(values: npt.ArrayLike, name: str) -> FloatArray:
    """A finite 1-D float series (M,), M >= 1, else InputError."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1 or arr.size == 0:
        raise InputError(f"{name} must have shape (M,) with M >= 1, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite")
    return arr


def yaw_error_rad(estimated_yaw_rad: npt.ArrayLike, true_yaw_rad: npt.ArrayLike) -> FloatArray:
    """Per-frame yaw error psi_e = wrap(estimated - true) (M,), radians."""
    est = check_angle_series(estimated_yaw_rad, "estimated_yaw_rad")
    true = check_angle_series(true_yaw_rad, "true_yaw_rad")
    if est.shape != true.shape:
        raise InputError(f"estimated and true yaw must have the same shape, got {est.shape} and {true.shape}")
    return wrap_angle_rad(est - true)


def accumulated_mean_error(error: npt.ArrayLike, window: int = 100) -> FloatArray:
    """Accumulated mean error over windows of N frames, paper A eq. 8.

    ``eps_N^k = 1/N * sum_{i=k}^{k+N} |psi_e^i - psi_e^k|`` for k = 1..M-N (as printed: N + 1 terms
    divided by N), where psi_e is the per-frame error. Returns (M - N,), in the unit of ``error``.
    """
    e = check_angle_series(error, "error")
    if window < 1:
        raise InputError(f"window must be >= 1, got {window}")
    if e.size <= window:
        raise InputError(f"need more than N = {window} errors, got {e.size}")
    windows = np.lib.stride_tricks.sliding_window_view(e, window + 1)  # (M - N, N + 1), row k = e[k..k+N]
    return np.asarray(np.abs(windows - windows[:, :1]).sum(axis=1) / window, dtype=np.float64)


@dataclass(frozen=True)
class YawErrorStats:
    """Plain statistics of a yaw error series, degrees; ``max_ame_deg`` is max of eq. 8 (nan if too short)."""

    frames: int
    mean_deg: float
    rms_deg: float
    median_abs_deg: float
    max_abs_deg: float
    final_deg: float
    max_ame_deg: float
    ame_window: int


def yaw_error_stats(
    estimated_yaw_rad: npt.ArrayLike, true_yaw_rad: npt.ArrayLike, ame_window: int = 100
) -> YawErrorStats:
    """Statistics of wrap(estimated - true), both series already expressed from the same origin."""
    error_deg = np.degrees(yaw_error_rad(estimated_yaw_rad, true_yaw_rad))
    ame = accumulated_mean_error(error_deg, ame_window) if error_deg.size > ame_window else None
    return YawErrorStats(
        frames=int(error_deg.size),
        mean_deg=float(np.mean(error_deg)),
        rms_deg=float(np.sqrt(np.mean(error_deg**2))),
        median_abs_deg=float(np.median(np.abs(error_deg))),
        max_abs_deg=float(np.max(np.abs(error_deg))),
        final_deg=float(error_deg[-1]),
        max_ame_deg=float(np.max(ame)) if ame is not None else math.nan,
        ame_window=ame_window,
    )


# --------------------------------------------------------------------------------------------------
# Trajectory metrics (evo's APE and RPE, translation part).
# --------------------------------------------------------------------------------------------------


def check_positions(positions_m: npt.ArrayLike, name: str) -> FloatArray:
    """A finite ``(N, D)`` position series, D in 2..3, N >= 1, else InputError."""
    arr = np.asarray(positions_m, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] not in (2, 3):
        raise InputError(f"{name} must have shape (N, 2) or (N, 3) with N >= 1, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite")
    return arr


def _paired(estimated_m: npt.ArrayLike, reference_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    est = check_positions(estimated_m, "estimated_m")
    ref = check_positions(reference_m, "reference_m")
    if est.shape != ref.shape:
        raise InputError(f"estimated and reference positions differ in shape: {est.shape} vs {ref.shape}")
    return est, ref


def ate_rmse_m(estimated_m: npt.ArrayLike, reference_m: npt.ArrayLike) -> float:
    """Absolute trajectory error, RMSE of ``|p_est_i - p_ref_i|`` over the synchronised samples (m).

    This is evo's APE translation part (``evo_ape --pose_relation trans_part``) with evo's default of
    **no alignment**: the estimator already expresses its positions in the reference's world frame (its
    origin and initial yaw are given), so an alignment would hide the drift being measured.
    """
    est, ref = _paired(estimated_m, reference_m)
    return float(np.sqrt(np.mean(np.sum((est - ref) ** 2, axis=1))))


def path_pairs_by_distance(path_m: npt.ArrayLike, delta_m: float) -> list[tuple[int, int]]:
    """Consecutive index pairs ``(i, j)`` whose travelled path between them first reaches ``delta_m``:
    evo's ``filter_pairs_by_path`` (consecutive mode), on the reference path."""
    path = check_positions(path_m, "path_m")
    if not (math.isfinite(delta_m) and delta_m > 0.0):
        raise InputError(f"delta_m must be a positive finite distance, got {delta_m}")
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1).tolist()
    ids = [0]
    travelled = 0.0
    for i, step in enumerate(steps, start=1):
        travelled += step
        if travelled >= delta_m:
            ids.append(i)
            travelled = 0.0
    return list(itertools.pairwise(ids))


@dataclass(frozen=True)
class RelativeError:
    """Relative position error over pairs ``delta_m`` of path apart (evo's RPE, translation part)."""

    delta_m: float
    pairs: int
    mean_m: float
    rmse_m: float
    max_m: float

    @property
    def mean_pct(self) -> float:
        """Mean error per pair in percent of the distance travelled (nan without pairs)."""
        return 100.0 * self.mean_m / self.delta_m if self.pairs else math.nan


def rpe_translation(
    estimated_m: npt.ArrayLike,
    reference_m: npt.ArrayLike,
    delta_m: float = 1.0,
    reference_path_m: npt.ArrayLike | None = None,
) -> RelativeError:
    """Relative position error per ``delta_m`` travelled: for evo's consecutive pairs ``(i, j)`` (chosen on
    ``reference_path_m``, default the reference), ``|(p_est_j - p_est_i) - (p_ref_j - p_ref_i)|``.

    That is evo's RPE translation part (``evo_rpe --delta 1 --delta_unit m --pairs_from_reference``: the
    pairs follow the true path, not the estimate's) on position-only trajectories
    (identity orientations): the drift of the displacement in the world frame over each ``delta_m`` of path,
    which is what paper C's "error in % of the path" expresses; the heading error's lever arm, which evo's
    SE(3) RPE would add, is reported separately (yaw error). ``reference_path_m`` lets the pairs follow the
    full 3-D path when the error is taken on the horizontal position only.
    """
    est, ref, pairs = _rpe_pairs(estimated_m, reference_m, delta_m, reference_path_m)
    if not pairs:
        return RelativeError(float(delta_m), 0, math.nan, math.nan, math.nan)
    i, j = np.array(pairs).T
    err = np.linalg.norm((est[j] - est[i]) - (ref[j] - ref[i]), axis=1)
    return RelativeError(
        delta_m=float(delta_m),
        pairs=len(pairs),
        mean_m=float(np.mean(err)),
        rmse_m=float(np.sqrt(np.mean(err**2))),
        max_m=float(np.max(err)),
    )


def _rpe_pairs(
    estimated_m: npt.ArrayLike,
    reference_m: npt.ArrayLike,
    delta_m: float,
    reference_path_m: npt.ArrayLike | None,
) -> tuple[FloatArray, FloatArray, list[tuple[int, int]]]:
    """Checked positions and evo's consecutive pairs ``delta_m`` apart on the reference path."""
    est, ref = _paired(estimated_m, reference_m)
    path = ref if reference_path_m is None else check_positions(reference_path_m, "reference_path_m")
    if path.shape[0] != ref.shape[0]:
        raise InputError(f"reference_path_m must have {ref.shape[0]} samples, got {path.shape[0]}")
    return est, ref, path_pairs_by_distance(path, delta_m)


@dataclass(frozen=True)
class TrackSplit:
    """The RPE pairs' horizontal displacement errors split along the true displacement (a scale error:
    positive when the estimate travelled too far) and across it (a heading error: positive to the left,
    counter-clockwise); signed means and RMS, in metres per pair (nan without pairs)."""

    delta_m: float
    pairs: int
    along_mean_m: float
    along_rmse_m: float
    cross_mean_m: float
    cross_rmse_m: float

    @property
    def along_rmse_pct(self) -> float:
        return 100.0 * self.along_rmse_m / self.delta_m

    @property
    def cross_rmse_pct(self) -> float:
        return 100.0 * self.cross_rmse_m / self.delta_m


def rpe_along_cross(
    estimated_m: npt.ArrayLike,
    reference_m: npt.ArrayLike,
    delta_m: float = 1.0,
    reference_path_m: npt.ArrayLike | None = None,
) -> TrackSplit:
    """:func:`rpe_translation`'s pair errors on x, y split into the component along the true horizontal
    displacement of the pair and the one across it (``along^2 + cross^2`` is the squared horizontal pair
    error): whether a VO's relative error is a scale error (altitude, the metric scale) or a heading error
    (yaw drift). Pairs without horizontal displacement are left out."""
    est, ref, pairs = _rpe_pairs(estimated_m, reference_m, delta_m, reference_path_m)
    i, j = np.array(pairs, dtype=np.intp).reshape(-1, 2).T
    err = ((est[j] - est[i]) - (ref[j] - ref[i]))[:, :2]
    seg = (ref[j] - ref[i])[:, :2]
    length = np.linalg.norm(seg, axis=1)
    keep = length > 1e-9
    if not np.any(keep):
        return TrackSplit(float(delta_m), 0, math.nan, math.nan, math.nan, math.nan)
    u = seg[keep] / length[keep, None]
    along = np.sum(err[keep] * u, axis=1)
    cross = u[:, 0] * err[keep, 1] - u[:, 1] * err[keep, 0]
    return TrackSplit(
        delta_m=float(delta_m),
        pairs=int(along.size),
        along_mean_m=float(np.mean(along)),
        along_rmse_m=float(np.sqrt(np.mean(along**2))),
        cross_mean_m=float(np.mean(cross)),
        cross_rmse_m=float(np.sqrt(np.mean(cross**2))),
    )


def _associate_exact(
    est_stamps_s: FloatArray, ref_stamps_s: FloatArray, tol_s: float
) -> npt.NDArray[np.intp]:
    """Index into ``ref`` of each estimate stamp (equal within ``tol_s``), else InputError."""
    ref = np.asarray(ref_stamps_s, dtype=np.float64)
    if est_stamps_s.size == 0:
        raise InputError("APE of an empty trajectory")
    order = np.argsort(ref)
    pos = np.clip(np.searchsorted(ref[order], est_stamps_s), 1, max(ref.size - 1, 1))
    left, right = order[pos - 1], order[np.minimum(pos, ref.size - 1)]
    nearest = np.where(np.abs(ref[left] - est_stamps_s) <= np.abs(ref[right] - est_stamps_s), left, right)
    if ref.size == 0 or np.any(np.abs(ref[nearest] - est_stamps_s) > tol_s):
        raise InputError(f"every estimate needs a ground-truth pose at its stamp (within {tol_s} s)")
    return nearest


def ape_translation_rmse_m(
    est_stamps_s: npt.ArrayLike, est_p_m: npt.ArrayLike, ref_stamps_s: npt.ArrayLike, ref_p_m: npt.ArrayLike,
    tol_s: float = 1e-6,
) -> float:  # fmt: skip
    """Absolute pose error, translation part, RMSE (metres), without alignment: evo's ``evo_ape tum REF
    EST`` (``-r trans_part``). Poses are associated by equal stamps."""
    stamps = np.asarray(est_stamps_s, dtype=np.float64)
    idx = _associate_exact(stamps, np.asarray(ref_stamps_s, dtype=np.float64), tol_s)
    err = np.linalg.norm(np.asarray(est_p_m, dtype=np.float64) - np.asarray(ref_p_m)[idx], axis=1)
    return float(np.sqrt(np.mean(err**2)))


def ape_rotation_rmse_deg(
    est_stamps_s: npt.ArrayLike, est_q: npt.ArrayLike, ref_stamps_s: npt.ArrayLike, ref_q: npt.ArrayLike,
    tol_s: float = 1e-6,
) -> float:  # fmt: skip
    """Absolute pose error, rotation angle, RMSE (degrees; evo's ``-r angle_deg``): the angle of
    ``R_ref^T R_est`` per pose. Quaternions scalar first; associated by equal stamps."""
    stamps = np.asarray(est_stamps_s, dtype=np.float64)
    idx = _associate_exact(stamps, np.asarray(ref_stamps_s, dtype=np.float64), tol_s)
    q_est = np.asarray(est_q, dtype=np.float64)
    q_ref = np.asarray(ref_q, dtype=np.float64)[idx]
    q_est = q_est / np.linalg.norm(q_est, axis=1, keepdims=True)
    q_ref = q_ref / np.linalg.norm(q_ref, axis=1, keepdims=True)
    # relative rotation conj(q_ref) * q_est: w = q_ref . q_est, v = w_r v_e - w_e v_r - v_r x v_e;
    # the angle from atan2 keeps full precision for small errors (arccos of w does not)
    w = np.sum(q_ref * q_est, axis=1)
    v = q_ref[:, :1] * q_est[:, 1:] - q_est[:, :1] * q_ref[:, 1:] - np.cross(q_ref[:, 1:], q_est[:, 1:])
    angle_deg = np.degrees(2.0 * np.arctan2(np.linalg.norm(v, axis=1), np.abs(w)))
    return float(np.sqrt(np.mean(angle_deg**2)))
