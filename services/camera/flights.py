"""The simulated flights the camera replays (``--flight``): the ground flights (paper A's hover, paper C's
turns, the field scenarios of :mod:`common.sim.field`) and the localizer's office flight with its odometry,
each as a :class:`~services.camera.sources.CameraSource` (:func:`flight_source`)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from common.camera import DEFAULT_HFOV_DEG, CameraModel
from common.datasets.calibration import opencv_yaml_text
from common.errors import CapatazError
from common.estimation.measurements import FrameMeasurement
from common.localization.odometry import noisy_odometry
from common.localization.office import OFFICE_HFOV_DEG, default_scene
from common.rig import Rig
from common.sim.field import FIELD_SCENARIOS, field_flight, scenario_camera
from common.sim.flight import Flight, hover_flight, turns_flight
from common.sim.scene import DEFAULT_FLIGHT_RENDER, default_flight, render_flight
from common.sim.stream import flight_measurements
from common.wire.messages import PoseEstimate
from services.camera.settings import CameraSettings, FlightName
from services.camera.sources import CameraSource, OdometrySample, OnSkip, Sample

#: the office flight's default image size (width, height)
OFFICE_SIZE = (320, 240)


def simulated_flight(settings: CameraSettings) -> Flight:
    """The ground flight the camera replays (the in-process reference builds the same one); at another
    ``--width`` x ``--height`` each flight keeps its own lens's view (a field scenario its wide angle or its
    pinhole, :func:`~common.sim.field.scenario_camera`)."""
    size = None if settings.width is None or settings.height is None else (settings.width, settings.height)
    if settings.flight.value in FIELD_SCENARIOS:
        scenario = FIELD_SCENARIOS[settings.flight.value]
        lens = None if size is None else scenario_camera(scenario, *size)
        return field_flight(scenario, seed=settings.seed, n_frames=settings.frames, camera=lens)
    camera = None if size is None else CameraModel.from_hfov(*size, DEFAULT_HFOV_DEG)
    if settings.flight is FlightName.TURNS:
        return turns_flight(seed=settings.seed, camera=camera)
    return hover_flight(seed=settings.seed, n_frames=settings.frames, camera=camera)


def office_frames(settings: CameraSettings) -> Iterator[tuple[int, float, np.ndarray]]:
    """The localizer's default flight through the built-in office: the same frames as
    ``common.sim.office_run.simulate_run(settings.frames, settings.seed)``."""
    camera = CameraModel.from_hfov(
        settings.width or OFFICE_SIZE[0], settings.height or OFFICE_SIZE[1], OFFICE_HFOV_DEG
    )
    flight = default_flight(n_frames=settings.frames)
    rng = np.random.default_rng(settings.seed)
    images = render_flight(default_scene(), flight, camera, DEFAULT_FLIGHT_RENDER, rng)
    for i, image in enumerate(images):
        yield i, float(flight.times_s[i]), image


def office_odometry_poses(settings: CameraSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps (T,), positions (T, 3) and Euler angles (T, 3) whose frame-to-frame differences are the office
    flight's noisy odometry (the localizer's in-process stand-in for VO), starting at the true first pose."""
    flight = default_flight(n_frames=settings.frames)
    odometry = noisy_odometry(
        flight.velocities_world_m_s, flight.euler_rates_rad_s, np.random.default_rng(settings.seed + 1)
    )
    dt_s = np.diff(flight.times_s, prepend=flight.times_s[0])[:, None]
    start = flight.states[0]
    positions = start[:3] + np.cumsum(odometry.velocities_world_m_s * dt_s, axis=0)
    angles = start[3:] + np.cumsum(odometry.euler_rates_rad_s * dt_s, axis=0)
    return flight.times_s, positions, angles


def write_flight_calibration(path: Path, settings: CameraSettings) -> int:
    """``--write-calibration``: the simulated ground flight's camera as OpenCV YAML (for ``master
    --calibration``); exit code 0."""
    if settings.images is not None or settings.flight is FlightName.OFFICE:
        raise CapatazError("--write-calibration needs a simulated ground flight (not --images or office)")
    path.write_text(opencv_yaml_text(simulated_flight(settings).camera))
    print(f"wrote {path}")
    return 0


def truth_pose(uav: str, seq: int, stamp_s: float, flight: Flight, i: int) -> PoseEstimate:
    """The simulated flight's true pose at frame ``i`` (world frame, zero covariance, source ``truth``)."""
    return PoseEstimate(
        uav=uav,
        seq=seq,
        stamp_s=stamp_s,
        p_world_body_m=flight.p_world_body_m[i],
        q_world_body=flight.q_world_body[i],
        covariance=np.zeros((6, 6)),
        source="truth",
    )


def flight_source(settings: CameraSettings) -> CameraSource:
    """The simulated flight of ``settings`` as the camera's source: a ground flight's one stream
    (:func:`common.sim.stream.flight_measurements`) with its true poses, or the office flight's frames with
    its odometry; frames at ``--fps`` frames per second."""
    if settings.flight is FlightName.OFFICE:
        return _office_source(settings)
    flight = simulated_flight(settings)
    camera = flight.camera
    size = f"{camera.width}x{camera.height}"
    return CameraSource(
        f"the simulated {settings.flight.value} flight ({flight.n_frames} frames of {size})",
        lambda _skip: flight_measurements(flight),
        frames=flight.n_frames,
        width=camera.width,
        height=camera.height,
        truth=lambda uav, seq, stamp_s, i: truth_pose(uav, seq, stamp_s, flight, i),
        paced_by_fps=True,
        rig=Rig(
            camera,
            flight.R_body_camera,
            R_body_imu=flight.imu.R_body_imu,
            time_offset_s=flight.imu.time_offset_s,
        ),
    )


def _office_source(settings: CameraSettings) -> CameraSource:
    stamps, positions, angles = office_odometry_poses(settings)

    def samples(_skip: OnSkip | None) -> Iterator[Sample]:
        """Before each frame, the odometry poses stamped in ``(previous frame, this frame]``."""
        previous = -np.inf
        for _i, stamp_s, image in office_frames(settings):
            a, b = np.searchsorted(stamps, [previous, stamp_s], side="right")
            for k in range(int(a), int(b)):
                yield OdometrySample(float(stamps[k]), positions[k], angles[k])
            yield FrameMeasurement(stamp_s, image)
            previous = stamp_s

    return CameraSource(
        f"the simulated office flight ({settings.frames} frames)",
        samples,
        frames=settings.frames,
        width=settings.width or OFFICE_SIZE[0],
        height=settings.height or OFFICE_SIZE[1],
        paced_by_fps=True,
    )
