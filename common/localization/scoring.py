"""Edge likelihoods of paper B: how well each particle's projected model edges match the camera image.

The image's edges are extracted once per frame (:func:`extract_image_edges`: Canny, plus the Euclidean
distance transform of the non-edge pixels). Each particle's projected sample points
(:class:`~common.localization.projection.ProjectedSamples`) are then scored, all particles at once, by one of
paper B's three methods (:class:`ScoringMethod`):

1. ``KLEIN_MURRAY``: a sample point is *aligned* when an image edge lies within ``align_px`` of it
   (a distance-transform lookup, exact for that definition); ``W ~ exp(k a / v)``.
2. ``PER_EDGE``: the same counts per model edge; ``W ~ exp(k a / v + lambda * mean_j(a_j / v_j))``.
3. ``NEAREST_EDGE``: from each sample point, search along the projected edge's normal (both ways, up to
   ``max_normal_px``) for the nearest image edge pixel; ``g(d) = exp(-d^2 / 2 sigma^2)``, a normal longer
   than the maximum is dropped (``g = 0``); per edge ``l = sum_i g(d_i) / S``;
   ``W = alpha exp(k mean_n l_n)``.

``NEAREST_EDGE_DT`` is the distance-transform fast path of method 3: ``d`` is the distance to the nearest
image edge pixel in any direction (one lookup instead of a walk along the normal). It is never larger than
the normal distance, and both agree whenever the nearest edge pixel lies on the normal -- the usual case near
the true pose, where model edges lie on image edges of the same direction. Tests check that both rank
rendered true poses above perturbed ones and rank particles alike (``tests/common/localization``).

Weights are returned as logarithms (``log W``) so that the filter can normalise them stably.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import numpy.typing as npt

from common.bounds import Bounded, bounded, setting
from common.errors import InputError
from common.images import check_grey_image
from common.localization.projection import ProjectedSamples
from common.types import BoolArray, Float32Array, FloatArray, U8Array


class ScoringMethod(enum.Enum):
    """Paper B's three image-closeness measures, plus the distance-transform fast path of the third."""

    KLEIN_MURRAY = "klein_murray"
    PER_EDGE = "per_edge"
    NEAREST_EDGE = "nearest_edge"
    NEAREST_EDGE_DT = "nearest_edge_dt"


@dataclass(frozen=True)
class ScoringSettings(Bounded):
    """Constants of the scorings (paper B's ``k``, ``lambda``, ``alpha``, ``sigma``, max normal length)."""

    method: ScoringMethod = setting(
        ScoringMethod.NEAREST_EDGE_DT,
        help="paper B's image-closeness measure (nearest_edge_dt: nearest edge through a distance transform)",
    )
    k: float = bounded(30.0, gt=0.0)
    lambda_per_edge: float = bounded(10.0, ge=0.0)
    alpha: float = bounded(1.0, ge=0.0)
    align_px: float = bounded(2.0, gt=0.0)
    sigma_px: float = bounded(2.0, gt=0.0)
    max_normal_px: int = bounded(10, ge=1)


@dataclass(frozen=True)
class ParticleSettings(Bounded):
    """What paper B's particle filter and the model tracker share: the particles and how they are scored
    (the model's edges sampled at ``points_per_edge`` points; particles scored in blocks of
    ``chunk_particles``, cache-sized temporaries)."""

    n_particles: int = bounded(200, ge=2, help="number of particles")
    points_per_edge: int = bounded(8, ge=1)
    scoring: ScoringSettings = field(default_factory=ScoringSettings)
    chunk_particles: int = bounded(256, ge=1)


@dataclass(frozen=True)
class ImageEdges:
    """Edges of one image: ``edge_map`` (H, W) uint8 (1 on an edge) and ``distance_px`` (H, W) float32.

    ``distance_lookup`` and ``edge_lookup`` are the flattened maps with one extra entry (``inf`` and 0) at
    index ``H * W``, where :class:`ProjectedSamples` points its invalid sample points.
    """

    edge_map: U8Array
    distance_px: Float32Array
    distance_lookup: Float32Array
    edge_lookup: U8Array
    #: Sobel image gradient (x, y) of every pixel (H, W) each (int16), when extracted ``with_gradients``
    gradient_x: npt.NDArray[np.int16] | None = None
    gradient_y: npt.NDArray[np.int16] | None = None
    #: per orientation bin (B, H * W + 1): distance to the nearest edge pixel of that gradient direction
    #: (:func:`with_oriented_distances`; None until asked for)
    oriented_lookup: Float32Array | None = None

    @property
    def width(self) -> int:
        return int(self.edge_map.shape[1])

    @property
    def height(self) -> int:
        return int(self.edge_map.shape[0])


