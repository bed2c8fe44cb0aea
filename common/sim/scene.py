"""Camera images of a known 3D scene (:class:`~common.localization.model.SceneModel`) and flights through it.

:func:`render_scene` rasterises the scene's faces with a small z-buffer: each front-facing face is clipped at
the near plane, projected, filled (pixels whose centres lie inside) in its bounding box, and kept where its
inverse depth (affine in the pixel coordinates for a planar face) beats the buffer. Faces are shaded with a
half-Lambert directional light (so that every box side has its own brightness), then optional
world-attached texture noise, Gaussian blur and Gaussian sensor noise are applied.

:func:`default_flight` is the embedded default trajectory: an ellipse around the centre of the built-in
office with slow height, yaw, roll and pitch oscillations; :func:`render_flight` renders its frames.

Poses are particle-style states ``(x, y, z, roll, pitch, yaw)`` of the body in the world (m, rad); the camera
sits at the body origin rotated by ``R_body_camera`` (forward-looking by default).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.camera_maps import through_lens_maps
from common.errors import InputError
from common.geometry import R_BODY_CAMERA_FORWARD, matrix_from_euler, wrap_angle_rad
from common.localization.model import SceneModel
from common.localization.projection import NEAR_PLANE_M, check_states
from common.localization.visibility import RasterLayers, rasterize_faces
from common.types import FloatArray, U8Array

IntArray = npt.NDArray[np.int32]


@dataclass(frozen=True)
class RenderOptions:
    """Lighting and degradations of a rendered frame (grey levels are 0..255)."""

    light_direction_world: tuple[float, float, float] = (0.35, 0.55, 0.76)
    ambient: float = 0.3
    diffuse: float = 0.7
    texture_amplitude: float = 0.0
    noise_sigma: float = 0.0
    blur_sigma_px: float = 0.0
    background: float = 0.0
    texture_frequency: float = 1.0


def rasterize_scene(
    scene: SceneModel,
    state: npt.ArrayLike,
    camera: CameraModel,
    R_body_camera: FloatArray = R_BODY_CAMERA_FORWARD,
    near_m: float = NEAR_PLANE_M,
) -> RasterLayers:
    """Visible face and inverse depth of every pixel (z-buffer) from one body pose ``(x, y, z, r, p, y)``."""
    pose = check_states(state, "state")[0]
    R_world_camera = matrix_from_euler(pose[3], pose[4], pose[5]) @ R_body_camera
    return rasterize_faces(scene, R_world_camera.T, pose[:3], camera, near_m)


def face_shades(scene: SceneModel, options: RenderOptions) -> FloatArray:
    """Grey level (0..255) of every face: albedo x (ambient + diffuse x half-Lambert term)."""
    light = np.asarray(options.light_direction_world, dtype=np.float64)
    light = light / np.linalg.norm(light)
    half_lambert = 0.5 + 0.5 * (scene.face_normals @ light)
    return np.asarray(255.0 * scene.face_albedo * (options.ambient + options.diffuse * half_lambert))


def _texture(points_world_m: FloatArray, frequency: float = 1.0) -> FloatArray:
    """Smooth world-attached pattern in [-1, 1] (a product of three plane waves; ``frequency`` scales it)."""
    x, y, z = (frequency * points_world_m[..., i] for i in range(3))
    return np.asarray(
        np.sin(7.3 * x + 3.1 * y + 5.7 * z)
        * np.sin(4.1 * x - 6.9 * y + 2.3 * z + 1.3)
        * np.sin(2.7 * y - 5.3 * z + 0.7)
    )


def render_scene(
    scene: SceneModel,
    state: npt.ArrayLike,
    camera: CameraModel,
    options: RenderOptions = RenderOptions(),
    rng: np.random.Generator | None = None,
    R_body_camera: FloatArray = R_BODY_CAMERA_FORWARD,
) -> U8Array:
    """Grey uint8 image (H, W) of the scene from a body pose; ``rng`` is needed when ``noise_sigma > 0``."""
    pose = check_states(state, "state")[0]
    R_world_camera = matrix_from_euler(pose[3], pose[4], pose[5]) @ R_body_camera
    return render_view(scene, R_world_camera, pose[:3], camera, options, rng)


def render_view(
    scene: SceneModel,
    R_world_camera: FloatArray,
    p_world_camera_m: FloatArray,
    camera: CameraModel,
    options: RenderOptions = RenderOptions(),
    rng: np.random.Generator | None = None,
) -> U8Array:
    """Grey uint8 image (H, W) of the scene from a camera pose, through the camera's lens (a distorted camera
    gets the pinhole rendering remapped by its distortion model)."""
    pinhole = camera.pinhole()
    layers = rasterize_faces(scene, R_world_camera.T, p_world_camera_m, pinhole)
    shades = np.append(face_shades(scene, options), options.background)
    image = shades[layers.face_id]  # face -1 picks the background
    if options.texture_amplitude > 0.0:
        hit = layers.face_id >= 0
        rows, cols = np.nonzero(hit)
        rays = np.stack(
            [(cols - camera.cx) / camera.fx, (rows - camera.cy) / camera.fy, np.ones(cols.size)], axis=1
        )
        # einsum, not a BLAS matmul: (N x 3) @ (3 x 3) woke the BLAS thread pool (240 ms on a busy host)
        scaled = rays / layers.inverse_depth[rows, cols][:, None]
        points = p_world_camera_m + np.einsum("ni,ji->nj", scaled, R_world_camera)
        image[rows, cols] += options.texture_amplitude * _texture(points, options.texture_frequency)
    if camera.is_distorted:
        image = cv2.remap(image.astype(np.float32), *through_lens_maps(camera), cv2.INTER_LINEAR)
    if options.blur_sigma_px > 0.0:
        image = cv2.GaussianBlur(image, (0, 0), options.blur_sigma_px)
    if options.noise_sigma > 0.0:
        if rng is None:
            raise InputError("render_scene needs an rng when noise_sigma > 0")
        image = image + rng.normal(0.0, options.noise_sigma, size=image.shape)
    return np.asarray(np.clip(np.rint(image), 0, 255), dtype=np.uint8)


#: Degradations of the embedded default flight's frames.
DEFAULT_FLIGHT_RENDER = RenderOptions(texture_amplitude=6.0, noise_sigma=2.0, blur_sigma_px=0.8)


@dataclass(frozen=True)
class SampledFlight:
    """Ground truth sampled at ``times_s`` (T,), one frame per stamp (subclasses add what is sampled)."""

    times_s: FloatArray

    @property
    def n_frames(self) -> int:
        return int(self.times_s.size)


@dataclass(frozen=True)
class SceneFlight(SampledFlight):
    """Ground truth of a flight: ``states`` (T, 6) body poses, ``velocities_world_m_s`` (T, 3) and
    ``euler_rates_rad_s`` (T, 3) (time derivatives of roll, pitch, yaw) at ``times_s`` (T,)."""

    states: FloatArray
    velocities_world_m_s: FloatArray
    euler_rates_rad_s: FloatArray


def default_flight(
    n_frames: int = 300,
    rate_hz: float = 20.0,
    centre_world_m: tuple[float, float] = (5.0, 4.0),
    radii_m: tuple[float, float] = (2.2, 1.6),
    height_m: float = 1.5,
) -> SceneFlight:
    """An ellipse around the office's centre at about 1.5 m (one lap in 15 s), the camera looking out.

    Yaw follows the heading turned 40 deg outwards plus a slow swing; height, roll and pitch oscillate a
    little. Velocities and Euler rates are exact derivatives (for odometry-driven prediction).
    """
    if n_frames < 2 or rate_hz <= 0.0:
        raise InputError(f"need n_frames >= 2 and rate_hz > 0, got {n_frames}, {rate_hz}")
    t = np.arange(n_frames) / rate_hz
    omega = 2.0 * np.pi / 15.0
    phase = omega * t
    cx, cy = centre_world_m
    ax, ay = radii_m
    x = cx + ax * np.cos(phase)
    y = cy + ay * np.sin(phase)
    z = height_m + 0.2 * np.sin(2.0 * np.pi * t / 6.0)
    vx = -ax * omega * np.sin(phase)
    vy = ay * omega * np.cos(phase)
    vz = 0.2 * (2.0 * np.pi / 6.0) * np.cos(2.0 * np.pi * t / 6.0)
    heading = np.arctan2(vy, vx)
    # heading rate of an ellipse: (vx ay' - vy ax') / |v|^2 with accelerations
    axx = -ax * omega**2 * np.cos(phase)
    ayy = -ay * omega**2 * np.sin(phase)
    heading_rate = (vx * ayy - vy * axx) / (vx**2 + vy**2)
    swing_w = 2.0 * np.pi / 7.0
    yaw = wrap_angle_rad(heading - np.radians(40.0) + 0.3 * np.sin(swing_w * t))
    yaw_rate = heading_rate + 0.3 * swing_w * np.cos(swing_w * t)
    tilt_w = 2.0 * np.pi / 5.0
    roll = np.radians(3.0) * np.sin(tilt_w * t)
    pitch = np.radians(2.0) * np.cos(1.3 * tilt_w * t)
    roll_rate = np.radians(3.0) * tilt_w * np.cos(tilt_w * t)
    pitch_rate = -np.radians(2.0) * 1.3 * tilt_w * np.sin(1.3 * tilt_w * t)
    return SceneFlight(
        times_s=t,
        states=np.stack([x, y, z, roll, pitch, yaw], axis=1),
        velocities_world_m_s=np.stack([vx, vy, vz], axis=1),
        euler_rates_rad_s=np.stack([roll_rate, pitch_rate, yaw_rate], axis=1),
    )


def render_flight(
    scene: SceneModel,
    flight: SceneFlight,
    camera: CameraModel,
    options: RenderOptions = DEFAULT_FLIGHT_RENDER,
    rng: np.random.Generator | None = None,
    R_body_camera: FloatArray = R_BODY_CAMERA_FORWARD,
) -> Iterator[U8Array]:
    """Frames of a flight, one per ground-truth state, in order."""
    for state in flight.states:
        yield render_scene(scene, state, camera, options, rng, R_body_camera)
