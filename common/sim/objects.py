"""Object-scale simulation for the localizer: a tabletop model, clutter that is not in it, flights around it.

:func:`tabletop_model` is the model a user would have (its CAD model): a 32 x 20 x 20 cm part on a table,
made of an L-shaped base (a non-convex top face), a tower standing on the base's arm (it hides base edges
from many views), a U-shaped bracket with an inner channel (concave, self-occluding) and a 16-facet cylinder
(smooth sides: only its limbs are edges). World frame: z up, the table top at ``z = 0``, the part around the
origin; metres.

:func:`tabletop_scene` is what the camera sees: the model plus clutter the localizer does not know (the
table top with markings, two boxes beside the part, a back wall), all with world-attached texture.

:func:`object_flight` flies a camera around the part at 0.45-0.9 m, looking at it (with a wandering aim and
roll), at 30 fps, moving at most 20 mm and 2 deg per frame; deterministic by seed, exact poses
(``p_world_camera_m``, ``R_world_camera``; OpenCV camera frame). :func:`kidnap` teleports the camera from a
frame on (the bench's kidnap test).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.errors import InputError
from common.localization.model import SceneModel, build_scene, scene_from_dict, scene_to_dict
from common.localization.pose import CameraPose, perturb, rotation_angle_rad, rotation_vectors
from common.sim.scene import RenderOptions, SampledFlight, render_view
from common.sim.sensors import ImuNoise
from common.types import FloatArray, U8Array

#: Where the flights aim: a little above the part's centre (m).
OBJECT_CENTRE_M = (0.0, 0.0, 0.07)
#: Frame rate of the object flights.
OBJECT_RATE_HZ = 30.0
#: Largest motion between two frames of an object flight.
MAX_STEP_M = 0.020
MAX_STEP_RAD = float(np.radians(2.0))

#: Degradations of the object flight's frames (texture frequency for centimetre-scale detail).
OBJECT_RENDER = RenderOptions(
    texture_amplitude=10.0, texture_frequency=12.0, noise_sigma=2.0, blur_sigma_px=0.8, background=40.0
)


def object_camera() -> CameraModel:
    """The object flights' camera: 640 x 480, a calibrated-looking pinhole (fx != fy, off-centre)."""
    return CameraModel(width=640, height=480, fx=612.0, fy=609.5, cx=322.3, cy=236.8)


class _Faces:
    """Accumulates faces (vertex loops counter-clockwise from outside), albedo and smooth groups."""

    def __init__(self) -> None:
        self.vertices: list[list[float]] = []
        self.faces: list[list[int]] = []
        self.albedo: list[float] = []
        self.groups: list[int] = []

    def face(self, points: Sequence[npt.ArrayLike], albedo: float, group: int = -1) -> None:
        start = len(self.vertices)
        self.vertices.extend([np.asarray(p, dtype=np.float64).tolist() for p in points])
        self.faces.append(list(range(start, start + len(points))))
        self.albedo.append(albedo)
        self.groups.append(group)

    def prism(
        self,
        outline: Sequence[Sequence[float]],
        origin: Sequence[float],
        axis_u: Sequence[float],
        axis_v: Sequence[float],
        depth_m: float,
        albedo: float,
        cap_albedo: float | None = None,
        bottom: bool = True,
    ) -> None:
        """A prism: a counter-clockwise 2D ``outline`` in the plane ``origin + a axis_u + b axis_v`` extruded
        by ``depth_m`` along ``axis_u x axis_v``; caps at both ends (the first one optional)."""
        o, u, v = (np.asarray(x, dtype=np.float64) for x in (origin, axis_u, axis_v))
        w = np.cross(u, v) * depth_m
        ring = [o + a * u + b * v for a, b in outline]
        far = [p + w for p in ring]
        cap = albedo if cap_albedo is None else cap_albedo
        if bottom:
            self.face(ring[::-1], cap)
        self.face(far, cap)
        n = len(ring)
        for i in range(n):
            j = (i + 1) % n
            self.face([ring[i], ring[j], far[j], far[i]], albedo)

    def cylinder(
        self, centre: Sequence[float], radius_m: float, height_m: float, albedo: float, group: int
    ) -> None:
        """A vertical 16-facet cylinder standing at ``centre`` (smooth sides, a top cap)."""
        angles = np.linspace(0.0, 2.0 * np.pi, 17)[:-1]
        c = np.asarray(centre, dtype=np.float64)
        ring = [c + radius_m * np.array([np.cos(a), np.sin(a), 0.0]) for a in angles]
        top = [p + np.array([0.0, 0.0, height_m]) for p in ring]
        self.face(top, albedo * 1.1)
        for i in range(16):
            j = (i + 1) % 16
            self.face([ring[i], ring[j], top[j], top[i]], albedo, group)

    def box(self, lo: Sequence[float], hi: Sequence[float], albedo: float) -> None:
        """An axis-aligned box without a bottom face."""
        self.prism(
            [(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])],
            (0.0, 0.0, lo[2]),
            (1.0, 0.0, 0.0),
            (0.0, 1.0, 0.0),
            hi[2] - lo[2],
            albedo,
            bottom=False,
        )

    def build(self, name: str) -> SceneModel:
        return build_scene(self.vertices, self.faces, self.albedo, name=name, face_groups=self.groups)


