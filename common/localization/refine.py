"""Local refinement of one pose against a frame's edges, and the texture-proof match measure.

Moving-edge style (as ViSP's model-based tracker): every visible sample point of the model searches along its
projected edge's normal, both ways up to ``search_px``, for the nearest image edge pixel whose gradient is
parallel to that normal (within ``max_angle_deg``; either polarity). Image edges of another direction --
texture, clutter crossing the model edge -- are not matches. The signed offsets ``d_i`` are point-to-line
residuals to the step the found edge pixel marks, located to a fraction of a pixel (:func:`_edge_points`);
Gauss-Newton with Tukey weights solves ``J dxi = d`` for a twist ``dxi = (v, w)`` of the camera
(``X_camera' = Exp(w) X_camera + v``), ``J_i = n_i^T (du/dX)(X) [I, -[X]x]``, re-searching at every
iteration (the search radius halves after the first).

:func:`match_fraction` is the loss measure: the fraction of visible sample points with such an oriented
match within ``match_px``. A pose that is off, or an image without the object, scores low however much
texture it has: texture seldom runs parallel to every model edge at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.bounds import Bounded, bounded
from common.camera import CameraModel
from common.localization.pose import CameraPose, rotation_matrices
from common.localization.projection import EdgeSamples, project_pose_samples
from common.localization.scoring import ImageEdges
from common.types import BoolArray, Float32Array, FloatArray


@dataclass(frozen=True)
class RefineSettings(Bounded):
    """Settings of :func:`refine_pose` and :func:`match_fraction`."""

    iterations: int = bounded(5, ge=1)
    search_px: int = bounded(12, ge=1)
    max_angle_deg: float = bounded(25.0, gt=0.0)
    match_px: float = bounded(2.5, gt=0.0)
    tukey_px: float = bounded(4.0, gt=0.0)
    min_points: int = bounded(12, ge=1)


@dataclass(frozen=True)
class Refinement:
    """A refined pose (``R_camera_world``, ``t_camera_world_m``), its match fraction, the number of visible
    points, and the covariance (6, 6) of the twist ``(v, w)`` from the last Gauss-Newton step."""

    R_camera_world: FloatArray
    t_camera_world_m: FloatArray
    match_fraction: float
    n_points: int
    covariance: FloatArray
    #: the matched outline (px, :func:`match_measures`): what decides between refinements
    outline_px: float = 0.0
    #: how much each edge's points agree in their offsets (:func:`edge_agreement`; NaN: not measured)
    edge_agreement: float = float("nan")


@dataclass(frozen=True)
class EdgeFit:
    """What one frame's refinements fit, the same for every pose tried: the model's edge ``samples``
    (``visible``: those not hidden, None = all), seen by ``camera``, against the frame's ``edges``."""

    samples: EdgeSamples
    camera: CameraModel
    edges: ImageEdges
    params: RefineSettings = RefineSettings()
    visible: BoolArray | None = None


def _edge_points(
    edges: ImageEdges, flat: npt.NDArray[np.int64], gx: Float32Array, gy: Float32Array
) -> tuple[FloatArray, FloatArray]:
    """Sub-pixel position (pixel-centre coordinates) of the step each edge pixel ``flat`` marks: the vertex of
    the parabola through the gradient magnitude at the pixel and its two neighbours along the gradient's
    dominant axis (``gx``, ``gy``: the pixel's gradient), clamped to one pixel.

    Canny marks one pixel of the two a step lies between (the one before it on axis-aligned steps, others on
    diagonal ones); the magnitude profile across the step peaks where the step is, whichever pixel was marked.
    Integer offsets to the marked pixel had biased the refinement by up to half a pixel along the diagonal.
    """
    assert edges.gradient_x is not None and edges.gradient_y is not None
    width, height = edges.width, edges.height
    col, row = flat % width, flat // width
    along_x = np.abs(gx) >= np.abs(gy)
    limit = np.where(along_x, width, height)
    pos = np.where(along_x, col, row)
    stride = np.where(along_x, 1, width)
    before = np.where(pos > 0, flat - stride, flat)
    after = np.where(pos < limit - 1, flat + stride, flat)
    fx, fy = edges.gradient_x.ravel(), edges.gradient_y.ravel()

    def magnitude(index: npt.NDArray[np.int64]) -> Float32Array:
        return np.asarray(np.hypot(fx[index].astype(np.float32), fy[index].astype(np.float32)))

    m_before, m_here, m_after = magnitude(before), np.hypot(gx, gy), magnitude(after)
    curvature = m_before - 2.0 * m_here + m_after
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(curvature < 0.0, 0.5 * (m_before - m_after) / curvature, 0.0)
    shift = np.clip(np.nan_to_num(shift), -1.0, 1.0).astype(np.float64)
    x = col.astype(np.float64) + np.where(along_x, shift, 0.0)
    y = row.astype(np.float64) + np.where(along_x, 0.0, shift)
    return x, y


