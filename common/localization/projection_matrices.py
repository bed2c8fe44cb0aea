"""Each particle's camera as one matrix product: ``K R`` and ``-K R p`` in float32, compiled.

Its own module so that numba is imported only when a process first projects (:func:`projection_matrices`):
a process that renders scenes but never projects particles (the camera) does not load it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from common.camera import CameraModel
from common.types import Float32Array, FloatArray


def _projection_matrices(  # pragma: no cover - compiled; tested through projection_matrices
    R: FloatArray, p: FloatArray, fx: float, fy: float, cx: float, cy: float
) -> tuple[Float32Array, Float32Array]:
    n = R.shape[0]
    KR = np.empty((n, 3, 3), dtype=np.float32)
    Kt = np.empty((n, 3, 1), dtype=np.float32)
    row = np.empty((3, 3))
    for i in range(n):
        for k in range(3):  # K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]: its zero terms left out
            row[0, k] = fx * R[i, 0, k] + cx * R[i, 2, k]
            row[1, k] = fy * R[i, 1, k] + cy * R[i, 2, k]
            row[2, k] = R[i, 2, k]
        for j in range(3):
            Kt[i, j, 0] = np.float32(-((row[j, 0] * p[i, 0] + row[j, 1] * p[i, 1]) + row[j, 2] * p[i, 2]))
            for k in range(3):
                KR[i, j, k] = np.float32(row[j, k])
    return KR, Kt


@functools.cache
def _compiled_projection_matrices() -> Callable[..., tuple[Float32Array, Float32Array]]:
    """:func:`_projection_matrices` compiled, on the first projection: numba is imported then, so that a
    process that only renders scenes (the camera) does not load it (about 1.2 s of CPU per process)."""
    from numba import njit

    return njit(cache=True, nogil=True)(_projection_matrices)


def projection_matrices(
    R_camera_world: FloatArray, p_world_camera: FloatArray, camera: CameraModel
) -> tuple[Float32Array, Float32Array]:
    """``K R`` (P, 3, 3) and ``-K R p`` (P, 3, 1) in float32: one product gives ``(u z, v z, z)`` of a world
    point in every particle's camera (K folded into the rotation). Computed in float64 and rounded once
    (compiled: numpy's einsum cost 0.2 us per particle here); both weighting paths project with these."""
    return _compiled_projection_matrices()(
        np.ascontiguousarray(R_camera_world, dtype=np.float64),
        np.ascontiguousarray(p_world_camera, dtype=np.float64),
        float(camera.fx),
        float(camera.fy),
        float(camera.cx),
        float(camera.cy),
    )
