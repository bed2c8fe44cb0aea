"""The search pieces of the model tracker (:mod:`~common.localization.tracker`): annealed weighting,
search candidates, the 2D chamfer shift that centres a search, and the estimate's covariance.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.localization.particle_filter import low_variance_resample
from common.localization.pose import CameraPose, perturb, rotation_matrices, rotation_vectors
from common.localization.scoring import ImageEdges
from common.types import FloatArray


def anneal(
    log_likelihood: Callable[..., FloatArray],
    positions: FloatArray,
    rotations: FloatArray,
    edges: ImageEdges,
    rng: np.random.Generator,
    layers: int,
    noise: tuple[float, float],
    keep: int,
    visible: npt.NDArray[np.bool_] | None,
    coarse: float = 1.0,
    expected_points: int = 0,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Annealed importance weighting (Deutscher et al.): per layer weigh with ``exp(beta l)`` at an
    effective sample size of half the cloud, resample ``keep`` poses, diffuse with a halving noise
    (position m, angle rad); the last layer is weighed and returned with its log weights. The scoring's
    pixel scales start ``coarse`` times wider and narrow geometrically to 1 on the last layer;
    ``log_likelihood(positions, rotations, edges, visible, coarseness, expected_points)`` scores the
    poses."""
    for layer in range(layers):
        coarseness = coarse ** (1.0 - layer / max(layers - 1, 1))
        loglik = log_likelihood(positions, rotations, edges, visible, coarseness, expected_points)
        last = layer == layers - 1
        beta = beta_for_ess(loglik, 0.5)
        logw = beta * loglik
        if last:
            return positions, rotations, logw
        weights = np.exp(logw - logw.max())
        weights /= weights.sum()
        idx = low_variance_resample(weights, rng, keep)
        scale = 0.5 ** (layer + 1)
        positions = positions[idx] + rng.normal(size=(keep, 3)) * (noise[0] * scale)
        rotations = perturb(rotations[idx], rng.normal(size=(keep, 3)) * (noise[1] * scale))
    raise AssertionError("unreachable")


