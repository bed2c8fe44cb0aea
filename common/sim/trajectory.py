"""Continuous-time trajectories with analytic derivatives: poses, body rates and specific force at any time.

A trajectory is a position ``p(t)`` with analytic derivatives up to the jerk, a yaw ``psi(t)`` (ZYX, CCW from
above) with its rate, and roll/pitch that are either

- ``AttitudeMode.COORDINATED``: what a quadrotor needs to accelerate, its thrust axis (body z) along
  ``a + g e_z`` (roll/pitch rates then follow analytically from the jerk), or
- ``AttitudeMode.PRESCRIBED``: given functions of time (a quasi-static hover wobble).

Sampling (:meth:`Trajectory.sample`) is exact at any time, so IMU samples at any rate are exact:
``omega_body`` from the ZYX Euler rates and ``specific_force_body = R_world_body^T (a_world + g e_z)``.

The two flights of the papers:

- :func:`hover_trajectory` (paper A): quasi-stationary hover (default altitude 1.5 m), yaw swings with rates
  up to +-45 deg/s (scaled so the peak |rate| is exactly ``max_yaw_rate_deg_s``), roll/pitch of a few degrees,
  horizontal drift of tens of centimetres.
- :func:`turns_trajectory` (paper C): hover at 3.5 m, then a climbing helix of two turns (radius 1.1 m)
  up to 4.0 m, heading along the path, coordinated tilt, then hover; septic smooth-step speed profile so
  velocity, acceleration and jerk (hence body rates) are continuous. Path length
  ``sqrt((2 turns 2 pi r)^2 + dz^2)`` = 13.832 m for the defaults.

Hover altitude 1.5 m (a choice: indoor hover height; the default camera then sees 3.0 x 1.9 m of ground at
4.0 mm per pixel, so a 2.25 deg inter-frame yaw at 45 deg/s moves the image corners by about 17 px).

Note for estimators: in COORDINATED flight the accelerometer reads pure thrust along body z (x and y are 0
plus noise and bias), as on a drag-free quadrotor. Paper C's gravity observation assumes no acceleration,
so during the turns it sees the vehicle level (up to 3 deg off). The PRESCRIBED hover satisfies it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import numpy.typing as npt

from common.errors import CapatazError, InputError
from common.geometry import matrix_from_euler, quaternion_from_euler
from common.types import FloatArray

GRAVITY_M_S2 = 9.80665

#: Paper A's hover: 2041 frames at 20 fps.
NOMINAL_HOVER_DURATION_S = 2040 / 20.0

#: Stream label mixed into the seed for the trajectory's random shape parameters.
TRAJECTORY_STREAM = 0x7A1


class TrajectoryError(CapatazError):
    """A trajectory cannot be evaluated (e.g. free fall: no thrust direction)."""


class AttitudeMode(enum.Enum):
    """How roll and pitch are obtained."""

    COORDINATED = "coordinated"
    PRESCRIBED = "prescribed"


class ScalarFunction(Protocol):
    """A smooth scalar function of time with analytic derivatives."""

    def derivative(self, t_s: FloatArray, order: int) -> FloatArray:
        """The ``order``-th time derivative at ``t_s`` (order 0 = the value)."""
        ...


@dataclass(frozen=True)
class SineSum:
    """``offset + sum_i A_i sin(omega_i t + phase_i)``, all derivatives analytic."""

    amplitudes: tuple[float, ...]
    omegas_rad_s: tuple[float, ...]
    phases_rad: tuple[float, ...]
    offset: float = 0.0

    def derivative(self, t_s: FloatArray, order: int) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        out = np.full(t.shape, self.offset if order == 0 else 0.0)
        for a, w, ph in zip(self.amplitudes, self.omegas_rad_s, self.phases_rad, strict=True):
            out += a * w**order * np.sin(w * t + ph + order * np.pi / 2.0)
        return out


@dataclass(frozen=True)
class TanhSteps:
    """``sum_i A_i (1 + tanh((t - c_i) / w_i)) / 2``: smooth steps; peak rate ``A_i / (2 w_i)``."""

    amplitudes: tuple[float, ...]
    centres_s: tuple[float, ...]
    widths_s: tuple[float, ...]

    def derivative(self, t_s: FloatArray, order: int) -> FloatArray:
        if order > 3:
            raise InputError(f"TanhSteps derivatives are implemented up to order 3, got {order}")
        t = np.asarray(t_s, dtype=np.float64)
        out = np.zeros(t.shape)
        for a, c, w in zip(self.amplitudes, self.centres_s, self.widths_s, strict=True):
            u = (t - c) / w
            th = np.tanh(u)
            sech2 = 1.0 - th * th
            if order == 0:
                out += 0.5 * a * (1.0 + th)
            elif order == 1:
                out += 0.5 * a / w * sech2
            elif order == 2:
                out += 0.5 * a / w**2 * (-2.0 * th * sech2)
            else:
                out += 0.5 * a / w**3 * (-2.0 * (sech2 * sech2 - 2.0 * th * th * sech2))
        return out


@dataclass(frozen=True)
class FunctionSum:
    """Sum of scalar functions."""

    terms: tuple[ScalarFunction, ...]

    def derivative(self, t_s: FloatArray, order: int) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        out = np.zeros(t.shape)
        for term in self.terms:
            out += term.derivative(t, order)
        return out


#: Septic smooth step ``35x^4 - 84x^5 + 70x^6 - 20x^7``: zero velocity, acceleration and jerk at both ends.
_SEPTIC = np.polynomial.Polynomial([0.0, 0.0, 0.0, 0.0, 35.0, -84.0, 70.0, -20.0])


@dataclass(frozen=True)
class SmoothStep:
    """``height * S((t - start_s) / duration_s)`` with the septic smooth step ``S`` (0 before, 1 after)."""

    start_s: float
    duration_s: float
    height: float = 1.0

    def derivative(self, t_s: FloatArray, order: int) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        x = (t - self.start_s) / self.duration_s
        inside = (x > 0.0) & (x < 1.0)
        poly = _SEPTIC.deriv(order) if order > 0 else _SEPTIC
        out = np.where(inside, poly(np.clip(x, 0.0, 1.0)), 0.0)
        if order == 0:
            out = np.where(x >= 1.0, 1.0, out)
        return np.asarray(self.height * out / self.duration_s**order, dtype=np.float64)


class PositionPath(Protocol):
    """World position of the body with analytic derivatives."""

    def derivatives(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(p, v, a, jerk)``, each (N, 3), at times ``t_s`` (N,)."""
        ...