def _model_faces() -> _Faces:
    f = _Faces()
    # L-shaped base, 6 cm high (its top face is non-convex: triangulated by build_scene)
    base = [(-0.16, -0.10), (0.16, -0.10), (0.16, 0.0), (-0.04, 0.0), (-0.04, 0.10), (-0.16, 0.10)]
    f.prism(base, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), 0.06, 0.55, cap_albedo=0.7, bottom=False)
    # tower on the base's arm
    f.box((-0.14, 0.02, 0.06), (-0.06, 0.08, 0.20), 0.35)
    # U-shaped bracket on the long arm: outline in (x, z), extruded along +y
    u_shape = [
        (0.02, 0.06), (0.14, 0.06), (0.14, 0.16), (0.11, 0.16), (0.11, 0.09), (0.05, 0.09), (0.05, 0.16),
        (0.02, 0.16),
    ]  # fmt: skip
    # plane axes x and z with normal x cross z = -y: start at y = -0.03 and extrude towards -y
    f.prism(u_shape, (0.0, -0.03, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.06, 0.8, bottom=True)
    # cylinder on the table, beside the base's short arm
    f.cylinder((0.06, 0.06, 0.0), 0.025, 0.09, 0.25, group=1)
    return f


def tabletop_model() -> SceneModel:
    """The tabletop part (the model the localizer is given)."""
    return _model_faces().build("tabletop")


def tabletop_scene(with_part: bool = True) -> SceneModel:
    """What the camera sees: the part plus clutter that is not in the model (only the clutter when
    ``with_part`` is False: frames where the object is gone, for loss detection)."""
    f = _model_faces() if with_part else _Faces()
    f.face([(-0.8, -0.8, 0.0), (0.8, -0.8, 0.0), (0.8, 0.8, 0.0), (-0.8, 0.8, 0.0)], 0.42)  # table top
    for x0, y0, x1, y1, a in ((0.25, -0.5, 0.6, -0.47, 0.9), (-0.5, 0.3, -0.2, 0.32, 0.1)):  # tape markings
        f.face([(x0, y0, 0.002), (x1, y0, 0.002), (x1, y1, 0.002), (x0, y1, 0.002)], a)
    f.box((0.28, 0.18, 0.0), (0.40, 0.26, 0.07), 0.85)  # a box not in the model
    f.box((-0.45, -0.35, 0.0), (-0.33, -0.22, 0.12), 0.2)  # another
    f.face([(-0.8, 0.8, 0.0), (0.8, 0.8, 0.0), (0.8, 0.8, 0.9), (-0.8, 0.8, 0.9)][::-1], 0.6)  # back wall
    return f.build("tabletop+clutter")


def scaled_scene(scene: SceneModel, scale: float) -> SceneModel:
    """``scene`` with every vertex scaled by ``scale`` about the origin."""
    description = scene_to_dict(scene)
    description["vertices"] = (np.asarray(description["vertices"]) * scale).tolist()
    return scene_from_dict(description)


@dataclass(frozen=True)
class CameraFlight(SampledFlight):
    """Exact camera poses at ``times_s`` (T,): centres (T, 3) and ``R_world_camera`` (T, 3, 3)."""

    p_world_camera_m: FloatArray
    R_world_camera: FloatArray

    def pose(self, frame: int) -> CameraPose:
        return CameraPose(self.p_world_camera_m[frame], self.R_world_camera[frame])

    def part(self, start: int, stop: int | None = None) -> CameraFlight:
        """Frames ``[start, stop)`` of the flight (their own stamps)."""
        cut = slice(start, stop)
        return CameraFlight(self.times_s[cut], self.p_world_camera_m[cut], self.R_world_camera[cut])


def _look_at(eye: FloatArray, target: FloatArray, roll_rad: FloatArray) -> FloatArray:
    """``R_world_camera`` (T, 3, 3) of cameras at ``eye`` looking at ``target``, rolled about the axis."""
    z = target - eye
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    c, s = np.cos(roll_rad)[:, None], np.sin(roll_rad)[:, None]
    x_r, y_r = c * x + s * y, -s * x + c * y
    return np.stack([x_r, y_r, z], axis=2)


def _wander(
    t: FloatArray, rng: np.random.Generator, amplitude: float, period_s: tuple[float, float]
) -> FloatArray:
    """A smooth random signal: three sines of random periods and phases, peak about ``amplitude``."""
    out = np.zeros_like(t)
    for _ in range(3):
        period = rng.uniform(*period_s)
        out += (
            (amplitude / 2.0) * rng.uniform(0.4, 1.0) * np.sin(2.0 * np.pi * t / period + rng.uniform(0, 6.3))
        )
    return out


def object_flight(
    n_frames: int = 300,
    seed: int = 0,
    rate_hz: float = OBJECT_RATE_HZ,
    *,
    scale: float = 1.0,
    distance_scale: float = 1.0,
    max_step_m: float = MAX_STEP_M,
    max_step_rad: float = MAX_STEP_RAD,
) -> CameraFlight:
    """A flight around the tabletop part: distance 0.45-0.9 m, elevation 20-55 deg, the aim wandering a few
    centimetres about the part and a roll of up to 10 deg; slowed down (if needed) so that no frame moves
    more than ``max_step_m`` (20 mm) or ``max_step_rad`` (2 deg). ``scale``: the world (and the flight)
    scaled about the origin (for :func:`scaled_scene` of the same factor); ``distance_scale``: the orbit's
    distance to the part times this (before ``scale``)."""
    if n_frames < 2 or rate_hz <= 0.0 or scale <= 0.0 or distance_scale <= 0.0:
        raise InputError(f"need n_frames >= 2 and rate_hz, scales > 0, got {n_frames}, {rate_hz}")
    speed = 1.0
    for _ in range(20):
        p, R = _orbit(speed * np.arange(n_frames, dtype=np.float64) / rate_hz, seed, distance_scale)
        p = scale * p
        step_m = np.linalg.norm(np.diff(p, axis=0), axis=1).max()
        step_rad = rotation_angle_rad(R[1:], R[:-1]).max()
        ratio = max(step_m / max_step_m, step_rad / max_step_rad)
        if ratio <= 1.0:
            return CameraFlight(times_s=np.arange(n_frames) / rate_hz, p_world_camera_m=p, R_world_camera=R)
        speed /= ratio * 1.02
    raise InputError("could not build a flight within the per-frame motion limits")


def _orbit(t: FloatArray, seed: int, distance_scale: float = 1.0) -> tuple[FloatArray, FloatArray]:
    """Camera centres and rotations of the orbit at (scaled) times ``t``; its shape depends on the seed."""
    rng = np.random.default_rng(seed)
    centre = np.asarray(OBJECT_CENTRE_M)
    azimuth = (
        rng.uniform(0.0, 2.0 * np.pi) + rng.choice([-1.0, 1.0]) * 0.45 * t + _wander(t, rng, 0.6, (4, 9))
    )
    elevation = np.radians(37.0) + _wander(t, rng, np.radians(16.0), (3, 8))
    distance = distance_scale * (0.66 + _wander(t, rng, 0.2, (3, 7)))
    eye = centre + distance[:, None] * np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=1
    )
    target = centre + np.stack([_wander(t, rng, 0.05, (2, 5)) for _ in range(3)], axis=1)
    roll = _wander(t, rng, np.radians(9.0), (2, 6))
    return eye, _look_at(eye, target, roll)


