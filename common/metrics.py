"""Accuracy metrics of estimated angles against ground truth (paper A's eq. 8 and plain statistics)."""

from __future__ import annotations

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
