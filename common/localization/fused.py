"""The weighting's hot path in one compiled pass: culling, projection, distance lookup and per-edge sums.

:func:`project_posed_samples` followed by :func:`~common.localization.scoring.score_particles` materialises
(P, E', S) arrays of pixels, validity, indices and distances (a dozen passes over memory per call).
:func:`fused_edge_sums` culls, projects and looks up every particle's sample points in one compiled call
(numba, one thread), with the same float32 arithmetic, the same validity rules (back faces, frustum, near
plane, image bounds, hidden points) and the same pixel rounding, and returns only the per-edge sums the
scorings need: visible points ``S`` (P, E') and ``sum f(d)`` (P, E'), where ``f`` is paper B method 3's
``g(d)`` or method 1 and 2's alignment indicator. :func:`score_from_edge_sums` turns them into ``log W`` by
the scorings' own functions.

Layout: the model is read from :class:`FusedModel` (float32, built once per tracker); per call the kept
edges' points are laid out point-major (all edges' first points, then their second points, ...), so that a
particle's projection, its weights and its per-edge sums are each one branch-free loop the compiler
vectorises; only the distance lookup is a scalar gather. ``g(d)`` is computed in the loop
(:func:`_exp_parts`, within 2e-7 of ``exp``), not read from a table. Back-face culling is decided once per
face for the whole cloud and per camera only for faces some cameras see and others not; frustum culling once
per cloud (:func:`_cloud_frustum`), the per-point image bounds doing the rest.

It serves the distance-transform scorings on undistorted cameras (the tracker's weighting); the normal walk
(``NEAREST_EDGE``), oriented lookups and lens distortion take the general path. A test checks both paths
agree particle by particle (``tests/common/localization/test_fused.py``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from common.camera import CameraModel
from common.localization.projection import (
    NEAR_PLANE_M,
    EdgeSamples,
    IntArray,
    frustum_tangents,
)
from common.localization.projection_matrices import projection_matrices
from common.localization.scoring import (
    ImageEdges,
    ScoringMethod,
    ScoringSettings,
    klein_murray_log_weight,
    nearest_edge_log_weight_of_sums,
    per_edge_log_weight,
)
from common.types import BoolArray, Float32Array, FloatArray

#: Cody-Waite split of ln 2 and the minimax polynomial of ``exp`` on [-ln2 / 2, ln2 / 2] (Cephes ``expf``)
_LOG2E = np.float32(1.44269504088896341)
_LN2_HI = np.float32(0.693359375)
_LN2_LO = np.float32(-2.12194440e-4)
_EXP_POLY = tuple(
    np.float32(c)
    for c in (1.9875691500e-4, 1.3981999507e-3, 8.3334519073e-3, 4.1665795894e-2, 1.6666665459e-1, 5.0e-1)
)
#: smallest argument (``exp`` stays a normal float32 above it)
_EXP_FLOOR = np.float32(-87.0)


class FusedModel(NamedTuple):
    """An :class:`EdgeSamples` and its camera's frustum as the compiled pass reads them (:func:`fused_model`,
    once per tracker; a named tuple, which the compiled code takes as one argument).

    ``points`` (E, 3, S) float32; ``centres`` (3, E) and ``radii`` (E,) float32 (bounding spheres);
    ``edge_faces`` (E, 2), ``edge_smooth`` (E,), ``face_normals`` (3, F), ``face_offsets_m`` (F,) as in
    :class:`EdgeSamples`; ``all_visible`` (E, S) true; ``sides`` the tangents of the frustum's left, right,
    top and bottom planes, then their normalisers ``1 / hypot(1, t)`` (float32, as
    :func:`~common.localization.projection.frustum_edges`).
    """

    points: Float32Array
    centres: Float32Array
    radii: Float32Array
    edge_faces: IntArray
    edge_smooth: BoolArray
    face_normals: FloatArray
    face_offsets_m: FloatArray
    all_visible: BoolArray
    sides: Float32Array


def fused_model(samples: EdgeSamples, camera: CameraModel) -> FusedModel:
    """The compiled pass's copy of ``samples`` (float32, contiguous) and of ``camera``'s frustum."""
    tangents = np.asarray(frustum_tangents(camera))
    return FusedModel(
        points=np.ascontiguousarray(np.transpose(samples.points_world_m, (0, 2, 1)), dtype=np.float32),
        centres=np.ascontiguousarray(samples.centres_world_m.T, dtype=np.float32),
        radii=np.ascontiguousarray(samples.radii_m, dtype=np.float32),
        edge_faces=np.ascontiguousarray(samples.edge_faces, dtype=np.int64),
        edge_smooth=np.ascontiguousarray(samples.edge_smooth, dtype=np.bool_),
        face_normals=np.ascontiguousarray(np.reshape(samples.face_normals, (-1, 3)).T, dtype=np.float64),
        face_offsets_m=np.ascontiguousarray(samples.face_offsets_m, dtype=np.float64),
        all_visible=np.ones(samples.points_world_m.shape[:2], dtype=np.bool_),
        sides=np.concatenate([tangents, 1.0 / np.hypot(1.0, tangents)]).astype(np.float32),
    )


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _exp_parts(x: np.float32) -> tuple[np.float32, np.int32]:  # pragma: no cover - compiled; tested
    """``exp(x)`` for ``x <= 0`` (float32; ``exp(-87)`` below -87) as ``m 2^n``: ``m`` a polynomial of the
    remainder, ``2^n`` as the bits of a float32 (the caller views them as floats: no branch, vectorises)."""
    x = x if x > _EXP_FLOOR else _EXP_FLOOR
    n = np.floor(x * _LOG2E + np.float32(0.5))
    r = (x - n * _LN2_HI) - n * _LN2_LO
    p0, p1, p2, p3, p4, p5 = _EXP_POLY
    p = ((((p0 * r + p1) * r + p2) * r + p3) * r + p4) * r + p5
    return p * r * r + r + np.float32(1.0), (np.int32(n) + np.int32(127)) << np.int32(23)


@njit(cache=True, nogil=True, error_model="numpy")
def _front_faces(p64: FloatArray, model: FusedModel) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """Which faces face each camera (P, F) (:func:`~common.localization.projection.front_facing_edges`'s
    test, float64) and per face whether every camera (1), none (0) or some (2) sees its front."""
    n_particles, n_faces = p64.shape[0], model.face_offsets_m.size
    nx, ny, nz = model.face_normals[0], model.face_normals[1], model.face_normals[2]
    front = np.empty((n_particles, n_faces), dtype=np.bool_)
    seen = np.zeros(n_faces, dtype=np.int64)
    for p in range(n_particles):
        px, py, pz = p64[p, 0], p64[p, 1], p64[p, 2]
        for f in range(n_faces):
            front[p, f] = (px * nx[f] + py * ny[f] + pz * nz[f]) - model.face_offsets_m[f] > 0.0
            seen[f] += front[p, f]
    state = np.where(seen == n_particles, 1, np.where(seen == 0, 0, 2))
    return front, state


@njit(cache=True, nogil=True, error_model="numpy")
def _cloud_frustum(R64: FloatArray, p64: FloatArray, model: FusedModel, near: float) -> np.ndarray:
    """Edges whose bounding sphere may be inside some camera's frustum (E,): the first camera's test of
    :func:`~common.localization.projection.frustum_edges` with the radius grown by how far any other camera
    may see a plane's signed distance move, ``|R_p - R_0| |c - o_0| + |o_p - o_0|`` (a superset: an edge
    left out is outside every frustum). The kernel then needs no per-particle frustum test: a sphere beyond a
    side by more than its radius has every sample point (strictly inside it) outside the image, which the
    per-point bounds test rejects anyway."""  # pragma: no cover - compiled
    n_particles = R64.shape[0]
    turn, shift = 0.0, 0.0
    for p in range(1, n_particles):
        d2 = 0.0
        for i in range(3):
            for k in range(3):
                d2 += (R64[p, i, k] - R64[0, i, k]) ** 2
        o2 = (p64[p, 0] - p64[0, 0]) ** 2 + (p64[p, 1] - p64[0, 1]) ** 2 + (p64[p, 2] - p64[0, 2]) ** 2
        turn, shift = max(turn, np.sqrt(d2)), max(shift, np.sqrt(o2))
    t_left, t_right, t_top, t_bottom, s_left, s_right, s_top, s_bottom = model.sides
    R = R64[0]
    inside = np.empty(model.radii.size, dtype=np.bool_)
    for e in range(model.radii.size):
        wx = model.centres[0, e] - p64[0, 0]
        wy = model.centres[1, e] - p64[0, 1]
        wz = model.centres[2, e] - p64[0, 2]
        x = R[0, 0] * wx + R[0, 1] * wy + R[0, 2] * wz
        y = R[1, 0] * wx + R[1, 1] * wy + R[1, 2] * wz
        z = R[2, 0] * wx + R[2, 1] * wy + R[2, 2] * wz
        distance = np.sqrt(wx * wx + wy * wy + wz * wz)
        # float32 rounding of the per-camera test is far below the 1e-5 relative margin
        r = -(model.radii[e] + turn * distance + shift + 1e-5 * (distance + model.radii[e]) + 1e-6)
        inside[e] = (
            (z - near > r)
            and (t_right * z - x) * s_right > r
            and (t_left * z + x) * s_left > r
            and (t_bottom * z - y) * s_bottom > r
            and (t_top * z + y) * s_top > r
        )
    return inside


@njit(cache=True, nogil=True, error_model="numpy")
def _edge_keep(first: int, second: int, smooth: bool, a: bool, b: bool) -> bool:  # pragma: no cover
    """Back-face culling of one edge from its faces' fronts (``a``, ``b``; ``second < 0``: one face)."""
    if first < 0:  # a standalone line
        return True
    b = b and second >= 0
    return (a != b) if smooth else (a or b)