def kidnap(
    flight: CameraFlight, frame: int, offset_m: npt.ArrayLike, rotvec_rad: npt.ArrayLike
) -> CameraFlight:
    """The same flight with the camera teleported from ``frame`` on: shifted by ``offset_m`` and turned by
    ``rotvec_rad`` (a world-frame rotation vector) about its own centre."""
    if not 0 < frame < flight.n_frames:
        raise InputError(f"kidnap frame must lie in (0, {flight.n_frames}), got {frame}")
    p = flight.p_world_camera_m.copy()
    R = flight.R_world_camera.copy()
    p[frame:] += np.asarray(offset_m, dtype=np.float64)
    rot = np.broadcast_to(np.asarray(rotvec_rad, dtype=np.float64), (flight.n_frames - frame, 3))
    R[frame:] = perturb(R[frame:], np.ascontiguousarray(rot))
    return replace(flight, p_world_camera_m=p, R_world_camera=R)


def _random_offsets(position_m: float, angle_rad: float, seed: int) -> tuple[FloatArray, FloatArray]:
    """A shift of length ``position_m`` and a rotation vector of angle ``angle_rad``, in random directions
    (by seed)."""
    rng = np.random.default_rng(seed)
    shift, turn = rng.normal(size=3), rng.normal(size=3)
    return position_m * shift / np.linalg.norm(shift), angle_rad * turn / np.linalg.norm(turn)