def oriented_offsets(
    u: FloatArray,
    v: FloatArray,
    nu: FloatArray,
    nv: FloatArray,
    edges: ImageEdges,
    radius: int,
    cos_max: float,
) -> FloatArray:
    """Signed distance (px) along each unit normal from the point to the sub-pixel step of the nearest
    oriented edge pixel on the normal (:func:`_edge_points`; NaN: none within ``radius``)."""
    assert edges.gradient_x is not None and edges.gradient_y is not None
    steps = np.concatenate([[0], np.stack([np.arange(1, radius + 1), -np.arange(1, radius + 1)], 1).ravel()])
    steps32 = steps.astype(np.float32)[None, :]
    nu32, nv32 = nu.astype(np.float32)[:, None], nv.astype(np.float32)[:, None]
    # pixel c covers [c - 1/2, c + 1/2): + 0.5 then truncation rounds (coordinates >= -0.5)
    half = np.float32(0.5)
    col = (u.astype(np.float32)[:, None] + steps32 * nu32 + half).astype(np.int32)
    row = (v.astype(np.float32)[:, None] + steps32 * nv32 + half).astype(np.int32)
    inside = (col >= 0) & (col < edges.width) & (row >= 0) & (row < edges.height)
    flat = np.where(inside, row * np.int32(edges.width) + col, 0)
    is_edge = inside & (edges.edge_map.ravel()[flat] > 0)
    candidates = np.flatnonzero(is_edge)  # only edge pixels need the direction test
    gx = edges.gradient_x.ravel()[flat.ravel()[candidates]].astype(np.float32)
    gy = edges.gradient_y.ravel()[flat.ravel()[candidates]].astype(np.float32)
    point = candidates // steps.size
    parallel = np.abs(gx * nu32[point, 0] + gy * nv32[point, 0])
    hit_flat = np.zeros(is_edge.size, dtype=bool)
    hit_flat[candidates] = parallel >= np.float32(cos_max) * np.hypot(gx, gy)
    hit = hit_flat.reshape(is_edge.shape[0], steps.size)
    first = np.argmax(hit, axis=1)  # steps are ordered by |offset|: the first hit is the nearest
    found = np.flatnonzero(hit[np.arange(hit.shape[0]), first])
    offsets = np.full(u.shape[0], np.nan)
    if found.size:
        pixel = flat[found, first[found]].astype(np.int64)
        gx_hit = edges.gradient_x.ravel()[pixel].astype(np.float32)
        gy_hit = edges.gradient_y.ravel()[pixel].astype(np.float32)
        x, y = _edge_points(edges, pixel, gx_hit, gy_hit)
        offsets[found] = (x - u[found]) * nu[found] + (y - v[found]) * nv[found]
    return offsets


def _visible_projection(
    fit: EdgeFit, R_camera_world: FloatArray, t_camera_world: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, npt.NDArray[np.intp]]:
    """Pixels, unit normals and camera-frame points of the valid sample points of one pose, and the model
    edge each lies on (an index into the edges the projection kept)."""
    p_world_camera = -R_camera_world.T @ t_camera_world
    samples = fit.samples
    proj = project_pose_samples(
        samples, R_camera_world, p_world_camera, fit.camera, with_normals=True, visible=fit.visible
    )
    assert proj.normal_u is not None and proj.normal_v is not None
    valid = proj.valid[0]
    points = samples.points_world_m[proj.edge_ids][valid]
    X = points @ R_camera_world.T + t_camera_world
    return (
        proj.u_px[0][valid].astype(np.float64),
        proj.v_px[0][valid].astype(np.float64),
        proj.normal_u[0][valid].astype(np.float64),
        proj.normal_v[0][valid].astype(np.float64),
        X,
        np.nonzero(valid)[0],
    )