@njit(cache=True, nogil=True, error_model="numpy")
def _edge_sums(  # pragma: no cover - compiled; checked against the numpy path
    KR: Float32Array,
    Kt: Float32Array,
    R64: FloatArray,
    p64: FloatArray,
    model: FusedModel,
    visible: BoolArray,
    width: int,
    height: int,
    lookup: Float32Array,
    gaussian: bool,
    threshold: np.float32,
    exponent_scale: np.float32,
    near: np.float32,
) -> tuple[Float32Array, Float32Array]:
    """``sum f(d)`` and visible points (P, E') over the candidate edges (E', ascending): front-facing for
    some camera, possibly in its frustum (:func:`_cloud_frustum`), with a sample point not hidden."""
    n_particles, n_points = KR.shape[0], model.points.shape[2]
    front, face_state = _front_faces(p64, model)
    in_frustum = _cloud_frustum(R64, p64, model, float(near))
    faces, smooth = model.edge_faces, model.edge_smooth
    n_edges = model.radii.size
    candidate = np.zeros(n_edges, dtype=np.bool_)
    mixed = np.zeros(n_edges, dtype=np.bool_)  # back-face culling differs between cameras
    for e in range(n_edges):
        first, second = faces[e, 0], faces[e, 1]
        state_b = face_state[second] if second >= 0 else 0
        mixed[e] = first >= 0 and (face_state[first] == 2 or state_b == 2)
        kept = mixed[e] or _edge_keep(first, second, smooth[e], face_state[first] == 1, state_b == 1)
        candidate[e] = kept and in_frustum[e] and visible[e].any()
    ids = np.flatnonzero(candidate)
    n = ids.size
    mixed_j = np.flatnonzero(mixed[ids])
    size = n * n_points
    # the candidates' points, point-major: index s * n + j is point s of candidate edge j
    xs, ys, zs = np.empty(size, np.float32), np.empty(size, np.float32), np.empty(size, np.float32)
    shown_mask = np.empty(size, np.bool_)
    for s in range(n_points):
        for j in range(n):
            q, e = s * n + j, ids[j]
            xs[q], ys[q], zs[q] = model.points[e, 0, s], model.points[e, 1, s], model.points[e, 2, s]
            shown_mask[q] = visible[e, s]
    sums = np.zeros((n_particles, n), dtype=np.float32)
    counts = np.zeros((n_particles, n), dtype=np.float32)
    half, one, zero = np.float32(0.5), np.float32(1.0), np.float32(0.0)
    u_max, v_max = np.float32(width) - half, np.float32(height) - half
    outside, w32 = np.int32(width * height), np.int32(width)  # the lookup's last entry is inf
    index = np.empty(size, dtype=np.uint32)  # unsigned: the gather needs no negative-index check
    weight = np.empty(size, dtype=np.float32)
    distance = np.empty(size, dtype=np.float32)
    bits = np.empty(size, dtype=np.int32)
    scale = bits.view(np.float32)
    for p in range(n_particles):
        # the particle's matrix in locals: loaded once, not once per point
        a00, a01, a02, a03 = KR[p, 0, 0], KR[p, 0, 1], KR[p, 0, 2], Kt[p, 0, 0]
        a10, a11, a12, a13 = KR[p, 1, 0], KR[p, 1, 1], KR[p, 1, 2], Kt[p, 1, 0]
        a20, a21, a22, a23 = KR[p, 2, 0], KR[p, 2, 1], KR[p, 2, 2], Kt[p, 2, 0]
        for q in range(size):  # branch-free: vectorised
            x, y, z = xs[q], ys[q], zs[q]
            hz = a20 * x + a21 * y + a22 * z + a23
            inv_z = one / hz
            u = (a00 * x + a01 * y + a02 * z + a03) * inv_z
            v = (a10 * x + a11 * y + a12 * z + a13) * inv_z
            ok = shown_mask[q] & (hz > near) & (u >= -half) & (u < u_max) & (v >= -half) & (v < v_max)
            pixel = np.int32(v + half) * w32 + np.int32(u + half)
            index[q] = np.uint32(pixel if ok else outside)
        for q in range(size):
            distance[q] = lookup[index[q]]
        if gaussian:  # g(d) by :func:`_exp_parts`, in one pass with the threshold, then scaled by 2^n
            for q in range(size):
                d = distance[q]
                mantissa, bits[q] = _exp_parts(d * d * exponent_scale)
                weight[q] = mantissa if d <= threshold else zero
            for q in range(size):
                weight[q] *= scale[q]
        else:
            for q in range(size):
                weight[q] = one if distance[q] <= threshold else zero
        row_sums, row_counts = sums[p], counts[p]
        for s in range(n_points):  # per edge, its points in order (the sums of the general path)
            for j in range(n):
                row_sums[j] += weight[s * n + j]
                row_counts[j] += one if index[s * n + j] != outside else zero
        for column in mixed_j:
            edge = ids[column]
            first, second = faces[edge, 0], faces[edge, 1]
            if not _edge_keep(first, second, smooth[edge], front[p, first], front[p, max(second, 0)]):
                row_sums[column], row_counts[column] = zero, zero
    return sums, counts


