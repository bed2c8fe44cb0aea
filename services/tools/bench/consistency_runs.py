"""The runs of ``capataz bench consistency``: each suite's errors against truth with the uncertainty the
service publishes with them, as NEES per sample (:func:`common.consistency.normalised_errors_squared`),
grouped by line (what is measured) for one seed.

- yaw: the field suite's flights through the core as ``bench yaw --suite field`` runs it
  (:func:`services.tools.bench.yaw_field.run_core`), once with the gyro prior and once without an IMU, on the
  same frames. Per pair: the published delta's error against the true yaw change over its
  ``delta_variance_rad2``, by provenance; per frame: the accumulated yaw's error against its
  ``yaw_variance_rad2``.
- estimator: paper C's and the agile flight through the proposal (``rectified``,
  :func:`common.estimation.replay.standard_estimators`); the attitude (world-frame error angles against the
  covariance of the ``attitude`` message, every 20th IMU output: 20 Hz) and the ``pose/vo`` position against
  the message's covariance, frames whose pair tracked: both as :mod:`services.estimator.outputs` publishes
  them.
- localizer: the field suite's scenes (the object and the office,
  :mod:`services.tools.bench.localizer_field`) through the model tracker with its defaults; the camera centre
  and world-frame error angles against the state's 6x6 covariance (the ``pose/pf`` message's), by tracking
  state.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from common.consistency import normalised_errors_squared
from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.estimation.replay import standard_estimators
from common.geometry import matrix_from_quaternion
from common.localization.pose import pose_errors, world_error_angles
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings, TrackerState
from common.localization.tracking import track_model
from common.metrics import yaw_error_rad
from common.provenance import Provenance
from common.sim.field import FIELD_SCENARIOS, field_flight
from common.sim.flight import Flight, FlightOptions, agile_flight, turns_flight
from common.sim.stream import flight_measurements
from common.types import FloatArray
from common.wire.messages import AttitudeEstimate, PoseEstimate
from common.wire.schema import WireModel
from common.yaw import YawSettings
from services.estimator.outputs import Publication, PublishedUncertainty
from services.estimator.settings import EstimatorSettings
from services.tools.bench.localizer_field import _object_scene, _office_scene, _Scene, _start
from services.tools.bench.yaw_field import run_core

logger = logging.getLogger(__name__)


@dataclass
class LineSamples:
    """One line's NEES of one seed (or merged seeds), each with the label of its time step: the same
    label in another seed is the same step of the same run (scenario, flight or scene and frame index)."""

    nees: list[float] = field(default_factory=list)
    steps: list[str] = field(default_factory=list)

    def extend(self, other: LineSamples) -> None:
        self.nees.extend(other.nees)
        self.steps.extend(other.steps)


#: The lines of one seed, and each line's degrees of freedom.
Samples = dict[str, LineSamples]
DOF: dict[str, int] = {}


def merge_samples(into: Samples, more: Samples) -> None:
    """Add each line of ``more`` to ``into``'s."""
    for line, values in more.items():
        into.setdefault(line, LineSamples()).extend(values)


T = TypeVar("T")

#: Every n-th attitude output (400 Hz IMU -> 20 Hz, the frame rate).
ATTITUDE_STRIDE = 20


def _add(out: Samples, line: str, dof: int, nees: FloatArray, run: str, steps: npt.ArrayLike) -> None:
    """Add the ``nees`` of ``line`` at time ``steps`` (frame or pair indices) of ``run``."""
    DOF[line] = dof
    k = np.asarray(steps).ravel()
    if k.size != np.asarray(nees).size:
        raise ValueError(f"{line}: {np.asarray(nees).size} NEES for {k.size} steps")
    samples = out.setdefault(line, LineSamples())
    samples.nees.extend(float(v) for v in nees)
    samples.steps.extend(f"{run}:{int(i)}" for i in k)


