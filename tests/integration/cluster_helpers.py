"""Shared pieces of the cluster integration tests: the in-process reference and a small cluster spec."""

from __future__ import annotations

import os

import numpy as np

from common.dispatch import Balance
from common.sim.flight import hover_flight
from common.yaw import YawSettings, YawTracker, gyro_delta_yaw_rad, make_patch_grid
from services.master.service import Topology
from services.tools.cluster_file import ClusterSpec, HostSpec

#: Frames of the fault run in CI (the issue's 2041-frame figure: CAPATAZ_CLUSTER_FRAMES=2041).
FAULT_FRAMES = int(os.environ.get("CAPATAZ_CLUSTER_FRAMES", "600"))


def reference_yaw_rad(n_frames: int, seed: int = 0) -> np.ndarray:
    """In-process yaw of every frame of the camera's default hover flight (frame 0 = 0), with the frame stamps
    and the gyro prior the master gets from the camera's IMU samples."""
    flight = hover_flight(seed=seed, n_frames=n_frames)
    settings = YawSettings()
    tracker = YawTracker(settings, make_patch_grid((flight.camera.height, flight.camera.width), settings))
    stamps = flight.frame_stamps_s
    state = tracker.initial_state(flight.frame(0), stamp_s=float(stamps[0]))
    yaw = np.zeros(n_frames)
    for k in range(1, n_frames):
        gyro = gyro_delta_yaw_rad(flight.imu.stamps_s, flight.imu.gyro_rad_s, stamps[k - 1], stamps[k])
        state, estimate = tracker.track(state, flight.frame(k), float(stamps[k]), gyro)
        yaw[k] = estimate.yaw_rad
    return yaw


def two_by_two(topology: str = "master-foreman-worker", workers: int = 2) -> ClusterSpec:
    return ClusterSpec(
        name="test",
        topology=Topology(topology),
        balance=Balance.TIME,
        hosts=(HostSpec(name="h1", workers=workers), HostSpec(name="h2", workers=workers)),
    )