def compile_fused_kernel() -> None:
    """Compile (or load from numba's cache) the pass on a one-edge problem. A tracker calls it when it is
    built, so that a service compiles before it subscribes (a cold compile takes seconds on a loaded host;
    met on the first frame, it let the estimator's queues overflow)."""
    samples = EdgeSamples(
        points_world_m=np.array([[[0.0, 0.0, 1.0]]]),
        directions_world=np.array([[1.0, 0.0, 0.0]]),
        centres_world_m=np.array([[0.0, 0.0, 1.0]]),
        radii_m=np.array([0.1]),
        edge_faces=np.array([[0, -1]]),
        face_normals=np.array([[0.0, 0.0, -1.0]]),
        face_offsets_m=np.array([-1.0]),
        edge_smooth=np.zeros(1, dtype=bool),
    )
    camera = CameraModel(width=2, height=2, fx=1.0, fy=1.0, cx=0.5, cy=0.5)
    edges_lookup = np.zeros(5, dtype=np.float32)
    for gaussian in (True, False):
        _run(fused_model(samples, camera), np.eye(3)[None], np.zeros((1, 3)), camera, edges_lookup, gaussian,
             1.0, -0.125, None, NEAR_PLANE_M)  # fmt: skip


def fused_applies(camera: CameraModel, edges: ImageEdges, params: ScoringSettings) -> bool:
    """Whether :func:`fused_edge_sums` computes what the general path would."""
    return (
        not camera.is_distorted
        and edges.oriented_lookup is None
        and params.method is not ScoringMethod.NEAREST_EDGE
    )