@dataclass(frozen=True)
class AxesPath:
    """Position whose x, y, z are independent scalar functions of time."""

    x: ScalarFunction
    y: ScalarFunction
    z: ScalarFunction

    def derivatives(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        t = np.asarray(t_s, dtype=np.float64)
        out = tuple(
            np.stack([f.derivative(t, k) for f in (self.x, self.y, self.z)], axis=-1) for k in range(4)
        )
        return out[0], out[1], out[2], out[3]


@dataclass(frozen=True)
class HelixPath:
    """Climbing helix travelled along its arc length ``s(t) = length * S((t - start) / duration)``.

    Centre ``(cx, cy)``, radius ``r``, ``turns`` counter-clockwise turns from the angle ``start_angle_rad``,
    from altitude ``z_start_m`` to ``z_end_m``. Its heading (tangent direction) is exposed as :meth:`heading`.
    """

    centre_x_m: float
    centre_y_m: float
    radius_m: float
    turns: float
    z_start_m: float
    z_end_m: float
    start_s: float
    duration_s: float
    start_angle_rad: float = 0.0

    @property
    def length_m(self) -> float:
        """Exact path length (m)."""
        return float(np.hypot(2.0 * np.pi * self.turns * self.radius_m, self.z_end_m - self.z_start_m))

    def _arc(self, t_s: FloatArray) -> list[FloatArray]:
        step = SmoothStep(self.start_s, self.duration_s, self.length_m)
        return [step.derivative(t_s, k) for k in range(4)]

    def derivatives(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        t = np.asarray(t_s, dtype=np.float64)
        s, s1, s2, s3 = self._arc(t)
        L = self.length_m
        k = 2.0 * np.pi * self.turns / L  # rad per metre of path
        m = (self.z_end_m - self.z_start_m) / L  # climb per metre of path
        r = self.radius_m
        ang = self.start_angle_rad + k * s
        c, sn = np.cos(ang), np.sin(ang)
        zero = np.zeros_like(s)
        p_s0 = np.stack([self.centre_x_m + r * c, self.centre_y_m + r * sn, self.z_start_m + m * s], axis=-1)
        p_s1 = np.stack([-r * k * sn, r * k * c, np.full_like(s, m)], axis=-1)
        p_s2 = np.stack([-r * k**2 * c, -r * k**2 * sn, zero], axis=-1)
        p_s3 = np.stack([r * k**3 * sn, -r * k**3 * c, zero], axis=-1)
        d1, d2, d3 = s1[:, None], s2[:, None], s3[:, None]
        v = p_s1 * d1
        a = p_s2 * d1**2 + p_s1 * d2
        j = p_s3 * d1**3 + 3.0 * p_s2 * d1 * d2 + p_s1 * d3
        return p_s0, v, a, j

    def heading(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Unwrapped tangent direction (yaw of the path, rad) and its rate (rad/s)."""
        s, s1, _, _ = self._arc(np.asarray(t_s, dtype=np.float64))
        k = 2.0 * np.pi * self.turns / self.length_m
        return self.start_angle_rad + np.pi / 2.0 + k * s, k * s1


@dataclass(frozen=True)
class HeadingOf:
    """The heading of a :class:`HelixPath` as a scalar function (orders 0 and 1) plus a constant offset."""

    path: HelixPath
    offset_rad: float = 0.0

    def derivative(self, t_s: FloatArray, order: int) -> FloatArray:
        heading, rate = self.path.heading(t_s)
        if order == 0:
            return heading + self.offset_rad
        if order == 1:
            return rate
        raise InputError(f"HeadingOf implements derivative orders 0 and 1, got {order}")


@dataclass(frozen=True, eq=False)
class TrajectorySample:
    """True state at times ``t_s`` (N,): ENU position, FLU attitude, body rates, specific force."""

    t_s: FloatArray
    p_world_body_m: FloatArray
    v_world_m_s: FloatArray
    a_world_m_s2: FloatArray
    euler_rad: FloatArray  # (N, 3) roll, pitch, yaw (yaw unwrapped, continuous in time)
    R_world_body: FloatArray  # (N, 3, 3)
    q_world_body: FloatArray  # (N, 4) Hamilton, scalar first, q0 >= 0
    omega_body_rad_s: FloatArray  # (N, 3) body angular rate (what an ideal gyro reads)
    specific_force_body_m_s2: FloatArray  # (N, 3) R^T (a + g e_z) (what an ideal accelerometer reads)

    @property
    def yaw_rad(self) -> FloatArray:
        """Unwrapped ZYX yaw (N,)."""
        return np.asarray(self.euler_rad[:, 2], dtype=np.float64)


def body_rate_from_euler_rates(euler_rad: FloatArray, euler_rate_rad_s: FloatArray) -> FloatArray:
    """Body angular rate (N, 3) of ``R = Rz(yaw) Ry(pitch) Rx(roll)`` from ZYX Euler angles and rates."""
    roll, pitch = euler_rad[:, 0], euler_rad[:, 1]
    droll, dpitch, dyaw = euler_rate_rad_s[:, 0], euler_rate_rad_s[:, 1], euler_rate_rad_s[:, 2]
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    return np.stack(
        [droll - dyaw * sp, dpitch * cr + dyaw * sr * cp, -dpitch * sr + dyaw * cr * cp],
        axis=-1,
    )


def coordinated_roll_pitch(
    a_world_m_s2: FloatArray, jerk_world_m_s3: FloatArray, yaw_rad: FloatArray, yaw_rate_rad_s: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Roll, pitch and their rates that put the body z axis along ``a + g e_z`` for the given yaw.

    With ``c = Rz(-yaw) (a + g e_z) / |a + g e_z| = Ry(pitch) Rx(roll) e_z``
    ``= [cos r sin p, -sin r, cos r cos p]``:
    ``pitch = atan2(c1, c3)``, ``roll = atan2(-c2, hypot(c1, c3))``; rates by the chain rule through the jerk.
    """
    f = a_world_m_s2 + np.array([0.0, 0.0, GRAVITY_M_S2])
    norm = np.linalg.norm(f, axis=-1, keepdims=True)
    if np.any(norm < 1e-6):
        raise TrajectoryError("free fall: the thrust direction is undefined")
    b3 = f / norm
    db3 = (jerk_world_m_s3 - b3 * np.sum(b3 * jerk_world_m_s3, axis=-1, keepdims=True)) / norm
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    # c = Rz(-yaw) b3
    c1 = cy * b3[:, 0] + sy * b3[:, 1]
    c2 = -sy * b3[:, 0] + cy * b3[:, 1]
    c3 = b3[:, 2]
    # dc = Rz(-yaw) db3 - yaw_rate * e_z x c
    dc1 = cy * db3[:, 0] + sy * db3[:, 1] + yaw_rate_rad_s * c2
    dc2 = -sy * db3[:, 0] + cy * db3[:, 1] - yaw_rate_rad_s * c1
    dc3 = db3[:, 2]
    rho = np.hypot(c1, c3)
    pitch = np.arctan2(c1, c3)
    roll = np.arctan2(-c2, rho)
    dpitch = (c3 * dc1 - c1 * dc3) / (rho * rho)
    drho = (c1 * dc1 + c3 * dc3) / rho
    droll = (-rho * dc2 + c2 * drho) / (rho * rho + c2 * c2)
    return roll, pitch, droll, dpitch


@dataclass(frozen=True)
class Trajectory:
    """A full 6-DoF trajectory over ``[0, duration_s]`` (evaluable at any time, also outside)."""

    name: str
    duration_s: float
    path: PositionPath
    yaw: ScalarFunction
    mode: AttitudeMode
    roll: ScalarFunction | None = None
    pitch: ScalarFunction | None = None
    info: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.mode is AttitudeMode.PRESCRIBED and (self.roll is None or self.pitch is None):
            raise InputError("a PRESCRIBED trajectory needs roll and pitch functions")
        if not (np.isfinite(self.duration_s) and self.duration_s > 0.0):
            raise InputError(f"duration_s must be positive, got {self.duration_s}")

    def sample(self, t_s: npt.ArrayLike) -> TrajectorySample:
        """Exact state at the times ``t_s`` (scalar or (N,))."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise InputError(f"t_s must be a finite scalar or (N,) array, got shape {np.shape(t_s)}")
        p, v, a, j = self.path.derivatives(t)
        yaw = self.yaw.derivative(t, 0)
        dyaw = self.yaw.derivative(t, 1)
        if self.mode is AttitudeMode.COORDINATED:
            roll, pitch, droll, dpitch = coordinated_roll_pitch(a, j, yaw, dyaw)
        else:
            assert self.roll is not None and self.pitch is not None
            roll, droll = self.roll.derivative(t, 0), self.roll.derivative(t, 1)
            pitch, dpitch = self.pitch.derivative(t, 0), self.pitch.derivative(t, 1)
        euler = np.stack([roll, pitch, yaw], axis=-1)
        omega = body_rate_from_euler_rates(euler, np.stack([droll, dpitch, dyaw], axis=-1))
        R = matrix_from_euler(roll, pitch, yaw)
        q = quaternion_from_euler(roll, pitch, yaw)
        f_world = a + np.array([0.0, 0.0, GRAVITY_M_S2])
        f_body = np.einsum("nji,nj->ni", R, f_world)
        return TrajectorySample(
            t_s=t,
            p_world_body_m=p,
            v_world_m_s=v,
            a_world_m_s2=a,
            euler_rad=euler,
            R_world_body=R,
            q_world_body=q,
            omega_body_rad_s=omega,
            specific_force_body_m_s2=f_body,
        )


def _random_sines(
    rng: np.random.Generator, amplitudes: tuple[float, ...], periods_s: tuple[float, ...], offset: float = 0.0
) -> SineSum:
    """Sines of the given amplitudes and (jittered +-20 %) periods with random phases."""
    jitter = rng.uniform(0.8, 1.2, len(periods_s))
    omegas = tuple(float(2.0 * np.pi / (p * j)) for p, j in zip(periods_s, jitter, strict=True))
    phases = tuple(float(x) for x in rng.uniform(-np.pi, np.pi, len(periods_s)))
    return SineSum(tuple(float(a) for a in amplitudes), omegas, phases, float(offset))


def _hover_yaw_steps(
    rng: np.random.Generator, duration_s: float, max_step_rad: float, wander_limit_rad: float
) -> TanhSteps:
    """Yaw swings: smooth steps every ~5-9 s, mostly alternating, the net yaw kept within the wander limit."""
    centres: list[float] = []
    amplitudes: list[float] = []
    widths: list[float] = []
    t = float(rng.uniform(2.0, 4.0))
    net = 0.0
    sign = 1.0 if rng.uniform() < 0.5 else -1.0
    while t < duration_s - 2.0:
        magnitude = float(rng.uniform(0.35, 1.0)) * max_step_rad
        if rng.uniform() < 0.7:
            sign = -sign
        if abs(net + sign * magnitude) > wander_limit_rad:
            sign = -sign
        peak_rate = float(rng.uniform(0.45, 1.0))  # relative; the whole yaw is rescaled afterwards
        amplitudes.append(sign * magnitude)
        centres.append(t)
        widths.append(magnitude / (2.0 * peak_rate))
        net += sign * magnitude
        t += float(rng.uniform(5.0, 9.0))
    return TanhSteps(tuple(amplitudes), tuple(centres), tuple(widths))


def hover_trajectory(
    seed: int = 0,
    duration_s: float = NOMINAL_HOVER_DURATION_S,
    altitude_m: float = 1.5,
    max_yaw_rate_deg_s: float = 45.0,
    max_tilt_deg: float = 3.0,
    drift_m: float = 0.25,
    mode: AttitudeMode = AttitudeMode.PRESCRIBED,
) -> Trajectory:
    """Paper A's quasi-stationary hover (ETH / Lee 2010 style), deterministic for a seed.

    - Yaw: a random initial heading, smooth swings both ways every 5-9 s (steps of 14-40 deg before
      scaling) plus a slow wander; the whole yaw motion is scaled so that the peak |yaw rate| over
      ``[0, duration_s]`` is exactly ``max_yaw_rate_deg_s``; the net yaw wanders over tens of degrees.
    - Position: altitude ``altitude_m`` +- 5 cm slow breathing (periods 7 and 40 s); horizontal drift of
      about ``drift_m`` (slow sines, periods 45 and 120 s).
    - Roll/pitch, PRESCRIBED mode (the default): three sines each (periods 1.2-9 s), peak about
      ``max_tilt_deg``, kinematically independent of the (quasi-static) position, so the accelerometer reads
      gravity in the tilted body (the hover assumption of paper C's accelerometer model).
    - COORDINATED mode: roll/pitch are what the thrust needs; a 1-4 cm position wobble (periods 1.4 and
      2.2 s) supplies accelerations for a tilt of about ``max_tilt_deg``, and the accelerometer reads pure
      thrust along body z.
    """
    if not (np.isfinite(duration_s) and duration_s > 0.0):
        raise InputError(f"duration_s must be positive, got {duration_s}")
    if not (np.isfinite(altitude_m) and altitude_m > 0.0):
        raise InputError(f"altitude_m must be positive, got {altitude_m}")
    rng = np.random.default_rng([TRAJECTORY_STREAM, 1, int(seed)])
    # The shape is drawn over at least the nominal duration so a shorter flight is a prefix of the long one.
    shape_duration_s = max(float(duration_s), NOMINAL_HOVER_DURATION_S)
    yaw0 = float(rng.uniform(-np.pi, np.pi))
    steps = _hover_yaw_steps(rng, shape_duration_s, np.radians(40.0), np.radians(50.0))
    wander = _random_sines(rng, (np.radians(12.0), np.radians(5.0)), (90.0, 35.0))
    raw_yaw = FunctionSum((steps, wander))
    grid = np.arange(0.0, shape_duration_s + 1e-9, 1e-3)
    peak = float(np.max(np.abs(raw_yaw.derivative(grid, 1))))
    scale = np.radians(max_yaw_rate_deg_s) / peak if peak > 0.0 else 1.0
    steps = TanhSteps(tuple(a * scale for a in steps.amplitudes), steps.centres_s, steps.widths_s)
    wander = SineSum(
        tuple(a * scale for a in wander.amplitudes), wander.omegas_rad_s, wander.phases_rad, yaw0
    )
    yaw = FunctionSum((steps, wander))

    # COORDINATED: a position wobble whose accelerations (about g tan(max_tilt)) produce the tilt.
    # PRESCRIBED: no wobble, so the accelerometer reads gravity in the tilted body (+ < 0.01 m/s^2).
    wobble_m = 0.0 if mode is AttitudeMode.PRESCRIBED else max_tilt_deg / 3.0

    def horizontal() -> FunctionSum:
        drift = _random_sines(rng, (0.6 * drift_m, 0.4 * drift_m), (120.0, 45.0))
        wobble = _random_sines(rng, (0.03 * wobble_m, 0.01 * wobble_m), (2.2, 1.4))
        return FunctionSum((drift, wobble))

    x = horizontal()
    y = horizontal()
    z = _random_sines(rng, (0.04, 0.01), (40.0, 7.0), offset=altitude_m)
    tilt = np.radians(max_tilt_deg)
    roll = _random_sines(rng, (0.5 * tilt, 0.3 * tilt, 0.2 * tilt), (9.0, 3.0, 1.3))
    pitch = _random_sines(rng, (0.5 * tilt, 0.3 * tilt, 0.2 * tilt), (8.0, 2.7, 1.2))
    return Trajectory(
        name="hover",
        duration_s=float(duration_s),
        path=AxesPath(x, y, z),
        yaw=yaw,
        mode=mode,
        roll=roll if mode is AttitudeMode.PRESCRIBED else None,
        pitch=pitch if mode is AttitudeMode.PRESCRIBED else None,
        info={"altitude_m": float(altitude_m), "max_yaw_rate_deg_s": float(max_yaw_rate_deg_s)},
    )


def turns_trajectory(
    seed: int = 0,
    z_start_m: float = 3.5,
    z_end_m: float = 4.0,
    radius_m: float = 1.1,
    turns: float = 2.0,
    hover_before_s: float = 5.0,
    manoeuvre_s: float = 40.0,
    hover_after_s: float = 5.0,
    heading_follows_path: bool = True,
) -> Trajectory:
    """Paper C's flight: hover at 3.5 m, two climbing turns (radius 1.1 m) to 4.0 m, hover; coordinated tilt.

    The start point is on the circle at a seed-dependent angle. The heading follows the path tangent (the
    vehicle turns with the path, 720 deg in total) unless ``heading_follows_path`` is False (constant yaw).
    Path length ``sqrt((2 pi turns radius)^2 + (z_end - z_start)^2)``: 13.832 m for the defaults. The septic
    speed profile peaks at 35/16 * length / manoeuvre_s = 0.76 m/s; the tilt peaks at 3.0 deg (roll into
    the turn) and the yaw rate at 39 deg/s.
    """
    for name, value in (("radius_m", radius_m), ("manoeuvre_s", manoeuvre_s), ("z_start_m", z_start_m)):
        if not (np.isfinite(value) and value > 0.0):
            raise InputError(f"{name} must be positive, got {value}")
    if hover_before_s < 0.0 or hover_after_s < 0.0:
        raise InputError("hover durations must be >= 0")
    rng = np.random.default_rng([TRAJECTORY_STREAM, 2, int(seed)])
    start_angle = float(rng.uniform(-np.pi, np.pi))
    helix = HelixPath(
        centre_x_m=0.0,
        centre_y_m=0.0,
        radius_m=float(radius_m),
        turns=float(turns),
        z_start_m=float(z_start_m),
        z_end_m=float(z_end_m),
        start_s=float(hover_before_s),
        duration_s=float(manoeuvre_s),
        start_angle_rad=start_angle,
    )
    if heading_follows_path:
        yaw: ScalarFunction = HeadingOf(helix)
    else:
        yaw = SineSum((), (), (), start_angle + np.pi / 2.0)
    return Trajectory(
        name="turns",
        duration_s=float(hover_before_s + manoeuvre_s + hover_after_s),
        path=helix,
        yaw=yaw,
        mode=AttitudeMode.COORDINATED,
        info={"path_length_m": helix.length_m, "radius_m": float(radius_m)},
    )


@dataclass(frozen=True)
class EnvelopedPath:
    """``centre + envelope(t) * motion(t)`` per axis, with ``envelope = S_up - S_down`` (two septic smooth
    steps: 0 before ``up``, 1 between, 0 after ``down``) so the flight starts and ends in a hover; all
    derivatives by the product rule (Leibniz)."""

    centre_m: tuple[float, float, float]
    motion: tuple[ScalarFunction, ScalarFunction, ScalarFunction]
    up: SmoothStep
    down: SmoothStep

    def derivatives(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        t = np.asarray(t_s, dtype=np.float64)
        env = [self.up.derivative(t, k) - self.down.derivative(t, k) for k in range(4)]
        binom = ((1,), (1, 1), (1, 2, 1), (1, 3, 3, 1))
        out = []
        for n in range(4):
            axes = []
            for axis, f in enumerate(self.motion):
                value = sum(c * env[k] * f.derivative(t, n - k) for k, c in enumerate(binom[n]))
                axes.append(value + (self.centre_m[axis] if n == 0 else 0.0))
            out.append(np.stack(axes, axis=-1))
        return out[0], out[1], out[2], out[3]


def agile_trajectory(
    seed: int = 0,
    duration_s: float = 60.0,
    hover_s: float = 4.0,
    ramp_s: float = 4.0,
    altitude_m: float = 2.0,
    altitude_swing_m: float = 0.9,
) -> Trajectory:
    """A longer, faster, more tilted indoor flight than paper C's: hover, then about 50 s of a figure of
    eight (about 2.4 x 1.4 m) with fast side-steps superposed, the altitude swinging between about 1.1 and
    2.9 m, a slowly swinging heading (+-70 deg), then hover again; coordinated tilt.

    Deterministic for a seed (phases and +-10 % periods). For seed 0 the speed peaks near 1.5 m/s and the
    tilt near 20 deg (``info`` holds the peaks over a 10 ms grid: ``max_speed_m_s``, ``max_tilt_deg``).
    """
    if not (np.isfinite(duration_s) and duration_s > 2.0 * (hover_s + ramp_s)):
        raise InputError(f"duration_s must exceed twice hover_s + ramp_s, got {duration_s}")
    rng = np.random.default_rng([TRAJECTORY_STREAM, 3, int(seed)])
    eight = 2.0 * np.pi / float(rng.uniform(11.0, 13.0))  # rad/s of the figure of eight
    phase = float(rng.uniform(-np.pi, np.pi))
    x = FunctionSum((SineSum((1.2,), (eight,), (phase,)), _random_sines(rng, (0.07,), (1.3,))))
    y = FunctionSum((SineSum((0.7,), (2.0 * eight,), (2.0 * phase,)), _random_sines(rng, (0.07,), (1.2,))))
    z = _random_sines(rng, (altitude_swing_m,), (14.0,))
    up = SmoothStep(hover_s, ramp_s)
    down = SmoothStep(duration_s - hover_s - ramp_s, ramp_s)
    path = EnvelopedPath((0.0, 0.0, float(altitude_m)), (x, y, z), up, down)
    yaw = _random_sines(rng, (np.radians(70.0),), (25.0,), offset=float(rng.uniform(-np.pi, np.pi)))
    trajectory = Trajectory(
        name="agile", duration_s=float(duration_s), path=path, yaw=yaw, mode=AttitudeMode.COORDINATED
    )
    grid = trajectory.sample(np.arange(0.0, duration_s, 0.01))
    speed = np.linalg.norm(grid.v_world_m_s, axis=1)
    tilt = np.degrees(np.arccos(np.clip(grid.R_world_body[:, 2, 2], -1.0, 1.0)))
    info = {
        "max_speed_m_s": float(speed.max()),
        "max_tilt_deg": float(tilt.max()),
        "min_altitude_m": float(grid.p_world_body_m[:, 2].min()),
        "max_altitude_m": float(grid.p_world_body_m[:, 2].max()),
        "path_length_m": float(np.sum(speed) * 0.01),
    }
    return Trajectory(
        name="agile",
        duration_s=float(duration_s),
        path=path,
        yaw=yaw,
        mode=AttitudeMode.COORDINATED,
        info=info,
    )
