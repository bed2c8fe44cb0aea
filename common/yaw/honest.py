"""The honest yaw: which delta is integrated, how it was obtained, and how uncertain the yaw has become.

A delta the core does not trust is never integrated as if measured. Each pair has a *prior*:

- ``GYRO``: the gyro's integrated rotation about the camera axis between the two frame stamps
  (:func:`gyro_delta_yaw_rad`); trusted to ``gyro_gate_deg``.
- ``HOLD``: no gyro; the recent yaw rate (a robust rate of the measured pairs of the last few tenths of a
  second, :mod:`common.yaw.held`) held over the frame interval, trusted to what the physical yaw
  acceleration limit allows since that rate applied (``max_yaw_accel_deg_s2``); uninformative before the
  first measurement.

A measured delta is integrated (``Provenance.MEASURED``) only when the patch fit is good, it lies within the
prior's tolerance and it implies a yaw rate within ``max_yaw_rate_deg_s``; otherwise the prior's delta is
integrated instead (``BRIDGED`` by the gyro, ``HELD`` without), and the yaw's variance grows accordingly.
The yaw's variance is not the plain sum of its pairs' variances (:mod:`common.yaw.yaw_variance`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import wrap_angle_rad
from common.provenance import Provenance
from common.yaw.held import HeldRate
from common.yaw.settings import YawSettings

__all__ = ["Prior", "PriorSource", "Provenance", "gyro_delta_yaw_rad", "make_prior"]

#: The held rate's tolerance never drops below this (deg): measurement noise and rate estimation noise.
MIN_HOLD_TOLERANCE_DEG = 5.0
#: Variance of a held pair's delta (:func:`held_variance_terms`): a multiple of the window's scatter of rates
#: squared, a yaw acceleration (deg/s^2, 1 sigma) over the time since the held rate applied, and a rate floor
#: (deg/s, 1 sigma). The gate keeps its tolerance (above); this is what the pair is published with. Before it
#: the variance was the tolerance's third squared, at least (5/3 deg)^2: 16 times the errors' std (mean NEES
#: 0.004). Fitted (Gaussian maximum likelihood) on the held pairs of the field suite's seeds 0-9 without a
#: gyro, 8 % of the frames washed out (1,494 pairs; ``bench consistency --fit-yaw-held --seeds 20
#: --field-frames 100``); the floor fits to 0.
HELD_SPREAD_SHARE = 10.78
HELD_ACCEL_DEG_S2 = 12.38
HELD_RATE_DEG_S = 0.0
#: Variance of a measured pair's delta, per patch: ``RESIDUAL_SHARE * (residual / lever)^2 * 2`` (residual at
#: least ``MIN_RESIDUAL_PX``), plus ``WARPED_FLOOR_DEG^2`` when the patches were measured on frame k warped
#: back (refined or pre-aligned: the warp's interpolation), plus ``(SHIFT_SHARE * shift / focal)^2`` for the
#: angle the view moved, the image's shift at the rotation centre over the focal length (the residual does not
#: see what a translation of the view turns into rotation: perspective, parallax, blur along the motion), plus
#: ``(AMBIGUITY_DEG / ratio)^2`` with ``ratio`` the median over the valid patches of their correlation's first
#: peak over its second (a periodic floor, blur or weak texture raise the second peak, and a patch's sub-pixel
#: shift is pulled towards it; the residual does not see it when every patch is pulled alike). The pair's
#: variance is that over the inliers (their average), times the measured patches over the inliers (how hard
#: the pair was: the patches that did not agree failed for blur, weak texture or parallax, which the inliers
#: share in part). Fitted (Gaussian maximum likelihood) on the field suite's measured pairs of seeds 0-9 over
#: the suite's whole 600-frame flights (59,000 pairs; a 100-frame flight is a shorter, calmer trajectory, and
#: constants fitted there published the whole flights' pairs with a mean NEES of 1.34). Held out (seeds
#: 10-19), the model before (the residual's term alone averaged over the inliers, no peak ratio) published the
#: pairs with fewer inliers and the periodic or blurred floors overconfident: mean NEES 4.98 below 20 inliers
#: of 40, 1.57 at 20-29, 0.88 at 36-40 (now 0.90, 0.94, 1.13), and by scenario from 0.67 (fast yaw) to 1.61
#: (field nuisances), now 0.89 to 1.31 (docs/methods.md). ``bench consistency --fit-yaw --seeds 20`` refits
#: them; ``bench consistency`` reports held-out seeds.
MIN_RESIDUAL_PX = 0.1
RESIDUAL_SHARE = 0.0366
WARPED_FLOOR_DEG = 0.1207
SHIFT_SHARE = 0.0935
AMBIGUITY_DEG = 0.602
#: A pair measured on the raw frames (not refined: it turned less than ``refine_min_deg``) adds
#: ``(UNREFINED_PULL * turn)^2``, once for the pair: the window pulls every patch's shift towards zero alike
#: (the refinement's reason), so the turn reads short by a share the residual does not see, which depends on
#: the lens and the texture. Regressed on the true turn over such pairs (300-frame field and checkerboard
#: flights, seed 0): 2-6 % on the suite's 120 deg lens, 2-8 % on a 90 deg pinhole, 12-13 % on an equidistant
#: fisheye of 120 deg (without this term its pairs had a mean NEES of 2.6, 0.83 within 2 sigma). The smallest
#: value that puts each of those three lenses' flights at 0.90 or more within 2 sigma (maximum likelihood over
#: their pooled pairs gives 0.0975 and leaves the fisheye's field flight at 0.896; the fisheye alone fits
#: 0.18-0.20); held out on seed 1 and two lenses it was not chosen on: docs/methods.md, "Lenses".
UNREFINED_PULL = 0.11


class PriorSource(Enum):
    GYRO = "gyro"
    HOLD = "hold"


@dataclass(frozen=True)
class Prior:
    """Expected delta of a pair, how far a measurement may differ, and the variance the bridge would add."""

    source: PriorSource
    delta_rad: float
    tolerance_rad: float
    variance_rad2: float
    dt_s: float | None  # None: the frames carry no stamps (no rate limit)

    @property
    def informative(self) -> bool:
        """The prior can pick among rotations 90 deg apart."""
        return self.tolerance_rad < math.radians(40.0)


def gyro_delta_yaw_rad(
    stamps_s: npt.ArrayLike,
    gyro_rad_s: npt.ArrayLike,
    start_s: float,
    stop_s: float,
    axis_body: npt.ArrayLike = (0.0, 0.0, 1.0),
) -> float | None:
    """Integrated body rotation weighed by ``axis_body`` (a unit axis, or weights such as
    :func:`~common.yaw.mount.image_turn_axis_imu`'s) from ``start_s`` to ``stop_s`` (rad), or None without
    coverage (no sample at or before ``start_s``, or the last sample more than 0.1 s before ``stop_s``).

    Samples hold piecewise linearly between stamps (trapezoid), the last one is held to ``stop_s``. Only the
    samples from the last one at or before ``start_s`` to the last one at or before ``stop_s`` are used, so
    any buffer holding them gives the same bits. For a downward camera the vehicle's yaw rate is the body
    z rate (``axis_body`` = +z, the image turns with +yaw).
    """
    t = np.asarray(stamps_s, dtype=np.float64)
    w = np.asarray(gyro_rad_s, dtype=np.float64)
    if t.ndim != 1 or w.shape != (t.size, 3):
        raise InputError(f"need stamps (M,) and gyro (M, 3), got {t.shape} and {w.shape}")
    if not (math.isfinite(start_s) and math.isfinite(stop_s)) or stop_s < start_s:
        raise InputError(f"need finite start <= stop, got {start_s}, {stop_s}")
    i0 = int(np.searchsorted(t, start_s, side="right")) - 1
    i1 = int(np.searchsorted(t, stop_s, side="right")) - 1
    if i0 < 0 or i1 < 0 or stop_s - t[i1] > 0.1:
        return None
    axis = np.asarray(axis_body, dtype=np.float64)
    rate = w[i0 : i1 + 1] @ axis
    ts = t[i0 : i1 + 1]
    if not np.all(np.isfinite(rate)):
        return None
    if ts.size == 1:
        return float(rate[0] * (stop_s - start_s))
    # rate at start_s by linear interpolation, then trapezoids over the samples, then hold the last one
    f = (start_s - ts[0]) / (ts[1] - ts[0]) if ts[1] > ts[0] else 0.0
    rate_start = rate[0] + f * (rate[1] - rate[0])
    total = 0.5 * (rate_start + rate[1]) * (ts[1] - start_s)
    if ts.size > 2:
        total += float(np.sum(0.5 * (rate[1:-1] + rate[2:]) * np.diff(ts[1:])))
    total += rate[-1] * (stop_s - ts[-1])
    return float(total)


def make_prior(
    settings: YawSettings,
    dt_s: float | None,
    gyro_delta_rad: float | None,
    held: HeldRate | None,
    since_measured_s: float,
) -> Prior:
    """The prior of a pair: the gyro's delta when given, else the held rate of the recent measured pairs
    (:func:`~common.yaw.held.held_rate`; None: unknown).

    The held delta's error is bounded by what the yaw acceleration limit (plus the window's own trend, up
    to that limit) allows over the pair's interval and the time since measured, plus twice the rates'
    scatter about the window's line over the interval; a third of that is one sigma, so the variance grows
    with the time since measured.
    """
    dt = dt_s if dt_s is not None else settings.frame_period_s
    if gyro_delta_rad is not None:
        gate = math.radians(settings.gyro_gate_deg)
        return Prior(PriorSource.GYRO, gyro_delta_rad, gate, gyro_variance_rad2(settings, dt), dt_s)
    if held is None:
        spread = math.radians(settings.max_yaw_rate_deg_s) * dt if dt_s is not None else math.pi
        return Prior(PriorSource.HOLD, 0.0, spread, spread**2, dt_s)
    accel = math.radians(settings.max_yaw_accel_deg_s2)
    trend = min(abs(held.trend_rad_s2), accel)
    drift = (accel + trend) * dt * (dt + since_measured_s) + 2.0 * held.spread_rad_s * dt
    tolerance = min(max(drift, math.radians(MIN_HOLD_TOLERANCE_DEG)), math.pi)
    variance = float(held_variance_terms(held, dt, since_measured_s) @ held_coefficients())
    return Prior(PriorSource.HOLD, held.rate_rad_s * dt, tolerance, variance, dt_s)


def held_variance_terms(held: HeldRate, dt_s: float, since_measured_s: float) -> npt.NDArray[np.float64]:
    """The terms of a held pair's variance, per unit coefficient (:func:`held_coefficients`): the window's
    scatter of rates over the pair, ``(spread dt)^2``; a rate that changed since it applied,
    ``(dt (lag + since + dt / 2))^2`` (a constant yaw acceleration's effect, per rad^2/s^4); and a rate
    floor, ``dt^2`` (per rad^2/s^2)."""
    reach = held.lag_s + since_measured_s + 0.5 * dt_s
    return np.array([(held.spread_rad_s * dt_s) ** 2, (dt_s * reach) ** 2, dt_s**2])


def held_coefficients() -> npt.NDArray[np.float64]:
    """The held variance's coefficients in :func:`held_variance_terms`' units."""
    return np.array(
        [HELD_SPREAD_SHARE, math.radians(HELD_ACCEL_DEG_S2) ** 2, math.radians(HELD_RATE_DEG_S) ** 2]
    )


def gyro_variance_rad2(settings: YawSettings, dt_s: float) -> float:
    """Variance of the gyro's integrated yaw over ``dt_s``: its bias (``gyro_sigma_deg_s``) times the gap,
    and its white noise (``gyro_noise_deg_s_rthz``) integrated over the gap (a random walk)."""
    bias = math.radians(settings.gyro_sigma_deg_s) * dt_s
    return bias**2 + math.radians(settings.gyro_noise_deg_s_rthz) ** 2 * dt_s


def plausible(delta_rad: float, prior: Prior, settings: YawSettings) -> bool:
    """Within the physical rate limit (when stamped) and the prior's tolerance."""
    limit = math.radians(settings.max_yaw_rate_deg_s)
    if prior.dt_s is not None and prior.dt_s > 0.0 and abs(delta_rad) > limit * prior.dt_s:
        return False
    return abs(float(wrap_angle_rad(delta_rad - prior.delta_rad))) <= prior.tolerance_rad


def choose_rotation(candidates: list[tuple[float, float]], prior: Prior, settings: YawSettings) -> int | None:
    """Index of the candidate rotation ``(rotation_rad, response)`` to verify, or None when ambiguous.

    Candidates that break the rate limit or the prior's tolerance are out; of those left, the ones whose
    response reaches ``ambiguity_ratio`` of the best look alike (a periodic floor): an informative prior
    picks the nearest, otherwise only a single look-alike is accepted. A response that is not a positive
    number is no peak: such candidates are out (none left: None).
    """
    kept = [
        i
        for i, (rotation, response) in enumerate(candidates)
        if response > 0.0 and math.isfinite(response) and plausible(rotation, prior, settings)
    ]
    if not kept:
        return None
    best = max(candidates[i][1] for i in kept)
    alike = [i for i in kept if candidates[i][1] >= settings.ambiguity_ratio * best]
    if len(alike) == 1:
        return alike[0]
    if not prior.informative:
        return None
    return min(alike, key=lambda i: abs(float(wrap_angle_rad(candidates[i][0] - prior.delta_rad))))


def measured_variance_rad2(
    residual_px: float,
    inliers: int,
    patches: int,
    lever_px: float,
    warped: bool = False,
    shift_px: float = 0.0,
    focal_px: float | None = None,
    peak_ratio: float = math.inf,
    unrefined_turn_rad: float = 0.0,
) -> float:
    """Variance of a measured delta from ``inliers`` of the ``patches`` measured: per patch, an angle error of
    ``residual / lever`` (scaled by :data:`RESIDUAL_SHARE`), plus the warp's floor :data:`WARPED_FLOOR_DEG`
    when frame k was warped back before the patches were measured (``warped``), plus ``(SHIFT_SHARE * shift /
    focal)^2`` for the image's shift at the rotation centre between the two frames (``shift_px``), as the
    angle the view moved (``focal_px``: the lens's focal length; None, a camera without intrinsics: the lever
    arm stands in, a cautious choice, as the patches' lever arm is shorter than a pinhole's focal length up to
    about 110 deg of view), plus ``(AMBIGUITY_DEG / peak_ratio)^2`` for the patches' median ratio of their
    correlation's first peak to its second (inf: unambiguous; NaN counts as 1, the most ambiguous). That is
    averaged over the inliers and scaled by ``patches / inliers``, the pair's difficulty. A pair measured on
    the raw frames adds ``(UNREFINED_PULL * unrefined_turn_rad)^2`` for the whole pair (the window's pull,
    common to its patches; 0 for a refined or pre-aligned pair)."""
    residual = max(residual_px if math.isfinite(residual_px) else 1.0, MIN_RESIDUAL_PX)
    lever = max(lever_px, 1.0)
    focal = lever if focal_px is None or not math.isfinite(focal_px) else max(focal_px, 1.0)
    agreed = max(inliers, 1)
    shift = SHIFT_SHARE * (shift_px if math.isfinite(shift_px) else 0.0) / focal
    ambiguity = math.radians(AMBIGUITY_DEG) / max(peak_ratio if not math.isnan(peak_ratio) else 1.0, 1.0)
    per_patch = RESIDUAL_SHARE * (residual / lever) ** 2 * 2.0 + shift**2 + ambiguity**2
    per_patch += math.radians(WARPED_FLOOR_DEG) ** 2 if warped else 0.0
    turn = unrefined_turn_rad if math.isfinite(unrefined_turn_rad) else 0.0
    return float(per_patch * max(patches, agreed) / agreed**2 + (UNREFINED_PULL * turn) ** 2)