def match_fraction(fit: EdgeFit, R_camera_world: FloatArray, t_camera_world: FloatArray) -> tuple[float, int]:
    """Fraction of the visible sample points with a same-direction image edge within ``match_px``, and the
    number of visible points (0 gives a fraction of 0)."""
    fraction, n, _ = match_measures(fit, R_camera_world, t_camera_world)
    return fraction, n


def match_measures(
    fit: EdgeFit, R_camera_world: FloatArray, t_camera_world: FloatArray
) -> tuple[float, int, float]:
    """:func:`match_fraction`'s two figures and the **matched outline** (px): the sum over the model's
    visible edges of the edge's projected visible length times the square of the share of its points
    matched. A pose shrunk onto texture inside the object's outline shows a shorter outline, and texture
    matches an edge in spots, not along it (the square); the whole outline on the object's edges scores
    most."""
    R, t = R_camera_world, t_camera_world
    proj = project_pose_samples(fit.samples, R, -R.T @ t, fit.camera, with_normals=True, visible=fit.visible)
    assert proj.normal_u is not None and proj.normal_v is not None
    valid = proj.valid[0]
    n = int(valid.sum())
    if n == 0:
        return 0.0, 0, 0.0
    params = fit.params
    radius = int(np.ceil(params.match_px))
    u, v = proj.u_px[0].astype(np.float64), proj.v_px[0].astype(np.float64)
    d = oriented_offsets(
        u[valid],
        v[valid],
        proj.normal_u[0][valid].astype(np.float64),
        proj.normal_v[0][valid].astype(np.float64),
        fit.edges,
        radius,
        float(np.cos(np.radians(params.max_angle_deg))),
    )
    hit = np.abs(np.nan_to_num(d, nan=np.inf)) <= params.match_px
    matched = np.zeros(valid.shape)
    matched[valid] = hit
    shown = valid.sum(axis=1)
    share = np.divide(matched.sum(axis=1), shown, out=np.zeros(shown.shape), where=shown > 0)
    spacing = np.hypot(np.diff(u, axis=1), np.diff(v, axis=1)).mean(axis=1) if u.shape[1] > 1 else 1.0
    outline = float(np.sum(shown * spacing * share**2))
    return float(hit.mean()), n, outline


def edge_agreement(
    J: FloatArray,
    weighted_residuals: FloatArray,
    edge: npt.NDArray[np.intp],
    H_inv: FloatArray,
    covariance: FloatArray,
) -> float:
    """How much the points of each model edge agree in their offsets: the trace of the twist's
    cluster-robust (sandwich) covariance with an edge's points as one cluster, ``H^-1 (sum_e s_e s_e^T)
    H^-1`` with ``s_e`` the sum of ``J_i w_i d_i`` over edge ``e``'s points (Liang and Zeger, *Biometrika*
    73, 1986), over the trace of ``covariance``, the one that counts every point as independent.

    Where the pose fits, an edge's offsets scatter about zero and cancel in ``s_e``: the ratio is small
    (0.2 in the office flight, 0.45 on the object). Where a pose held by few edges along one direction is
    locked off its true one, the offsets of each edge's points share a sign and add up: 1.2-3.2 there
    (office frames 106-120 of every seed, 20-70 mm off). ``weighted_residuals`` are ``w_i d_i`` (P,),
    ``edge`` each point's edge (P,), ``H_inv`` the inverse (damped) normal matrix."""
    scores = J * weighted_residuals[:, None]
    per_edge = np.zeros((int(edge.max()) + 1 if edge.size else 0, J.shape[1]))
    np.add.at(per_edge, edge, scores)
    clustered = H_inv @ (per_edge.T @ per_edge) @ H_inv
    independent = float(np.trace(covariance))
    return float(np.trace(clustered)) / independent if independent > 0.0 else float("nan")


