"""Field scenarios: what users fly over and through (issue 10), each deterministic by seed with exact truth.

- Floors (:func:`checkerboard_texture`, :func:`tiled_texture`): a black-and-white checkerboard mat (square
  size configurable, default 10 cm) and a tiled floor with grout lines, both with a faint print/wear grain
  (a low-contrast noise carpet) as real floors have; exactly periodic, hence 90/180 deg self-similar.
- Lens (:func:`wide_angle_camera`, :func:`render_lens_view`): a 320x240 wide-angle camera (120 deg HFOV over
  the distorted image) with strong OpenCV radial-tangential barrel distortion, rendered exactly: every pixel's
  ray is undistorted through :class:`common.camera.CameraModel` and intersected with the ground; the texture
  is sampled there (``cv2.remap``) with a per-pixel mip-map level (trilinear), so the image stays band-limited
  where the lens compresses the periphery.
- Low altitude (:func:`field_trajectory`): climbs and descents between 0.3 and 1.3 m at up to 0.4 m/s
  (septic smooth steps), horizontal drift up to 0.3 m/s, yaw swings with rates up to a given peak
  (60 deg/s at 20 fps for the fast scenarios).
- Motion blur and exposure (:class:`FieldFlight`): a frame integrates the view over the exposure time
  (sub-frames at the true poses, as many as the image motion needs, so the blur is proportional to the image
  motion), then auto-exposure gain steps, then the sensor's :class:`~common.sim.sensors.ImageDegradation`.

:data:`FIELD_SCENARIOS` names one scenario per effect and the combined ``field`` flight;
:func:`field_flight` builds any of them. IMU and rangefinder series come with every flight.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace

import cv2
import numpy as np
import numpy.typing as npt

from common.camera import CameraModel, Distortion, DistortionModel
from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, matrix_from_euler
from common.sim.flight import CAMERA_RATE_HZ, Flight, simulate_flight
from common.sim.ground import (
    GroundTexture,
    GroundViewError,
    camera_pose_from_body,
    ground_texture_from_image,
    make_ground_texture,
)
from common.sim.sensors import ImageDegradation
from common.sim.trajectory import (
    AttitudeMode,
    AxesPath,
    FunctionSum,
    SineSum,
    SmoothStep,
    TanhSteps,
    Trajectory,
)
from common.types import Float32Array, FloatArray, U8Array

#: Stream labels mixed into the seed (floors, trajectory shape, exposure steps).
FLOOR_STREAM = 0xF10
FIELD_TRAJECTORY_STREAM = 0xF1A
EXPOSURE_STREAM = 0xF1E
#: Texels per floor tile side (power of two, so every pattern period divides it).
FLOOR_SIZE_PX = 2048
#: Texels are at most this big (m): finer than a pixel of the 320x240 cameras at 0.3 m.
MAX_TEXEL_M = 0.0032
#: Most sub-frames a motion-blurred frame integrates.
MAX_BLUR_SUBFRAMES = 9


class FieldError(InputError):
    """A field scenario cannot be built with the given settings."""


# ------------------------------------------------------------------------------------------------- floors
def _texel_for(period_m: float) -> float:
    """Texel size ``period_m / 2^k``, the largest not above :data:`MAX_TEXEL_M` (whole texels per period)."""
    if not (math.isfinite(period_m) and 0.01 <= period_m <= 2.0):
        raise FieldError(f"pattern size must be in [0.01, 2] m, got {period_m}")
    texels = 1
    while period_m / texels > MAX_TEXEL_M:
        texels *= 2
    if texels > FLOOR_SIZE_PX // 2:
        raise FieldError(f"pattern size {period_m} m needs too many texels")
    return period_m / texels


def _grain(seed: int, texel_m: float, grain_dn: float) -> Float32Array:
    """Zero-mean low-contrast noise carpet (print texture, wear, dust), ``grain_dn`` per std."""
    if grain_dn <= 0.0:
        return np.zeros((FLOOR_SIZE_PX, FLOOR_SIZE_PX), np.float32)
    carpet = make_ground_texture(
        seed=seed ^ FLOOR_STREAM, size_px=FLOOR_SIZE_PX, texel_m=texel_m, contrast_dn=grain_dn
    )
    return carpet.levels[0].astype(np.float32) - np.float32(128.0)


def _soften(image: Float32Array, sigma_texels: float = 0.7) -> Float32Array:
    """Periodic Gaussian blur (printed edges are not sharper than a texel)."""
    pad = 4
    padded = np.pad(image, pad, mode="wrap")
    return np.asarray(cv2.GaussianBlur(padded, (0, 0), sigma_texels)[pad:-pad, pad:-pad], dtype=np.float32)


def _printed(pattern: Float32Array, seed: int, texel_m: float, grain_dn: float) -> GroundTexture:
    """A pattern as printed on a floor: edges softened to the texel, a faint grain, 8-bit grey."""
    image = np.clip(np.rint(_soften(pattern) + _grain(seed, texel_m, grain_dn)), 0, 255).astype(np.uint8)
    return ground_texture_from_image(image, texel_m)


def checkerboard_texture(
    seed: int = 0,
    square_m: float = 0.10,
    dark_dn: float = 35.0,
    light_dn: float = 220.0,
    grain_dn: float = 3.0,
) -> GroundTexture:
    """A black-and-white checkerboard mat of ``square_m`` squares (the tile repeats it exactly)."""
    texel = _texel_for(square_m)
    n = round(square_m / texel)
    idx = np.arange(FLOOR_SIZE_PX) // n
    board = np.where((idx[:, None] + idx[None, :]) % 2 == 0, dark_dn, light_dn).astype(np.float32)
    return _printed(board, seed, texel, grain_dn)


def tiled_texture(
    seed: int = 0,
    tile_m: float = 0.30,
    grout_m: float = 0.006,
    tile_dn: float = 175.0,
    grout_dn: float = 70.0,
    tile_variation_dn: float = 6.0,
    grain_dn: float = 3.0,
) -> GroundTexture:
    """Square floor tiles of ``tile_m`` with grout lines ``grout_m`` wide; each tile a little lighter or
    darker (``tile_variation_dn``), plus a faint grain."""
    texel = _texel_for(tile_m)
    n = round(tile_m / texel)
    grout = max(1, round(grout_m / texel))
    tiles = FLOOR_SIZE_PX // n
    rng = np.random.default_rng([FLOOR_STREAM, int(seed), 2])
    shade = tile_dn + tile_variation_dn * rng.standard_normal((tiles, tiles))
    image = np.kron(shade, np.ones((n, n))).astype(np.float32)
    pos = np.arange(FLOOR_SIZE_PX) % n
    line = pos < grout
    image[line, :] = grout_dn
    image[:, line] = grout_dn
    return _printed(image, seed, texel, grain_dn)


# ---------------------------------------------------------------------------------------------------- lens
def wide_angle_camera(
    width: int = 320, height: int = 240, hfov_deg: float = 120.0, k1: float = -0.30, k2: float = 0.08
) -> CameraModel:
    """A wide-angle lens with strong barrel distortion (OpenCV radtan ``k1, k2``): ``fx`` chosen so the
    *distorted* image spans ``hfov_deg`` horizontally (the edge pixel's ray is ``hfov_deg / 2`` off-axis)."""
    r = math.tan(math.radians(hfov_deg) / 2.0)
    r_d = r * (1.0 + k1 * r * r + k2 * r**4)
    if r_d <= 0.0:
        raise FieldError(f"distortion k1={k1}, k2={k2} folds the image edge back (hfov {hfov_deg} deg)")
    f = (width / 2.0) / r_d
    distortion = Distortion(DistortionModel.RADTAN, (k1, k2, 0.0, 0.0, 0.0))
    return CameraModel(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, distortion)


def pixel_rays(camera: CameraModel) -> FloatArray:
    """Camera-frame rays (H, W, 3), z = 1, of every pixel centre (through the lens model)."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
    rays = camera.rays(pixels)
    if not np.all(np.isfinite(rays)):
        raise FieldError("the lens model cannot be inverted at some pixels")
    return rays.reshape(camera.height, camera.width, 3)


def _texel_maps(
    texture: GroundTexture, rays_camera: FloatArray, R_world_camera: FloatArray, p_world_camera_m: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Level-0 texel coordinates (H, W) where each pixel's ray meets the ground ``z = 0``."""
    d = rays_camera @ np.asarray(R_world_camera).T
    if p_world_camera_m[2] <= 0.0:
        raise GroundViewError(f"the camera must be above the ground, got z = {p_world_camera_m[2]:.4g} m")
    if np.any(d[..., 2] >= -1e-6):
        raise GroundViewError("a pixel does not see the ground (the horizon is in view)")
    s = -p_world_camera_m[2] / d[..., 2]
    x = p_world_camera_m[0] + s * d[..., 0]
    y = p_world_camera_m[1] + s * d[..., 1]
    return (x - texture.origin_x_m) / texture.texel_m, (y - texture.origin_y_m) / texture.texel_m


def _sample_texture(texture: GroundTexture, u0: FloatArray, v0: FloatArray) -> Float32Array:
    """Trilinear mip-mapped samples (float32, H x W) of the periodic texture at level-0 coordinates."""
    du = np.hypot(np.gradient(u0, axis=1), np.gradient(v0, axis=1))
    dv = np.hypot(np.gradient(u0, axis=0), np.gradient(v0, axis=0))
    top = len(texture.levels) - 1
    lod = np.clip(np.log2(np.maximum(np.maximum(du, dv), 1e-9)), 0.0, float(top))
    lo = np.floor(lod).astype(np.int64)
    frac = (lod - lo).astype(np.float32)
    out = np.zeros(u0.shape, np.float32)
    for level in range(int(lo.min()), min(int(lo.max()) + 1, top) + 1):
        weight = np.where(lo == level, 1.0 - frac, 0.0) + np.where(lo == level - 1, frac, 0.0)
        if level == top:
            weight = weight + np.where(lo == top, frac, 0.0)
        if not np.any(weight > 0.0):
            continue
        size = texture.levels[level].shape[0]
        scale = 1.0 / float(2**level)
        map_x = np.mod(u0 * scale, size).astype(np.float32)
        map_y = np.mod(v0 * scale, size).astype(np.float32)
        sampled = cv2.remap(
            texture.levels[level], map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP
        ).astype(np.float32)
        out += weight.astype(np.float32) * sampled
    return out


def render_lens_view(
    texture: GroundTexture,
    rays_camera: FloatArray,
    R_world_camera: npt.ArrayLike,
    p_world_camera_m: npt.ArrayLike,
) -> Float32Array:
    """Exact float32 view (H, W) of the ground through a lens whose pixel rays are ``rays_camera``
    (:func:`pixel_rays`, any distortion model), anti-aliased per pixel (no noise)."""
    R = np.asarray(R_world_camera, dtype=np.float64)
    p = np.asarray(p_world_camera_m, dtype=np.float64)
    u0, v0 = _texel_maps(texture, rays_camera, R, p)
    return _sample_texture(texture, u0, v0)


# ------------------------------------------------------------------------------------------------ motion
def _scaled_yaw_swings(
    rng: np.random.Generator, duration_s: float, max_rate_rad_s: float, yaw0: float
) -> FunctionSum:
    """Yaw swings both ways (smooth steps every 1.5-4 s, 20-90 deg) plus a slow sine; peak |rate| exact."""
    centres, amplitudes, widths = [], [], []
    t = float(rng.uniform(1.0, 2.0))
    sign = 1.0 if rng.uniform() < 0.5 else -1.0
    while t < duration_s - 1.0:
        magnitude = math.radians(float(rng.uniform(20.0, 90.0)))
        if rng.uniform() < 0.6:
            sign = -sign
        relative_rate = float(rng.uniform(0.5, 1.0))
        amplitudes.append(sign * magnitude)
        centres.append(t)
        widths.append(magnitude / (2.0 * relative_rate))
        t += float(rng.uniform(1.5, 4.0))
    steps = TanhSteps(tuple(amplitudes), tuple(centres), tuple(widths))
    wander = SineSum((math.radians(10.0),), (2.0 * math.pi / 23.0,), (float(rng.uniform(-3, 3)),))
    grid = np.arange(0.0, duration_s + 1e-9, 1e-3)
    peak = float(np.max(np.abs(FunctionSum((steps, wander)).derivative(grid, 1))))
    k = max_rate_rad_s / peak if peak > 0.0 else 1.0
    steps = TanhSteps(tuple(a * k for a in steps.amplitudes), steps.centres_s, steps.widths_s)
    wander = SineSum(tuple(a * k for a in wander.amplitudes), wander.omegas_rad_s, wander.phases_rad, yaw0)
    return FunctionSum((steps, wander))


def _altitude_profile(
    rng: np.random.Generator, duration_s: float, low_m: float, high_m: float, max_speed_m_s: float
) -> FunctionSum:
    """Climbs and descents between ``low_m`` and ``high_m`` (septic steps peaking at ``max_speed_m_s``)."""
    height = high_m - low_m
    ramp_s = 35.0 / 16.0 * height / max_speed_m_s  # the septic step's peak rate is 35/16 h / T
    terms: list[SmoothStep | SineSum] = [SineSum((), (), (), low_m)]
    t = float(rng.uniform(1.0, 2.0))
    up = True
    while t + ramp_s < duration_s:
        terms.append(SmoothStep(t, ramp_s, height if up else -height))
        t += ramp_s + float(rng.uniform(0.5, 2.5))
        up = not up
    return FunctionSum(tuple(terms))


def _drift(rng: np.random.Generator, duration_s: float, max_speed_m_s: float) -> SineSum:
    """Horizontal drift: three sines scaled so the peak speed is ``max_speed_m_s``."""
    periods = (float(rng.uniform(9.0, 14.0)), float(rng.uniform(4.0, 7.0)), float(rng.uniform(2.0, 3.0)))
    omegas = tuple(2.0 * math.pi / p for p in periods)
    phases = tuple(float(x) for x in rng.uniform(-math.pi, math.pi, 3))
    raw = SineSum((1.0, 0.5, 0.15), omegas, phases)
    grid = np.arange(0.0, duration_s + 1e-9, 1e-3)
    peak = float(np.max(np.abs(raw.derivative(grid, 1))))
    k = max_speed_m_s / peak if peak > 0.0 else 0.0
    return SineSum(tuple(a * k for a in raw.amplitudes), omegas, phases)


def field_trajectory(
    seed: int = 0,
    duration_s: float = 30.0,
    altitude_m: tuple[float, float] = (1.0, 1.0),
    max_climb_m_s: float = 0.4,
    max_drift_m_s: float = 0.1,
    max_yaw_rate_deg_s: float = 45.0,
    max_tilt_deg: float = 3.0,
    name: str = "field",
) -> Trajectory:
    """A field flight: altitude between ``altitude_m`` (low, high) with climbs/descents at up to
    ``max_climb_m_s`` (a constant altitude plus 2 cm breathing when low == high), horizontal drift peaking at
    ``max_drift_m_s``, yaw swings peaking at exactly ``max_yaw_rate_deg_s``, a few degrees of wobble."""
    low, high = altitude_m
    if not (0.1 <= low <= high <= 10.0) or duration_s <= 0.0 or max_climb_m_s <= 0.0:
        raise FieldError(f"bad field trajectory: altitude {altitude_m}, duration {duration_s}")
    rng = np.random.default_rng([FIELD_TRAJECTORY_STREAM, int(seed)])
    yaw = _scaled_yaw_swings(
        rng, duration_s, math.radians(max_yaw_rate_deg_s), float(rng.uniform(-math.pi, math.pi))
    )
    if high > low:
        z: FunctionSum | SineSum = _altitude_profile(rng, duration_s, low, high, max_climb_m_s)
    else:
        z = SineSum((0.02,), (2.0 * math.pi / 7.0,), (float(rng.uniform(-3, 3)),), low)
    # each axis peaks at max / sqrt(2): the horizontal speed never exceeds ``max_drift_m_s``
    per_axis = max_drift_m_s / math.sqrt(2.0)
    x, y = _drift(rng, duration_s, per_axis), _drift(rng, duration_s, per_axis)
    tilt = math.radians(max_tilt_deg)
    sines = [
        SineSum(
            (0.6 * tilt, 0.4 * tilt),
            (2.0 * math.pi / float(rng.uniform(3.0, 6.0)), 2.0 * math.pi / float(rng.uniform(1.0, 2.0))),
            tuple(float(v) for v in rng.uniform(-math.pi, math.pi, 2)),
        )
        for _ in range(2)
    ]
    return Trajectory(
        name=name,
        duration_s=float(duration_s),
        path=AxesPath(x, y, z),
        yaw=yaw,
        mode=AttitudeMode.PRESCRIBED,
        roll=sines[0],
        pitch=sines[1],
        info={"max_yaw_rate_deg_s": float(max_yaw_rate_deg_s), "low_m": low, "high_m": high},
    )


@dataclass(frozen=True)
class ExposureSteps:
    """Auto-exposure: the gain jumps by a factor in ``[1 / max_factor, max_factor]`` every 2-5 s (0.2 s
    transitions), deterministic for a seed; ``exposure_s`` is the shutter time the motion blur integrates."""

    exposure_s: float = 0.0
    max_factor: float = 1.0

    def gain(self, t_s: float, seed: int, duration_s: float) -> float:
        """Gain at ``t_s``: log-gain steps to a new level in ``[-log max_factor, log max_factor]``."""
        if self.max_factor <= 1.0:
            return 1.0
        rng = np.random.default_rng([EXPOSURE_STREAM, int(seed)])
        limit = math.log(self.max_factor)
        log_gain, previous, t = 0.0, 0.0, float(rng.uniform(1.0, 3.0))
        while t < duration_s:
            target = float(rng.uniform(-limit, limit))
            log_gain += (target - previous) * min(max((t_s - t) / 0.2, 0.0), 1.0)
            previous = target
            t += float(rng.uniform(2.0, 5.0))
        return math.exp(log_gain)


@dataclass(frozen=True, eq=False)
class FieldFlight(Flight):
    """A :class:`Flight` rendered through any lens (exact ray casting), motion blur and exposure steps."""

    rays_camera: FloatArray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    exposure: ExposureSteps = ExposureSteps()

    def _view(self, t_s: float) -> Float32Array:
        truth = self.trajectory.sample(np.array([t_s]))
        R, p = camera_pose_from_body(truth.R_world_body[0], truth.p_world_body_m[0], self.R_body_camera)
        return render_lens_view(self.texture, self.rays_camera, R, p)

    def _maps(self, t_s: float) -> tuple[FloatArray, FloatArray]:
        truth = self.trajectory.sample(np.array([t_s]))
        R, p = camera_pose_from_body(truth.R_world_body[0], truth.p_world_body_m[0], self.R_body_camera)
        return _texel_maps(self.texture, self.rays_camera[::8, ::8], R, p)

    def subframes(self, i: int) -> int:
        """Sub-frames frame ``i`` integrates: one per ~0.75 px of the largest image motion while exposed."""
        index = self._check_index(i)
        if self.exposure.exposure_s <= 0.0:
            return 1
        t = float(self.frame_stamps_s[index])
        half = self.exposure.exposure_s / 2.0
        (ua, va), (ub, vb) = self._maps(t - half), self._maps(t + half)
        footprint = np.hypot(np.gradient(ua, axis=1), np.gradient(va, axis=1)) / 8.0
        motion_px = float(np.max(np.hypot(ub - ua, vb - va) / np.maximum(footprint, 1e-9)))
        return int(min(MAX_BLUR_SUBFRAMES, max(1, math.ceil(motion_px / 0.75) + 1)))

    def clean_frame(self, i: int) -> U8Array:
        """Frame ``i`` before sensor noise: exposure-integrated view times the auto-exposure gain."""
        index = self._check_index(i)
        t = float(self.frame_stamps_s[index])
        k = self.subframes(index)
        if k == 1:
            image = self._view(t)
        else:
            offsets = (np.arange(k) / (k - 1) - 0.5) * self.exposure.exposure_s
            image = sum((self._view(t + float(o)) for o in offsets), np.zeros(self.camera.shape, np.float32))
            image = image / np.float32(k)
        gain = self.exposure.gain(t, self.seed, float(self.frame_stamps_s[-1]))
        frame: U8Array = np.clip(np.rint(image * np.float32(gain)), 0, 255).astype(np.uint8)
        return frame


# ------------------------------------------------------------------------------------------------ scenarios
class Floor(enum.Enum):
    CARPET = "carpet"  # the paper's noise carpet
    CHECKERBOARD = "checkerboard"
    TILES = "tiles"


@dataclass(frozen=True)
class FieldScenario:
    """One field scenario: floor, lens, altitude band, motion blur / exposure, peak yaw rate, and the rig's
    nuisances: the camera's mount (tilted off the down mount by ``camera_tilt_deg`` about the body's y axis
    after turning ``camera_turn_deg`` about its optical axis), the IMU's axes (ZYX Euler angles of
    ``R_body_imu``, deg) and clock offset (``t_imu = t_cam + imu_time_offset_s``), bursty frame stamps
    (``frame_jitter_s``), dropped frames (``frame_drop_share``), and whether the flight's IMU is used
    (``use_imu``: False, the yaw runs without a gyro prior)."""

    name: str
    floor: Floor = Floor.CARPET
    wide_angle: bool = False
    altitude_m: tuple[float, float] = (1.0, 1.0)
    max_drift_m_s: float = 0.1
    max_yaw_rate_deg_s: float = 45.0
    exposure_s: float = 0.0
    exposure_factor: float = 1.0
    n_frames: int = 600
    camera_tilt_deg: float = 0.0
    camera_turn_deg: float = 0.0
    imu_euler_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu_time_offset_s: float = 0.0
    frame_jitter_s: float = 0.0
    frame_drop_share: float = 0.0
    use_imu: bool = True

    @property
    def R_body_camera(self) -> FloatArray:
        """The camera's mount: the down mount turned about its optical axis, then tilted about body y."""
        return mounted_camera(self.camera_tilt_deg, self.camera_turn_deg)

    @property
    def R_body_imu(self) -> FloatArray:
        roll, pitch, yaw = (math.radians(a) for a in self.imu_euler_deg)
        return np.asarray(matrix_from_euler(roll, pitch, yaw), dtype=np.float64)


def mounted_camera(tilt_deg: float, turn_deg: float) -> FloatArray:
    """``Ry(tilt) R_BODY_CAMERA_DOWN Rz(turn)``: a down camera turned by ``turn_deg`` about its optical axis
    and tilted by ``tilt_deg`` about the body's y axis (positive: the optical axis leans backward)."""
    tilt = matrix_from_euler(0.0, math.radians(tilt_deg), 0.0)
    turn = matrix_from_euler(0.0, 0.0, math.radians(turn_deg))
    return np.asarray(tilt @ R_BODY_CAMERA_DOWN @ turn, dtype=np.float64)


#: The combined ``field`` flight: every effect above at once.
FIELD = FieldScenario(
    "field",
    floor=Floor.CHECKERBOARD,
    wide_angle=True,
    altitude_m=(0.3, 1.3),
    max_drift_m_s=0.3,
    max_yaw_rate_deg_s=60.0,
    exposure_s=0.02,
    exposure_factor=1.4,
)
#: The rig's nuisances: a camera tilted 10 deg and turned 90 deg about its axis, an IMU upside down and
#: turned 90 deg (a flight controller mounted rotated), its clock 12 ms ahead of the camera's.
MOUNTED_RIG = replace(
    FIELD,
    name="mounted_rig",
    camera_tilt_deg=10.0,
    camera_turn_deg=90.0,
    imu_euler_deg=(180.0, 0.0, 90.0),
    imu_time_offset_s=0.012,
)
#: The stream's nuisances without an IMU: stamps +-40 ms around the nominal, 5 % of the frames dropped.
BURSTY_NO_IMU = replace(
    FIELD, name="bursty_no_imu", frame_jitter_s=0.04, frame_drop_share=0.05, use_imu=False
)
#: All of them with the IMU.
FIELD_NUISANCES = replace(MOUNTED_RIG, name="field_nuisances", frame_jitter_s=0.04, frame_drop_share=0.05)

#: One scenario per field effect, the combined ``field`` flight, and the combined flight with the rig's
#: nuisances (``mounted_rig``), with bursty stamps and drops and no IMU (``bursty_no_imu``) and with all of
#: them and the IMU (``field_nuisances``); 30 s each at 20 fps.
FIELD_SCENARIOS: dict[str, FieldScenario] = {
    s.name: s
    for s in (
        FieldScenario("checkerboard", floor=Floor.CHECKERBOARD),
        FieldScenario("tiles", floor=Floor.TILES),
        FieldScenario("wide_angle", wide_angle=True),
        FieldScenario("low_altitude", altitude_m=(0.3, 1.3), max_drift_m_s=0.3),
        FieldScenario("blur_exposure", exposure_s=0.02, exposure_factor=1.4, altitude_m=(0.6, 0.6)),
        FieldScenario("fast_yaw", max_yaw_rate_deg_s=60.0),
        FIELD,
        MOUNTED_RIG,
        BURSTY_NO_IMU,
        FIELD_NUISANCES,
    )
}

#: The narrow camera of the non-lens scenarios: 320x240 pinhole, 90 deg HFOV.
NARROW_HFOV_DEG = 90.0


def floor_texture(floor: Floor, seed: int) -> GroundTexture:
    if floor is Floor.CHECKERBOARD:
        return checkerboard_texture(seed)
    if floor is Floor.TILES:
        return tiled_texture(seed)
    return make_ground_texture(seed, size_px=FLOOR_SIZE_PX, texel_m=0.0025)


def fisheye_camera(width: int = 320, height: int = 240, hfov_deg: float = 120.0) -> CameraModel:
    """An equidistant fisheye (OpenCV's ``cv::fisheye`` with zero coefficients: a ray ``theta`` off-axis
    lands ``f theta`` from the centre) whose image spans ``hfov_deg`` horizontally."""
    f = (width / 2.0) / (math.radians(hfov_deg) / 2.0)
    distortion = Distortion(DistortionModel.FISHEYE, (0.0, 0.0, 0.0, 0.0))
    return CameraModel(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, distortion)


#: Lenses a field scenario can fly instead of its own (``capataz bench yaw --suite field --field-lens``):
#: name -> the lens at a frame size, each keeping its field of view at any size
FIELD_LENSES: dict[str, Callable[[int, int], CameraModel]] = {
    "pinhole60": lambda w, h: CameraModel.from_hfov(w, h, 60.0),
    "pinhole90": lambda w, h: CameraModel.from_hfov(w, h, NARROW_HFOV_DEG),
    "radtan120": wide_angle_camera,
    "fisheye100": lambda w, h: fisheye_camera(w, h, 100.0),
    "fisheye120": lambda w, h: fisheye_camera(w, h, 120.0),
}


def scenario_camera(
    scenario: FieldScenario, width: int = 320, height: int = 240, lens: str | None = None
) -> CameraModel:
    """The scenario's lens at ``width`` x ``height``: the wide-angle lens or the narrow pinhole, the same view
    at any size (``capataz bench yaw --suite field --field-size``); ``lens`` names one of
    :data:`FIELD_LENSES` instead (an unknown name is a :class:`FieldError`)."""
    if lens is not None:
        if lens not in FIELD_LENSES:
            raise FieldError(f"unknown lens {lens!r}; known: {', '.join(FIELD_LENSES)}")
        return FIELD_LENSES[lens](width, height)
    return FIELD_LENSES["radtan120" if scenario.wide_angle else "pinhole90"](width, height)


#: The frame rates a field flight may be flown at (Hz, :func:`field_flight`'s ``camera_rate_hz``).
FIELD_RATES_HZ = (0.5, 1000.0)


def field_flight(
    scenario: FieldScenario | str,
    seed: int = 0,
    n_frames: int | None = None,
    camera: CameraModel | None = None,
    texture: GroundTexture | None = None,
    degradation: ImageDegradation | None = None,
    camera_rate_hz: float = CAMERA_RATE_HZ,
) -> FieldFlight:
    """The flight of a field scenario (by name or value); ``camera`` overrides the scenario's lens (e.g. the
    pinhole twin of the wide-angle lens, for comparisons on the same trajectory). ``camera_rate_hz`` is the
    frame rate (``n_frames`` frames span ``(n_frames - 1) / camera_rate_hz``); the shutter time of a blurred
    scenario is at most the frame interval."""
    if isinstance(scenario, str):
        if scenario not in FIELD_SCENARIOS:
            raise FieldError(f"unknown field scenario {scenario!r}; known: {sorted(FIELD_SCENARIOS)}")
        scenario = FIELD_SCENARIOS[scenario]
    frames = scenario.n_frames if n_frames is None else int(n_frames)
    if frames < 2:
        raise FieldError(f"n_frames must be >= 2, got {frames}")
    low, high = FIELD_RATES_HZ
    if not (math.isfinite(camera_rate_hz) and low <= camera_rate_hz <= high):
        raise FieldError(f"camera_rate_hz must be in [{low:g}, {high:g}], got {camera_rate_hz}")
    duration_s = max((frames - 1) / camera_rate_hz, 1.0)
    trajectory = field_trajectory(
        seed,
        duration_s=duration_s,
        altitude_m=scenario.altitude_m,
        max_drift_m_s=scenario.max_drift_m_s,
        max_yaw_rate_deg_s=scenario.max_yaw_rate_deg_s,
        name=scenario.name,
    )
    if camera is None:
        camera = scenario_camera(scenario)
    base = simulate_flight(
        trajectory,
        seed=seed,
        n_frames=frames,
        camera=camera,
        texture=texture if texture is not None else floor_texture(scenario.floor, seed),
        degradation=degradation,
        R_body_camera=scenario.R_body_camera,
        R_body_imu=scenario.R_body_imu,
        imu_time_offset_s=scenario.imu_time_offset_s,
        frame_jitter_s=scenario.frame_jitter_s,
        frame_drop_share=scenario.frame_drop_share,
        camera_rate_hz=camera_rate_hz,
    )
    values = {f.name: getattr(base, f.name) for f in fields(base)}
    return FieldFlight(
        **values,
        rays_camera=pixel_rays(camera),
        exposure=ExposureSteps(min(scenario.exposure_s, 1.0 / camera_rate_hz), scenario.exposure_factor),
    )