def _run(
    model: FusedModel,
    R_camera_world: FloatArray,
    p_world_camera: FloatArray,
    camera: CameraModel,
    lookup: Float32Array,
    gaussian: bool,
    threshold: float,
    exponent_scale: float,
    visible: BoolArray | None,
    near_m: float,
) -> tuple[Float32Array, Float32Array]:
    KR, Kt = projection_matrices(R_camera_world, p_world_camera, camera)
    return _edge_sums(
        KR,
        Kt,
        np.ascontiguousarray(R_camera_world, dtype=np.float64),
        np.ascontiguousarray(p_world_camera, dtype=np.float64),
        model,
        model.all_visible if visible is None else np.ascontiguousarray(visible, dtype=np.bool_),
        int(camera.width),
        int(camera.height),
        lookup,
        gaussian,
        np.float32(threshold),
        np.float32(exponent_scale),
        np.float32(near_m),
    )


def fused_edge_sums(
    model: FusedModel,
    R_camera_world: FloatArray,
    p_world_camera: FloatArray,
    camera: CameraModel,
    edges: ImageEdges,
    params: ScoringSettings,
    visible: BoolArray | None = None,
    near_m: float = NEAR_PLANE_M,
) -> tuple[Float32Array, Float32Array]:
    """Per particle and kept edge: ``sum f(d)`` and the number of visible sample points (P, E') each;
    ``model`` is :func:`fused_model` of the samples and ``camera``."""
    gaussian = params.method is ScoringMethod.NEAREST_EDGE_DT
    threshold = float(params.max_normal_px) if gaussian else params.align_px
    # the exponent of g(d) = exp(-d^2 / (2 sigma^2)) as :func:`~common.localization.scoring.normal_weight`
    exponent_scale = np.float32(-0.5 / params.sigma_px**2)
    return _run(model, R_camera_world, p_world_camera, camera, edges.distance_lookup, gaussian, threshold,
                float(exponent_scale), visible, near_m)  # fmt: skip


def score_from_edge_sums(sums: Float32Array, counts: Float32Array, params: ScoringSettings) -> FloatArray:
    """``log W`` (P,) of the chosen scoring from :func:`fused_edge_sums`."""
    if params.method is ScoringMethod.KLEIN_MURRAY:
        a = sums.sum(axis=1, dtype=np.float64)
        v = counts.sum(axis=1, dtype=np.float64)
        return klein_murray_log_weight(a, v, params.k)
    if params.method is ScoringMethod.PER_EDGE:
        a_j, v_j = sums.astype(np.float64), counts.astype(np.float64)
        return per_edge_log_weight(a_j, v_j, params.k, params.lambda_per_edge)
    return nearest_edge_log_weight_of_sums(sums, counts, params.k, params.alpha)[0]