def refine_pose(fit: EdgeFit, R_camera_world: FloatArray, t_camera_world: FloatArray) -> Refinement:
    """Gauss-Newton on oriented point-to-edge offsets from one pose (see the module docstring)."""
    R, t = R_camera_world.copy(), t_camera_world.copy()
    params, camera = fit.params, fit.camera
    cos_max = float(np.cos(np.radians(params.max_angle_deg)))
    radius = params.search_px
    covariance = np.full((6, 6), np.nan)
    agreement = float("nan")
    for _ in range(params.iterations):
        u, v, nu, nv, X, edge = _visible_projection(fit, R, t)
        if u.size < params.min_points:
            break
        d = oriented_offsets(u, v, nu, nv, fit.edges, radius, cos_max)
        ok = np.isfinite(d)
        if ok.sum() < params.min_points:
            break
        d, nu, nv, X, edge = d[ok], nu[ok], nv[ok], X[ok], edge[ok]
        x, y, z = X[:, 0], X[:, 1], X[:, 2]
        inv_z = 1.0 / z
        # du/dX (2 x 3) folded with the normal: a = n^T du/dX
        a = np.stack(
            [
                nu * camera.fx * inv_z,
                nv * camera.fy * inv_z,
                -(nu * camera.fx * x + nv * camera.fy * y) * inv_z**2,
            ],
            1,
        )
        # dX/dxi = [I, -[X]x]: n^T du/dX [I, -[X]x] = [a, X x a]
        J = np.concatenate([a, np.cross(X, a)], axis=1)
        scale = params.tukey_px
        w = np.where(np.abs(d) < scale, (1.0 - (d / scale) ** 2) ** 2, 0.0)
        H = (J * w[:, None]).T @ J
        g = (J * w[:, None]).T @ d
        trace = np.trace(H)
        if not np.isfinite(trace) or trace <= 0.0:
            break
        H_damped = H + 1e-6 * trace * np.eye(6)
        step = np.linalg.solve(H_damped, g)
        dR = rotation_matrices(step[3:][None, :])[0]
        R = dR @ R
        t = dR @ t + step[:3]
        dof = max(float(w.sum()) - 6.0, 1.0)
        sigma2 = float(np.sum(w * d * d) / dof) + 0.25  # pixel quantisation floor (1/2 px)
        H_inv = np.linalg.inv(H_damped)
        covariance = sigma2 * H_inv
        agreement = edge_agreement(J, w * d, edge, H_inv, covariance)
        radius = max(params.search_px // 2, int(np.ceil(params.match_px)) + 1)
        if np.linalg.norm(step[:3]) < 1e-5 and np.linalg.norm(step[3:]) < 1e-5:
            break
    fraction, n_points, outline = match_measures(fit, R, t)
    return Refinement(R, t, fraction, n_points, covariance, outline, agreement)


def refine_best(
    fit: EdgeFit,
    positions: FloatArray,
    rotations: FloatArray,
    logw: FloatArray,
    count: int,
    also: Sequence[CameraPose] = (),
) -> tuple[Refinement, CameraPose]:
    """Refine the poses ``also`` (the motion model's prediction) and the ``count`` best distinct particles
    (``R_world_camera`` rotations) with the largest log weights; the refinement with the longest matched
    outline (:func:`match_measures`, which texture cannot raise by shrinking the model onto it) wins.
    Returns it and its pose."""
    order = np.argsort(-logw)
    chosen: list[int] = []
    for i in order:
        if len(chosen) >= count:
            break
        if all(np.linalg.norm(positions[i] - positions[j]) > 1e-4 for j in chosen):
            chosen.append(int(i))
    guesses = list(also) + [CameraPose(positions[i], rotations[i]) for i in chosen]
    best: tuple[Refinement, CameraPose] | None = None
    for guess in guesses:
        result = refine_pose(fit, guess.R_camera_world, guess.t_camera_world_m)
        if best is None or result.outline_px > best[0].outline_px:
            pose = CameraPose(-result.R_camera_world.T @ result.t_camera_world_m, result.R_camera_world.T)
            best = (result, pose)
    assert best is not None
    return best