def random_kidnap(
    flight: CameraFlight, frame: int, position_m: float, angle_rad: float, seed: int
) -> CameraFlight:
    """:func:`kidnap` by exactly ``position_m`` and ``angle_rad`` in random directions (by seed)."""
    return kidnap(flight, frame, *_random_offsets(position_m, angle_rad, seed))


#: The localizer field bench's kidnap: the camera teleported this far (m, deg), in random directions.
BENCH_KIDNAP_M, BENCH_KIDNAP_DEG = 0.1, 10.0


def bench_kidnap(flight: CameraFlight, frame: int, run: int) -> CameraFlight:
    """The localizer field bench's kidnap of its run ``run`` at ``frame`` (:func:`random_kidnap` by
    :data:`BENCH_KIDNAP_M` and :data:`BENCH_KIDNAP_DEG`); the tracker's regression tests replay it."""
    return random_kidnap(flight, frame, BENCH_KIDNAP_M, float(np.radians(BENCH_KIDNAP_DEG)), 10_000 + run)


def frame_gyro(flight: CameraFlight, noise: ImuNoise, seed: int) -> FloatArray:
    """What a gyro rigidly mounted with the camera reads, averaged over each frame interval and turned into
    the camera frame (T, 3) rad/s (row 0: zeros): the true mean rate ``Log(R_k-1^T R_k) / dt`` plus a
    constant bias ``N(0, gyro_bias_sigma)`` per axis (by seed) and the white noise averaged over the
    interval (``density / sqrt(dt)``)."""
    rng = np.random.default_rng(seed)
    bias = rng.normal(size=3) * noise.gyro_bias_sigma_rad_s
    R = flight.R_world_camera
    dt = np.diff(flight.times_s)
    if np.any(dt <= 0.0):
        raise InputError("flight times must increase")
    rates = rotation_vectors(np.einsum("nji,njk->nik", R[:-1], R[1:])) / dt[:, None]
    white = rng.normal(size=rates.shape) * (noise.gyro_noise_density_rad_s_sqrt_hz / np.sqrt(dt))[:, None]
    return np.concatenate([np.zeros((1, 3)), rates + bias + white])


def offset_pose(pose: CameraPose, position_m: float, angle_rad: float, seed: int) -> CameraPose:
    """``pose`` off by exactly ``position_m`` and ``angle_rad`` in random directions (by seed): the start
    error of the localizer's tests and bench."""
    shift_m, rotvec_rad = _random_offsets(position_m, angle_rad, seed)
    return CameraPose(
        pose.p_world_camera_m + shift_m, perturb(pose.R_world_camera[None], rotvec_rad[None])[0]
    )


def render_camera_flight(
    scene: SceneModel,
    flight: CameraFlight,
    camera: CameraModel,
    options: RenderOptions = OBJECT_RENDER,
    rng: np.random.Generator | None = None,
) -> Iterator[U8Array]:
    """Frames of a camera flight, one per pose, in order."""
    for p, R in zip(flight.p_world_camera_m, flight.R_world_camera, strict=True):
        yield render_view(scene, R, p, camera, options, rng)


def rendered_object_flight(
    n_frames: int, seed: int, camera: CameraModel | None = None
) -> tuple[CameraFlight, list[U8Array]]:
    """:func:`object_flight` over :func:`tabletop_scene` and its frames (the noise seeded alike), seen by
    ``camera`` (default :func:`object_camera`)."""
    flight = object_flight(n_frames, seed=seed)
    rng = np.random.default_rng(seed)
    return flight, list(render_camera_flight(tabletop_scene(), flight, camera or object_camera(), rng=rng))