def search_candidates(
    centre: CameraPose,
    n: int,
    pos_spread: float,
    ang_spread: float,
    distance_m: float,
    rng: np.random.Generator,
    anchor_world_m: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """``n`` poses about ``centre``: half uniform in the box ``+- (pos_spread, ang_spread)`` (position per
    axis, world rotation vector per axis); half *aimed*: positions in the same box, each turned so that
    ``anchor_world_m`` (the model in view; default: the point ``distance_m`` ahead of the centre) stays
    where the centre sees it, plus a turn of up to ``ang_spread / 2``. A camera moved sideways by ``dp``
    sees the model shifted like a turn of ``dp / d``; the box needs both to match, which in 6-D it rarely
    samples, while the aimed half couples them (the centre already put the model where the image shows it,
    :func:`chamfer_turn`)."""
    half = n // 2
    units = rng.uniform(-1.0, 1.0, (n, 6))
    positions = centre.p_world_camera_m + units[:, :3] * pos_spread
    turns = units[:, 3:] * ang_spread
    if anchor_world_m is None:
        anchor_world_m = centre.p_world_camera_m + distance_m * centre.R_world_camera[:, 2]
    seen = anchor_world_m - centre.p_world_camera_m
    seen = seen / max(float(np.linalg.norm(seen)), 1e-9)
    aimed = anchor_world_m - positions[half:]
    aimed = aimed / np.maximum(np.linalg.norm(aimed, axis=1, keepdims=True), 1e-9)
    axis = np.cross(seen, aimed)
    sin = np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.arctan2(sin, aimed @ seen[:, None])
    turns[half:] = np.where(sin > 1e-12, axis / np.maximum(sin, 1e-12) * angle, 0.0) + 0.5 * turns[half:]
    rotations = perturb(np.repeat(centre.R_world_camera[None], n, axis=0), turns)
    return positions, rotations


def chamfer_turn(
    u_px: npt.ArrayLike,
    v_px: npt.ArrayLike,
    edges: ImageEdges,
    camera: CameraModel,
    turn_rad: float,
    cap_px: float,
    bins: npt.ArrayLike | None = None,
) -> FloatArray | None:
    """The camera turn ``R`` (applied as ``R R_camera_world``) that moves projected model points ``(u, v)``
    by the 2D shift where the image's edges fit them best: mean distance-transform value (capped at
    ``cap_px``; points shifted out of the image count the cap) over a grid of shifts up to ``turn_rad x f``,
    coarse then fine. A camera moved sideways or turned moves a model seen from afar mostly as a whole; this
    finds that move whatever the search spread. None when the best shift is not clearly better (20 %) than
    none. With ``bins`` (each point's orientation bin) the distances are the oriented ones
    (:func:`~common.localization.scoring.with_oriented_distances`): clutter of other directions does not
    attract the shift."""
    u = np.asarray(u_px, dtype=np.float32)
    v = np.asarray(v_px, dtype=np.float32)
    cap = np.float32(cap_px)

    def cost(shifts: FloatArray) -> FloatArray:
        su = (u[None, :] + shifts[:, :1].astype(np.float32) + np.float32(0.5)).astype(np.int32)
        sv = (v[None, :] + shifts[:, 1:].astype(np.float32) + np.float32(0.5)).astype(np.int32)
        inside = (su >= 0) & (su < edges.width) & (sv >= 0) & (sv < edges.height)
        index = np.where(inside, sv * np.int32(edges.width) + su, edges.width * edges.height)
        if bins is not None and edges.oriented_lookup is not None:
            offset = np.asarray(bins, dtype=np.int32) * np.int32(edges.oriented_lookup.shape[1])
            d = np.minimum(np.take(edges.oriented_lookup.ravel(), index + offset[None, :]), cap)
        else:
            d = np.minimum(np.take(edges.distance_lookup, index), cap)
        return np.asarray(d.mean(axis=1), dtype=np.float64)

    reach = max(4.0, turn_rad * max(camera.fx, camera.fy))
    step = max(2.0, reach / 24.0)
    grid = np.arange(-reach, reach + 1e-9, step)
    shifts = np.stack(np.meshgrid(grid, grid), axis=-1).reshape(-1, 2)
    best = shifts[int(np.argmin(cost(shifts)))]
    local = np.arange(-step, step + 1e-9, step / 4.0)
    fine = best + np.stack(np.meshgrid(local, local), -1).reshape(-1, 2)
    fine_costs = cost(fine)
    best, best_cost = fine[int(np.argmin(fine_costs))], float(np.min(fine_costs))
    if best_cost > 0.8 * float(cost(np.zeros((1, 2)))[0]):
        return None
    # a turn w (camera frame) moves image points by about (fx w_y, -fy w_x)
    du, dv = float(best[0]), float(best[1])
    return np.asarray(rotation_matrices(np.array([[-dv / camera.fy, du / camera.fx, 0.0]]))[0])


def beta_for_ess(loglik: FloatArray, fraction: float) -> float:
    """Largest ``beta`` in (0, 1] whose weights ``exp(beta l)`` keep an effective sample size of at least
    ``fraction`` of the cloud (bisection)."""
    spread = loglik - loglik.max()

    def ess(beta: float) -> float:
        w = np.exp(beta * spread)
        return float(w.sum() ** 2 / np.sum(w * w)) / float(w.size)

    if ess(1.0) >= fraction:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if ess(mid) >= fraction:
            lo = mid
        else:
            hi = mid
    return max(lo, 1e-6)


def cloud_covariance(positions: FloatArray, rotations: FloatArray, centre: CameraPose) -> FloatArray:
    """6x6 covariance of the cloud about ``centre``: position and world-frame error angles."""
    dp = positions - centre.p_world_camera_m
    dtheta = rotation_vectors(np.einsum("nij,kj->nik", rotations, centre.R_world_camera))
    residual = np.concatenate([dp, dtheta], axis=1)
    cov = residual.T @ residual / residual.shape[0]
    return np.asarray(0.5 * (cov + cov.T))


def untrusted_covariance(
    cloud: FloatArray, pose: CameraPose, last_good: CameraPose, spreads: tuple[float, float]
) -> FloatArray:
    """The covariance of a pose not trusted (a search's guess), about ``pose``: the cloud's own covariance
    (``cloud``), plus the search box about the last trusted pose (uniform ``+- spreads``: position m per
    axis, angle rad per axis, variance ``spread^2 / 3``), plus the outer product of the offset from the last
    trusted pose (position, world-frame error angles). It is never tighter than the region the search
    believes the camera in, and the last trusted pose always lies within one sigma of it: a search that
    settled tightly on clutter does not read as measured."""
    offset = np.concatenate(
        [
            last_good.p_world_camera_m - pose.p_world_camera_m,
            rotation_vectors((last_good.R_world_camera @ pose.R_world_camera.T)[None])[0],
        ]
    )
    box = np.repeat(np.square(np.asarray(spreads, dtype=np.float64)) / 3.0, 3)
    cov = np.nan_to_num(cloud, nan=0.0) + np.diag(box) + np.outer(offset, offset)
    return np.asarray(0.5 * (cov + cov.T))


def shrunk_covariance(covariance: FloatArray, shrinkage: float, scale: float = 1.0) -> FloatArray:
    """A tracked pose's published covariance: shrunk towards its diagonal, scaled (``covariance_*``)."""
    s = shrinkage
    return np.asarray(scale * ((1.0 - s) * covariance + s * np.diag(np.diag(covariance))), dtype=np.float64)


def agreement_inflation(agreement: float, reference: float, power: float) -> float:
    """The factor on a tracked pose's published covariance from its refinement's
    :func:`~common.localization.refine.edge_agreement` ``r``: ``max(1, r / reference) ** power``. A pose
    whose edges' offsets add up (large ``r``: locked off its true one along a weak direction) is published as
    that much less certain; an unmeasured ``r`` (NaN) counts as 1, the clustered covariance as large as the
    independent one."""
    r = agreement if math.isfinite(agreement) else 1.0
    return float(max(1.0, r / reference) ** power)


def twist_covariance_to_world(covariance_twist: FloatArray, pose: CameraPose) -> FloatArray:
    """Covariance of the camera twist ``(v, w)`` (camera frame) as (camera centre, world error angles)."""
    R_wc = pose.R_world_camera
    # p = -R_wc t and a twist (v, w) maps t -> Exp(w) t + v, R_cw -> Exp(w) R_cw: to first order
    # p' = -R_wc Exp(-w) (Exp(w) t + v) = p - R_wc v and R_wc' = R_wc Exp(-w) = Exp(-R_wc w) R_wc
    J = np.zeros((6, 6))
    J[:3, :3] = -R_wc
    J[3:, 3:] = -R_wc
    mapped = J @ covariance_twist @ J.T
    return np.asarray(0.5 * (mapped + mapped.T))
