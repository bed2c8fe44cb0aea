"""Hidden-line removal: which model edge sample points the model's own faces hide from a camera.

:func:`rasterize_faces` fills a z-buffer of the model's faces (inverse depth per pixel, the front face's
index) for one camera pose: each front-facing face is clipped at the near plane, projected, filled (the
pixels whose centres lie inside, :func:`_centres_inside`) in its bounding box, and kept where its inverse
depth (affine in the pixel coordinates for a planar face) beats the buffer. The simulator renders its images
with the same function.

:func:`visible_points` uses it at low resolution (a quarter of the image by default) from one pose -- the
cloud's predicted mean -- and marks a sample point hidden when every buffer pixel in its 3x3 neighbourhood
is nearer than the point by more than a relative tolerance. The neighbourhood makes the test generous along
occluding contours (where a coarse pixel mixes both sides), the tolerance keeps a point on its own face
visible. One pose serves the whole cloud: particles lie within a few millimetres and tenths of a degree of
it while tracking, where visibility barely changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.localization.model import SceneModel
from common.types import BoolArray, FloatArray

IntArray = npt.NDArray[np.int32]

#: A sample point is hidden when the buffer is nearer by more than this fraction of the point's depth.
HIDDEN_DEPTH_TOLERANCE = 0.01


@dataclass(frozen=True)
class RasterLayers:
    """Per pixel: index of the visible face (-1 for none) and its inverse depth (1/m, 0 for none)."""

    face_id: IntArray
    inverse_depth: FloatArray


def _clip_near(polygon_camera: FloatArray, near_m: float) -> FloatArray:
    """Sutherland-Hodgman clipping of a camera-frame polygon (K, 3) to ``z >= near_m``."""
    out: list[FloatArray] = []
    count = polygon_camera.shape[0]
    for i in range(count):
        a = polygon_camera[i]
        b = polygon_camera[(i + 1) % count]
        a_in, b_in = a[2] >= near_m, b[2] >= near_m
        if a_in:
            out.append(a)
        if a_in != b_in:
            t = (near_m - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def _centres_inside(
    u: FloatArray, v: FloatArray, width: int, height: int
) -> tuple[tuple[int, int, int, int], BoolArray] | None:
    """The pixels of a ``width x height`` image whose centres lie inside the polygon with pixel vertices
    ``(u, v)`` (K,): its bounding box ``(x0, x1, y0, y1)`` (half-open, clipped to the image) and mask, or None
    when no pixel centre is inside the box.

    Crossing-number test on the pixel centres (a centre on a left or top side counts as inside, on a right or
    bottom side as outside, so faces sharing a side do not overlap): a step in the image lies exactly on the
    projected side, as a camera integrating light over its pixels would see it. ``cv2.fillPoly`` instead fills
    every pixel within half a pixel of the polygon: faces came out a pixel too large, which biased the
    sub-pixel refinement by half a pixel at every silhouette.
    """
    x0, x1 = max(int(np.ceil(u.min())), 0), min(int(np.floor(u.max())) + 1, width)
    y0, y1 = max(int(np.ceil(v.min())), 0), min(int(np.floor(v.max())) + 1, height)
    if x0 >= x1 or y0 >= y1:
        return None
    nx, ny = x1 - x0, y1 - y0
    ys = np.arange(y0, y1, dtype=np.float64)
    u_next, v_next = np.roll(u, -1), np.roll(v, -1)
    # per side, the rows whose centre line it crosses (half-open in v) and where: a centre is inside when an
    # odd number of sides cross its row to its right (column < ceil(crossing))
    spans = (v[:, None] <= ys[None, :]) != (v_next[:, None] <= ys[None, :])  # (K, rows)
    side, rows = np.nonzero(spans)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = u[side] + (ys[rows] - v[side]) * (u_next[side] - u[side]) / (v_next[side] - v[side])
    first_outside = np.clip(np.ceil(crossing) - x0, 0, nx).astype(np.int64)
    # counts per pixel by a difference array: +1 at each crossed row's start, -1 after its last column
    diff = np.bincount(rows * (nx + 1), minlength=ny * (nx + 1))
    diff -= np.bincount(rows * (nx + 1) + first_outside, minlength=ny * (nx + 1))
    inside = (np.cumsum(diff.astype(np.int16).reshape(ny, nx + 1)[:, :nx], axis=1) & 1).astype(bool)
    return (x0, x1, y0, y1), inside


def rasterize_faces(
    scene: SceneModel,
    R_camera_world: FloatArray,
    p_world_camera_m: FloatArray,
    camera: CameraModel,
    near_m: float = 0.05,
) -> RasterLayers:
    """Visible face and inverse depth of every pixel of the pinhole ``camera`` (distortion ignored)."""
    height, width = int(camera.height), int(camera.width)
    face_id = np.full((height, width), -1, dtype=np.int32)
    inverse_depth = np.zeros((height, width), dtype=np.float64)
    x_norm = (np.arange(width) - camera.cx) / camera.fx
    y_norm = (np.arange(height) - camera.cy) / camera.fy
    front = scene.face_normals @ p_world_camera_m - scene.face_offsets_m > 1e-9
    for f in np.flatnonzero(front):
        polygon = (scene.face_polygon_world_m(int(f)) - p_world_camera_m) @ R_camera_world.T
        polygon = _clip_near(polygon, near_m)
        if polygon.shape[0] < 3:
            continue
        u = camera.fx * polygon[:, 0] / polygon[:, 2] + camera.cx
        v = camera.fy * polygon[:, 1] / polygon[:, 2] + camera.cy
        inside = _centres_inside(u, v, width, height)
        if inside is None:
            continue
        (x0, x1, y0, y1), mask = inside
        # plane n_c . X = d_c in the camera frame; along the ray (x_n, y_n, 1): 1/z = (n_c . ray) / d_c
        normal_camera = R_camera_world @ scene.face_normals[f]
        d_camera = float(normal_camera @ polygon[0])
        inv_z = (
            normal_camera[0] * x_norm[None, x0:x1] + normal_camera[1] * y_norm[y0:y1, None] + normal_camera[2]
        ) / d_camera
        region_depth = inverse_depth[y0:y1, x0:x1]
        closer = mask & (inv_z > region_depth)
        region_depth[closer] = inv_z[closer]
        face_id[y0:y1, x0:x1][closer] = f
    return RasterLayers(face_id=face_id, inverse_depth=inverse_depth)


def visible_points(
    scene: SceneModel,
    points_world_m: FloatArray,
    R_camera_world: FloatArray,
    p_world_camera_m: FloatArray,
    camera: CameraModel,
    scale: float = 0.25,
    tolerance: float = HIDDEN_DEPTH_TOLERANCE,
) -> BoolArray:
    """Which of the points (..., 3) the scene's faces do not hide from this camera (hidden-line removal).

    Points behind the camera or outside the image count as visible (other culling handles them).
    """
    if scene.n_faces == 0:
        return np.ones(points_world_m.shape[:-1], dtype=bool)
    small = camera.pinhole().scaled(scale)
    layers = rasterize_faces(scene, R_camera_world, p_world_camera_m, small)
    farthest = cv2.erode(layers.inverse_depth.astype(np.float32), np.ones((3, 3), np.uint8))
    flat = points_world_m.reshape(-1, 3)
    pc = (flat - p_world_camera_m) @ R_camera_world.T
    z = pc[:, 2]
    ahead = z > 1e-6
    safe_z = np.where(ahead, z, 1.0)
    col = np.rint(small.fx * pc[:, 0] / safe_z + small.cx).astype(np.int64)
    row = np.rint(small.fy * pc[:, 1] / safe_z + small.cy).astype(np.int64)
    inside = ahead & (col >= 0) & (col < small.width) & (row >= 0) & (row < small.height)
    buffer = np.zeros(flat.shape[0], dtype=np.float64)
    buffer[inside] = farthest[row[inside], col[inside]]
    hidden = inside & (buffer * (1.0 - tolerance) > 1.0 / safe_z)
    return np.asarray(~hidden).reshape(points_world_m.shape[:-1])
