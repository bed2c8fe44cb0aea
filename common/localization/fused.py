"""The weighting's hot path in one compiled pass: projection, distance lookup and per-edge sums.

:func:`project_posed_samples` followed by :func:`~common.localization.scoring.score_particles` materialises
(P, E', S) arrays of pixels, validity, indices and distances (a dozen passes over memory per call).
:func:`fused_edge_sums` walks every particle's kept edges' sample points once (numba), with the same
float32 arithmetic, the same validity rules (near plane, image bounds, culled edges, hidden points) and the
same pixel rounding, and returns only the per-edge sums the scorings need: visible points ``S`` (P, E') and
``sum f(d)`` (P, E'), where ``f`` is paper B method 3's ``g(d)`` or method 1 and 2's alignment indicator.
:func:`score_from_edge_sums` turns them into ``log W`` by the scorings' own functions.

It serves the distance-transform scorings on undistorted cameras (the tracker's weighting); the normal walk
(``NEAREST_EDGE``), oriented lookups and lens distortion take the general path. A test checks both paths
agree particle by particle (``tests/common/localization/test_fused.py``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from common.camera import CameraModel
from common.localization.projection import NEAR_PLANE_M, EdgeSamples, kept_edges, projection_matrices
from common.localization.scoring import (
    ImageEdges,
    ScoringMethod,
    ScoringSettings,
    klein_murray_log_weight,
    nearest_edge_log_weight_of_sums,
    per_edge_log_weight,
)
from common.types import BoolArray, Float32Array, FloatArray


@njit(cache=True, nogil=True, error_model="numpy")  # no zero-division checks (hz > near first)
def _edge_sums(  # pragma: no cover - compiled; checked against the numpy path
    KR: Float32Array,
    Kt: Float32Array,
    points: Float32Array,
    edge_keep: BoolArray,
    visible: BoolArray,
    width: int,
    height: int,
    lookup: Float32Array,
    gaussian: bool,
    threshold: np.float32,
    g_table: Float32Array,
    steps_per_px: np.float32,
    near: np.float32,
    sums: Float32Array,
    counts: Float32Array,
) -> None:
    half = np.float32(0.5)
    u_max = np.float32(width) - half
    v_max = np.float32(height) - half
    one = np.float32(1.0)
    for p in range(KR.shape[0]):
        # the particle's matrix in locals: loaded once, not once per point (the output arrays could alias it)
        a00, a01, a02, a03 = KR[p, 0, 0], KR[p, 0, 1], KR[p, 0, 2], Kt[p, 0, 0]
        a10, a11, a12, a13 = KR[p, 1, 0], KR[p, 1, 1], KR[p, 1, 2], Kt[p, 1, 0]
        a20, a21, a22, a23 = KR[p, 2, 0], KR[p, 2, 1], KR[p, 2, 2], Kt[p, 2, 0]
        for e in range(points.shape[0]):
            acc = np.float32(0.0)
            count = 0
            if edge_keep[p, e]:
                for s in range(points.shape[1]):
                    if not visible[e, s]:
                        continue
                    x, y, z = points[e, s, 0], points[e, s, 1], points[e, s, 2]
                    hz = a20 * x + a21 * y + a22 * z + a23
                    if not hz > near:
                        continue
                    inv_z = one / hz
                    u = (a00 * x + a01 * y + a02 * z + a03) * inv_z
                    v = (a10 * x + a11 * y + a12 * z + a13) * inv_z
                    if not (u >= -half and u < u_max and v >= -half and v < v_max):
                        continue
                    d = lookup[int(v + half) * width + int(u + half)]
                    count += 1
                    if d <= threshold:
                        if gaussian:  # g(d) interpolated in its table (exp costs 3x the rest of a point)
                            t = d * steps_per_px
                            k = int(t)
                            acc += g_table[k] + (t - np.float32(k)) * (g_table[k + 1] - g_table[k])
                        else:
                            acc += one
            sums[p, e] = acc
            counts[p, e] = np.float32(count)


def compile_fused_kernel() -> None:
    """Compile (or load from numba's cache) the pass on a one-point problem. A tracker calls it when it is
    built, so that a service compiles before it subscribes (a cold compile takes seconds on a loaded host;
    met on the first frame, it let the estimator's queues overflow)."""
    one = np.ones((1, 1), dtype=bool)
    KR = np.eye(3, dtype=np.float32)[None]
    Kt = np.zeros((1, 3, 1), dtype=np.float32)
    point = np.array([[[0.0, 0.0, 1.0]]], dtype=np.float32)
    table = np.ones(2, dtype=np.float32)
    out = np.zeros((1, 1), dtype=np.float32), np.zeros((1, 1), dtype=np.float32)
    lookup = np.zeros(2, dtype=np.float32)
    _edge_sums(KR, Kt, point, one, one, 1, 1, lookup, True, np.float32(1.0), table, np.float32(1.0),
               np.float32(0.05), *out)  # fmt: skip


#: resolution of the table of g(d) (linear interpolation between entries: within 1e-5 of g)
_TABLE_STEPS_PER_PX = 64


def _normal_weight_table(params: ScoringSettings) -> Float32Array:
    """``g(d)`` (:func:`~common.localization.scoring.normal_weight`) at ``d = i / 64`` px up to the maximum
    normal length and one step beyond."""
    d = np.arange(params.max_normal_px * _TABLE_STEPS_PER_PX + 2, dtype=np.float32) / _TABLE_STEPS_PER_PX
    return np.asarray(np.exp(d * d * np.float32(-0.5 / params.sigma_px**2)), dtype=np.float32)


def fused_applies(camera: CameraModel, edges: ImageEdges, params: ScoringSettings) -> bool:
    """Whether :func:`fused_edge_sums` computes what the general path would."""
    return (
        not camera.is_distorted
        and edges.oriented_lookup is None
        and params.method is not ScoringMethod.NEAREST_EDGE
    )


def fused_edge_sums(
    samples: EdgeSamples,
    R_camera_world: FloatArray,
    p_world_camera: FloatArray,
    camera: CameraModel,
    edges: ImageEdges,
    params: ScoringSettings,
    visible: BoolArray | None = None,
    near_m: float = NEAR_PLANE_M,
) -> tuple[Float32Array, Float32Array]:
    """Per particle and kept edge: ``sum f(d)`` and the number of visible sample points (P, E') each."""
    edge_ids, edge_keep = kept_edges(samples, R_camera_world, p_world_camera, camera, near_m)
    KR, Kt = projection_matrices(R_camera_world, p_world_camera, camera)
    points = np.ascontiguousarray(samples.points_world_m[edge_ids], dtype=np.float32)
    shown = (
        np.ones(points.shape[:2], dtype=bool) if visible is None else np.ascontiguousarray(visible[edge_ids])
    )
    gaussian = params.method is ScoringMethod.NEAREST_EDGE_DT
    threshold = float(params.max_normal_px) if gaussian else params.align_px
    n = R_camera_world.shape[0]
    sums = np.empty((n, edge_ids.size), dtype=np.float32)
    counts = np.empty((n, edge_ids.size), dtype=np.float32)
    _edge_sums(
        KR,
        Kt,
        points,
        np.ascontiguousarray(edge_keep),
        shown,
        int(camera.width),
        int(camera.height),
        edges.distance_lookup,
        gaussian,
        np.float32(threshold),
        _normal_weight_table(params),
        np.float32(_TABLE_STEPS_PER_PX),
        np.float32(near_m),
        sums,
        counts,
    )
    return sums, counts


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
