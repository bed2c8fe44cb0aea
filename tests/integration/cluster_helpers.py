"""Shared pieces of the cluster integration tests: the in-process reference and a small cluster spec."""

from __future__ import annotations

import os

import numpy as np

from common.dispatch import Balance
from common.sim.flight import hover_flight
from common.yaw import YawSettings
from services.master.service import Topology
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.flight_prior import FlightPrior, Level

#: Frames of the fault run in CI (the issue's 2041-frame figure: CAPATAZ_CLUSTER_FRAMES=2041).
FAULT_FRAMES = int(os.environ.get("CAPATAZ_CLUSTER_FRAMES", "600"))


def reference_yaw_rad(n_frames: int, seed: int = 0, level: Level = Level.NONE) -> np.ndarray:
    """In-process yaw of every frame of the camera's default hover flight (frame 0 = 0), as the master
    measures it: the flight's rig, the frame stamps, the gyro prior and the level views from the camera's
    IMU samples (:class:`~services.tools.flight_prior.FlightPrior`; ``level`` IMU for a master with
    ``--level-views``)."""
    flight = hover_flight(seed=seed, n_frames=n_frames)
    prior = FlightPrior(flight, level=level)
    tracker = prior.tracker(YawSettings())
    stamps = flight.frame_stamps_s
    state = tracker.initial_state(flight.frame(0), stamp_s=float(stamps[0]), R_level_body=prior.tilt(0))
    yaw = np.zeros(n_frames)
    for k in range(1, n_frames):
        gyro, tilt = prior.gyro_delta_rad(k), prior.tilt(k)
        state, estimate = tracker.track(state, flight.frame(k), float(stamps[k]), gyro, tilt)
        yaw[k] = estimate.yaw_rad
    return yaw


def two_by_two(topology: str = "master-foreman-worker", workers: int = 2) -> ClusterSpec:
    return ClusterSpec(
        name="test",
        topology=Topology(topology),
        balance=Balance.TIME,
        hosts=(HostSpec(name="h1", workers=workers), HostSpec(name="h2", workers=workers)),
    )