@dataclass(frozen=True)
class ScoreResult:
    """Per particle: ``log_weight`` (P,) = log W of the chosen method, ``fit`` (P,) in [0, 1] (1 = best)."""

    log_weight: FloatArray
    fit: FloatArray


def extract_image_edges(
    image: npt.ArrayLike,
    canny_low: float = 40.0,
    canny_high: float = 100.0,
    with_gradients: bool = False,
    precise_distance: bool = True,
) -> ImageEdges:
    """Canny edges of a grey uint8 image and the distance (px) of every pixel to the nearest edge pixel;
    ``with_gradients`` adds the Sobel gradients (for oriented edge matching). ``precise_distance=False``
    takes OpenCV's 5x5 chamfer distance (within 2 % of the Euclidean distance, 1.6 ms instead of 4.2 ms at
    640x480, measured on one core)."""
    gray = check_grey_image(image, "image", min_side_px=8)
    gradient_x: npt.NDArray[np.int16] | None = None
    gradient_y: npt.NDArray[np.int16] | None = None
    if with_gradients:
        gradient_x = np.asarray(cv2.Sobel(gray, cv2.CV_16S, 1, 0), dtype=np.int16)
        gradient_y = np.asarray(cv2.Sobel(gray, cv2.CV_16S, 0, 1), dtype=np.int16)
        edges = cv2.Canny(gradient_x, gradient_y, canny_low, canny_high, L2gradient=True)
    else:
        edges = cv2.Canny(gray, canny_low, canny_high, L2gradient=True)
    distance: Float32Array = np.asarray(
        cv2.distanceTransform(
            np.where(edges > 0, 0, 255).astype(np.uint8),
            cv2.DIST_L2,
            cv2.DIST_MASK_PRECISE if precise_distance else cv2.DIST_MASK_5,
        ),
        dtype=np.float32,
    )
    edge_map = (edges > 0).astype(np.uint8)
    return ImageEdges(
        edge_map=edge_map,
        distance_px=distance,
        distance_lookup=np.append(distance.ravel(), np.float32(np.inf)),
        edge_lookup=np.append(edge_map.ravel(), np.uint8(0)),
        gradient_x=gradient_x,
        gradient_y=gradient_y,
    )


#: orientation bins of :func:`with_oriented_distances` (30 deg each over the half circle)
ORIENTATION_BINS = 6