def two_folds(seeds: list[int]) -> list[tuple[list[int], list[int]]]:
    """A fit's two-fold check over ``seeds``: fit on the first half and score on the second, then the other
    way round; none when a half would be empty."""
    halves = [seeds[: len(seeds) // 2], seeds[len(seeds) // 2 :]]
    return [(halves[0], halves[1]), (halves[1], halves[0])] if all(halves) else []


# ------------------------------------------------------------------------------------------------------ yaw
#: the largest share of washed-out frames ``yaw_samples`` takes (``--glare``)
MAX_GLARE = 0.5
#: the grey level of a washed-out frame, and the random stream that picks them (per seed and scenario)
GLARE_LEVEL = 250
GLARE_STREAM = 7_707


def with_glare(
    frames: list[npt.NDArray[np.uint8]], share: float, seed: int, scenario: int
) -> list[npt.NDArray[np.uint8]]:
    """``frames`` with about ``share`` of them (never the first) washed out to one grey level, as sun glare
    or an exposure hiccup leaves them: no texture, so the pairs on either side cannot be measured and are
    bridged by the gyro (held without one). Which frames: drawn per ``seed`` and ``scenario``."""
    if share <= 0.0:
        return frames
    washed = np.random.default_rng([GLARE_STREAM, seed, scenario]).random(len(frames)) < share
    washed[0] = False
    return [np.full_like(f, GLARE_LEVEL) if w else f for f, w in zip(frames, washed, strict=True)]


def yaw_samples(seed: int, frames: int, scenarios: list[str] | None = None, glare: float = 0.0) -> Samples:
    """The yaw lines of one seed over the field scenarios (each rendered once, tracked with and without a
    gyro): ``yaw pair <provenance>`` (per pair, 1 dof) and ``yaw accumulated <gyro|no imu>`` (per frame).
    ``glare``: the share of frames washed out (:func:`with_glare`)."""
    out: Samples = {}
    settings = YawSettings()
    for name in scenarios or list(FIELD_SCENARIOS):
        flight = field_flight(name, seed=seed, n_frames=frames)
        rendered = with_glare(list(flight.frames()), glare, seed, list(FIELD_SCENARIOS).index(name))
        true_delta = np.diff(flight.yaw_rad)
        true_yaw = flight.yaw_rad - flight.yaw_rad[0]
        for gyro in (True, False):
            series = run_core(flight, settings, rendered, gyro)
            error = yaw_error_rad(series.delta_rad, true_delta)
            nees = normalised_errors_squared(error, series.delta_variance_rad2)
            provenance = np.array([p.value for p in series.provenance])
            pair = np.arange(len(provenance))
            for kind in Provenance:
                chosen = provenance == kind.value
                if np.any(chosen):
                    line = f"yaw pair {kind.value}{'' if gyro else ' (no imu)'}"
                    _add(out, line, 1, nees[chosen], name, pair[chosen])
            yaw = np.cumsum(series.delta_rad)
            accumulated = yaw_error_rad(yaw, true_yaw[1:])
            line = f"yaw accumulated {'gyro' if gyro else 'no imu'}"
            _add(out, line, 1, normalised_errors_squared(accumulated, series.yaw_variance_rad2), name, pair)
        logger.info("yaw seed %d %s done", seed, name)
    return out


# ------------------------------------------------------------------------------------------------ estimator
#: each takes the seed and the flight's options (e.g. its camera and IMU rates)
FLIGHTS: dict[str, Callable[..., Flight]] = {"paper_c": turns_flight, "agile": agile_flight}


def published_messages(
    outputs: list[AttitudeOutput | PoseOutput], max_pair_s: float, model: PublishedUncertainty
) -> list[AttitudeEstimate | PoseEstimate]:
    """The messages the service publishes of ``outputs`` (in order), with ``model``'s uncertainties."""
    messages: list[AttitudeEstimate | PoseEstimate] = []

    def put(_publisher: object, message: WireModel) -> bool:
        assert isinstance(message, AttitudeEstimate | PoseEstimate)
        messages.append(message)
        return True

    Publication("uav0", max_pair_s, model).publish(outputs, put, None, None)
    return messages


def estimator_outputs(flight: Flight, frames: int | None) -> list[AttitudeOutput | PoseOutput]:
    """The proposal's (``rectified``) outputs over the first ``frames`` frames of ``flight`` (None: all)."""
    estimator = standard_estimators(flight, 0, ("rectified",))["rectified"]
    outputs: list[AttitudeOutput | PoseOutput] = []
    for m in flight_measurements(flight, 0, frames):
        estimator.push(m)
        outputs.extend(estimator.process_due())
    outputs.extend(estimator.drain())
    return outputs


def attitude_errors(
    flight: Flight, messages: list[AttitudeEstimate | PoseEstimate]
) -> tuple[FloatArray, FloatArray]:
    """World-frame error angles (N, 3) of every ``ATTITUDE_STRIDE``-th ``attitude`` message of ``messages``
    against the flight's truth at its stamp, and the messages' covariances (N, 3, 3)."""
    attitudes = [m for m in messages if isinstance(m, AttitudeEstimate)][::ATTITUDE_STRIDE]
    imu = flight.imu
    idx = np.searchsorted(imu.stamps_s, np.array([m.stamp_s for m in attitudes]) - 1e-9)
    R_true = matrix_from_quaternion(imu.true_q_world_body[idx])
    R_est = matrix_from_quaternion(np.array([m.q_world_body for m in attitudes]))
    return world_error_angles(R_true, R_est), np.array([m.covariance for m in attitudes])


def per_flight(
    seed: int,
    frames: int | None,
    flights: list[str] | None,
    read: Callable[[Flight, list[AttitudeOutput | PoseOutput]], T],
    options: FlightOptions | None = None,
) -> dict[str, T]:
    """``read(flight, outputs)`` of each flight of one seed (the proposal's outputs over its first ``frames``
    frames; None: all), flown with ``options`` (e.g. other sensor rates; None: the flight's own)."""
    out: dict[str, T] = {}
    for name in flights or list(FLIGHTS):
        flight = FLIGHTS[name](seed, **(options or {}))
        out[name] = read(flight, estimator_outputs(flight, frames))
        logger.info("estimator seed %d %s read", seed, name)
    return out


def tracked_poses(messages: list[AttitudeEstimate | PoseEstimate]) -> list[PoseEstimate]:
    """The ``pose/vo`` messages of ``messages`` whose pair tracked."""
    return [m for m in messages if isinstance(m, PoseEstimate) and m.tracking_state == "tracking"]


def frame_indices(flight: Flight, poses: list[PoseEstimate]) -> npt.NDArray[np.intp]:
    """The index of each of ``poses``' frames in ``flight``."""
    return np.searchsorted(flight.frame_stamps_s, np.array([m.stamp_s for m in poses]) - 1e-9)


def position_errors(flight: Flight, poses: list[PoseEstimate]) -> tuple[FloatArray, FloatArray]:
    """Position errors (N, 3) of ``poses`` against the flight's truth at their frames, and their
    covariances' position blocks (N, 3, 3)."""
    k = frame_indices(flight, poses)
    errors = np.array([m.p_world_body_m for m in poses]).reshape(-1, 3) - flight.p_world_body_m[k]
    return errors, np.array([np.asarray(m.covariance)[:3, :3] for m in poses]).reshape(-1, 3, 3)


def estimator_lines(
    name: str,
    flight: Flight,
    outputs: list[AttitudeOutput | PoseOutput],
    model: PublishedUncertainty | None = None,
) -> Samples:
    """The lines of one flight's ``outputs`` published with ``model`` (None: the service's defaults)."""
    out: Samples = {}
    defaults = EstimatorSettings()
    messages = published_messages(outputs, defaults.max_pair_s, model or defaults.published_uncertainty())
    angles, P = attitude_errors(flight, messages)
    k = np.arange(len(angles))  # every ATTITUDE_STRIDE-th IMU output: the same stamps in every seed
    _add(out, f"estimator attitude {name}", 3, normalised_errors_squared(angles, P), name, k)
    _add(out, f"estimator tilt {name}", 2, normalised_errors_squared(angles[:, :2], P[:, :2, :2]), name, k)
    _add(out, f"estimator heading {name}", 1, normalised_errors_squared(angles[:, 2], P[:, 2, 2]), name, k)
    poses = tracked_poses(messages)
    e, C = position_errors(flight, poses)
    k = frame_indices(flight, poses)
    _add(out, f"estimator position {name}", 3, normalised_errors_squared(e, C), name, k)
    _add(out, f"estimator horizontal {name}", 2, normalised_errors_squared(e[:, :2], C[:, :2, :2]), name, k)
    _add(out, f"estimator altitude {name}", 1, normalised_errors_squared(e[:, 2], C[:, 2, 2]), name, k)
    return out


def estimator_samples(
    seed: int, frames: int | None, flights: list[str] | None = None, options: FlightOptions | None = None
) -> Samples:
    """The estimator lines of one seed, per flight: ``estimator attitude`` (3 dof), its ``tilt`` (world x
    and y) and its ``heading`` (world z) apart, ``estimator position`` (3 dof, tracking frames), ``estimator
    horizontal`` (x, y) and ``estimator altitude`` (z), each against the covariance of the message the
    service publishes (:class:`~services.estimator.outputs.Publication` with the default settings); the
    flights flown with ``options`` (None: their own camera and IMU rates)."""
    out: Samples = {}
    for name in flights or list(FLIGHTS):
        merge_samples(out, per_flight(seed, frames, [name], partial(estimator_lines, name), options)[name])
    return out


# ------------------------------------------------------------------------------------------------ localizer
def tracked_scene(
    scene: _Scene, seed: int, settings: TrackerSettings | None = None
) -> tuple[list[TrackerState], FloatArray]:
    """The model tracker's state after each of ``scene``'s frames (``settings``; None: the defaults), from
    the bench's start for ``seed``, and each state's error (N, 6) against the truth: camera centre (m) and
    world-frame error angles (rad)."""
    tracker = ModelTracker(scene.model, scene.camera, settings or TrackerSettings())
    rng = np.random.default_rng(40_000 + seed)
    start = tracker.start(_start(scene, seed))
    states = list(track_model(tracker, scene.images, scene.flight.times_s, start, rng, scene.gyro))
    n = len(states)
    p = np.array([s.pose.p_world_camera_m for s in states])
    R = np.array([s.pose.R_world_camera for s in states])
    return states, pose_errors(scene.flight.p_world_camera_m[:n], scene.flight.R_world_camera[:n], p, R)


#: the localizer suite's scenes, each built from ``(frames, seed)``
LOCALIZER_SCENES: dict[str, Callable[[int, int], _Scene]] = {"object": _object_scene, "office": _office_scene}


def localizer_samples(seed: int, frames: int, scenes: list[str] | None = None) -> Samples:
    """The localizer lines of one seed: ``localizer <scene> <state>`` (6 dof: camera centre and world-frame
    error angles against the state's covariance), and the position and rotation parts of tracking frames."""
    out: Samples = {}
    for name in scenes or list(LOCALIZER_SCENES):
        states, error = tracked_scene(LOCALIZER_SCENES[name](frames, seed), seed)
        n = len(states)
        P = np.array([s.covariance for s in states])
        status = np.array([s.status.value for s in states])
        frame = np.arange(n)
        for value in sorted(set(status.tolist())):
            chosen = status == value
            nees = normalised_errors_squared(error[chosen], P[chosen])
            _add(out, f"localizer {name} {value}", 6, nees, name, frame[chosen])
        tracking = status == "tracking"
        if np.any(tracking):
            e, C, k = error[tracking], P[tracking], frame[tracking]
            position = normalised_errors_squared(e[:, :3], C[:, :3, :3])
            _add(out, f"localizer {name} tracking position", 3, position, name, k)
            rotation = normalised_errors_squared(e[:, 3:], C[:, 3:, 3:])
            _add(out, f"localizer {name} tracking rotation", 3, rotation, name, k)
        logger.info("localizer seed %d %s done", seed, name)
    return out