def with_oriented_distances(edges: ImageEdges) -> ImageEdges:
    """The edges with one distance transform per gradient direction (directional chamfer matching, Liu et al.
    2010): each edge pixel joins the bin of its gradient direction (modulo 180 deg, either polarity) and the
    nearer neighbouring bin, so a lookup in the bin of a model edge's normal finds image edges within about
    15-45 deg of that direction. Texture and clutter of other directions then do not count as close."""
    if edges.gradient_x is None or edges.gradient_y is None:
        raise InputError("oriented distances need edges with gradients")
    bins = ORIENTATION_BINS
    angle = np.mod(
        np.arctan2(edges.gradient_y.astype(np.float32), edges.gradient_x.astype(np.float32)), np.pi
    )
    position = angle / np.float32(np.pi / bins)
    own = np.minimum(position.astype(np.int32), bins - 1)
    neighbour = np.where(position - own >= 0.5, own + 1, own - 1) % bins
    on_edge = edges.edge_map > 0
    maps = np.empty((bins, edges.edge_map.size + 1), dtype=np.float32)
    for b in range(bins):
        member = on_edge & ((own == b) | (neighbour == b))
        d = cv2.distanceTransform(np.where(member, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
        maps[b, :-1] = d.ravel()
        maps[b, -1] = np.inf
    return replace(edges, oriented_lookup=maps)


def orientation_bins(normal_u: npt.ArrayLike, normal_v: npt.ArrayLike) -> npt.NDArray[np.int32]:
    """The orientation bin (0 .. ORIENTATION_BINS - 1) of image normals (0 for undefined ones)."""
    angle = np.mod(np.arctan2(np.asarray(normal_v), np.asarray(normal_u)), np.pi)
    angle = np.where(np.isfinite(angle), angle, 0.0)  # culled points carry nan normals
    b = np.minimum((angle / (np.pi / ORIENTATION_BINS)).astype(np.int32), ORIENTATION_BINS - 1)
    return np.asarray(b, dtype=np.int32)


def oriented_distances(projected: ProjectedSamples, edges: ImageEdges) -> Float32Array:
    """Distance (px) from each sample point to the nearest image edge pixel of its projected edge's normal
    direction (P, E', S); ``inf`` for invalid points. Needs :func:`with_oriented_distances` and normals."""
    if edges.oriented_lookup is None or projected.normal_u is None or projected.normal_v is None:
        raise InputError("oriented distances need with_oriented_distances edges and projected normals")
    b = orientation_bins(projected.normal_u, projected.normal_v)
    flat = b * np.int32(edges.oriented_lookup.shape[1]) + projected.pixel_index
    return np.asarray(np.take(edges.oriented_lookup.ravel(), flat, mode="clip"))


def _pixel_index(u_px: Float32Array, v_px: Float32Array, width: int) -> npt.NDArray[np.int32]:
    """Flat index of the pixel nearest to each point (points must lie inside the image)."""
    column = (u_px + np.float32(0.5)).astype(np.int32)
    row = (v_px + np.float32(0.5)).astype(np.int32)
    return np.asarray(row * np.int32(width) + column)


def distance_transform_distances(projected: ProjectedSamples, edges: ImageEdges) -> Float32Array:
    """Distance (px) from each sample point to the nearest image edge pixel (P, E', S), one lookup each;
    ``inf`` for invalid points."""
    if edges.width * edges.height != int(edges.distance_lookup.size) - 1:
        raise InputError("ImageEdges lookup tables do not match the edge map")
    return np.asarray(np.take(edges.distance_lookup, projected.pixel_index, mode="clip"))


def normal_search_distances(
    projected: ProjectedSamples, edges: ImageEdges, max_normal_px: int
) -> Float32Array:
    """Paper B method 3's normal search: distance (px) along each point's image normal to the nearest image
    edge pixel, searching both ways in 1 px steps up to ``max_normal_px``; ``inf`` where none is found."""
    if projected.normal_u is None or projected.normal_v is None:
        raise InputError(
            "normal search needs ProjectedSamples with normals (project_samples(with_normals=True))"
        )
    flat = edges.edge_lookup
    distance = np.full(projected.u_px.shape, np.inf, dtype=np.float32)
    unresolved = projected.valid.copy()
    for step in range(max_normal_px + 1):
        if not unresolved.any():
            break
        for sign in (1.0, -1.0) if step > 0 else (1.0,):
            offset = np.float32(sign * step)
            u = projected.u_px + offset * projected.normal_u
            v = projected.v_px + offset * projected.normal_v
            inside = (u >= -0.5) & (u < edges.width - 0.5) & (v >= -0.5) & (v < edges.height - 0.5)
            # culled points carry nan coordinates: index only the points inside (casting nan is undefined)
            u_in = np.where(inside, u, np.float32(0.0))
            v_in = np.where(inside, v, np.float32(0.0))
            index = np.where(
                inside, _pixel_index(u_in, v_in, edges.width), np.int32(edges.width * edges.height)
            )
            hit = unresolved & (np.take(flat, index, mode="clip") > 0)
            distance[hit] = np.float32(step)
            unresolved &= ~hit
    return distance


def per_edge_sum(values: npt.NDArray[np.bool_] | Float32Array) -> Float32Array:
    """Sum over each edge's sample points (last axis): (P, E, S) -> (P, E) float32.

    ``einsum`` is about 5x faster than ``sum(axis=2)`` over such a short last axis; booleans are summed
    through a uint8 view (exact while S < 256).
    """
    if values.dtype == np.bool_ and values.shape[-1] < 256:
        return np.asarray(np.einsum("pes->pe", values.view(np.uint8)), dtype=np.float32)
    return np.asarray(np.einsum("pes->pe", values.astype(np.float32, copy=False)), dtype=np.float32)


def normal_weight(distance_px: Float32Array, sigma_px: float, max_normal_px: float) -> Float32Array:
    """Weight of one normal, paper B method 3: ``g(d) = exp(-d^2 / (2 sigma^2))``; normals longer than the
    maximum length are dropped (weight 0)."""
    d = np.minimum(distance_px, np.float32(max_normal_px + 1.0))
    g = np.exp(d * d * np.float32(-0.5 / sigma_px**2))
    return np.asarray(np.where(distance_px <= max_normal_px, g, np.float32(0.0)))


def klein_murray_log_weight(aligned: FloatArray, visible: FloatArray, k: float) -> FloatArray:
    """Paper B method 1 (Klein & Murray): ``W = p(y|x) ~ exp(k a / v)``, a = aligned edge samples,
    v = visible edge samples. Returns ``k a / v`` (0 where nothing is visible)."""
    return np.asarray(k * aligned / np.maximum(visible, 1.0))


def per_edge_log_weight(
    aligned_per_edge: FloatArray, visible_per_edge: FloatArray, k: float, lambda_per_edge: float
) -> FloatArray:
    """Paper B method 2 (per edge): ``W ~ exp(k a / v + lambda * (sum_j a_j / v_j) / m)`` over the m visible
    edges. Inputs are (P, E) counts; returns the exponent (P,)."""
    a = aligned_per_edge.sum(axis=1)
    v = visible_per_edge.sum(axis=1)
    seen = visible_per_edge > 0
    m = np.maximum(seen.sum(axis=1), 1)
    ratios = np.where(seen, aligned_per_edge / np.maximum(visible_per_edge, 1.0), 0.0).sum(axis=1)
    return np.asarray(k * a / np.maximum(v, 1.0) + lambda_per_edge * ratios / m)


def nearest_edge_log_weight(
    normal_weights: Float32Array, valid: BoolArray, k: float, alpha: float
) -> tuple[FloatArray, FloatArray]:
    """Paper B method 3 (nearest edge) of per-point weights (P, E', S) and validity; see
    :func:`nearest_edge_log_weight_of_sums`. ``normal_weights`` must be 0 at invalid points."""
    return nearest_edge_log_weight_of_sums(per_edge_sum(normal_weights), per_edge_sum(valid), k, alpha)


def nearest_edge_log_weight_of_sums(
    g_sum: Float32Array, s: Float32Array, k: float, alpha: float
) -> tuple[FloatArray, FloatArray]:
    """Paper B method 3 (nearest edge): per line ``l_n = sum_i g(d_i) / S`` over its S visible sample points,
    ``W = alpha exp(k sum_n l_n / m)`` over the m visible lines. Inputs are per line (P, E): ``sum_i g(d_i)``
    and S. Returns (log W, mean l) per particle."""
    seen = s > 0
    lines = np.where(seen, g_sum / np.maximum(s, np.float32(1.0)), np.float32(0.0))
    m = np.maximum(seen.sum(axis=1), 1)
    mean_l = lines.sum(axis=1, dtype=np.float64) / m
    return np.log(alpha) + k * mean_l, mean_l


def score_particles(projected: ProjectedSamples, edges: ImageEdges, params: ScoringSettings) -> ScoreResult:
    """log W (P,) and fit (P,) of every particle by ``params.method``; on edges with oriented distances
    (:func:`with_oriented_distances`) the distances are the oriented ones (method 3 then as its
    distance-transform path)."""
    method = params.method
    valid = projected.valid
    if edges.oriented_lookup is not None:
        distance = oriented_distances(projected, edges)
        if method is ScoringMethod.NEAREST_EDGE:
            method = ScoringMethod.NEAREST_EDGE_DT  # the oriented lookup replaces the normal walk
    elif method is ScoringMethod.NEAREST_EDGE:
        distance = normal_search_distances(projected, edges, params.max_normal_px)
    else:
        distance = distance_transform_distances(projected, edges)
    if method in (ScoringMethod.NEAREST_EDGE, ScoringMethod.NEAREST_EDGE_DT):
        g = normal_weight(distance, params.sigma_px, params.max_normal_px)
        log_w, mean_l = nearest_edge_log_weight(g, valid, params.k, params.alpha)
        return ScoreResult(log_weight=log_w, fit=mean_l)
    aligned = distance <= np.float32(params.align_px)  # invalid points have distance inf
    if method is ScoringMethod.KLEIN_MURRAY:
        a = per_edge_sum(aligned).sum(axis=1, dtype=np.float64)
        v = per_edge_sum(valid).sum(axis=1, dtype=np.float64)
        return ScoreResult(log_weight=klein_murray_log_weight(a, v, params.k), fit=a / np.maximum(v, 1.0))
    a_j = per_edge_sum(aligned).astype(np.float64)
    v_j = per_edge_sum(valid).astype(np.float64)
    log_w = per_edge_log_weight(a_j, v_j, params.k, params.lambda_per_edge)
    return ScoreResult(log_weight=log_w, fit=a_j.sum(axis=1) / np.maximum(v_j.sum(axis=1), 1.0))
