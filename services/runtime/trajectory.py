"""TUM trajectory output of capataz's estimates: ``--trajectory FILE`` on the services that publish them,
and the files ``capataz run`` writes into ``out/tum/`` beside their ground truth.

| estimate (key)                 | TUM pose written                                  | evo relation         |
| ------------------------------ | ------------------------------------------------- | -------------------- |
| YawEstimate (``yaw``)          | rotation about world z by ``yaw_rad``, position 0 | ``-r angle_deg``     |
| AttitudeEstimate (``attitude``)| ``q_world_body``, position 0                      | ``-r angle_deg``     |
| PoseEstimate (``pose/vo|pf``)  | ``p_world_body_m``, ``q_world_body``              | ``-r trans_part``    |

Rotation-only files carry position 0 in both the estimate and its ground truth, so their translation APE
is 0 by construction. Check a file with evo: ``evo_ape tum out/tum/pose_vo_truth.tum
out/tum/pose_vo.tum -r trans_part`` (no alignment: capataz estimates are in the world frame already).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from common.datasets.tum import Trajectory, TumWriter, write_tum
from common.geometry import constant, quaternion_from_euler
from common.metrics import ape_rotation_rmse_deg, ape_translation_rmse_m
from common.wire.messages import AttitudeEstimate, PoseEstimate, YawEstimate
from common.wire.schema import WireModel

_ZERO = constant(np.zeros(3))


def add_trajectory_argument(parser: argparse.ArgumentParser, what: str, flag: str = "--trajectory") -> str:
    """The option ``flag`` of a TUM file of ``what``; returns its name in the parsed arguments."""
    return parser.add_argument(flag, type=Path, help=f"also write {what} as a TUM trajectory file").dest


def tum_pose(message: WireModel) -> tuple[float, np.ndarray, np.ndarray]:
    """(stamp, position, quaternion wxyz) of an estimate, as in the table of the module docstring."""
    if isinstance(message, YawEstimate):
        return message.stamp_s, _ZERO, np.asarray(quaternion_from_euler(0.0, 0.0, message.yaw_rad))
    if isinstance(message, AttitudeEstimate):
        return message.stamp_s, _ZERO, message.q_world_body
    if isinstance(message, PoseEstimate):
        return message.stamp_s, message.p_world_body_m, message.q_world_body
    raise TypeError(f"{type(message).__name__} is not an estimate with a pose")


class TrajectoryTap:
    """The ``--trajectory`` files of a service: one TUM writer per estimate type it publishes."""

    def __init__(self, paths: dict[type[WireModel], Path | None]) -> None:
        self.writers = {cls: TumWriter(path) for cls, path in paths.items() if path is not None}

    def write(self, message: WireModel) -> None:
        writer = self.writers.get(type(message))
        if writer is not None:
            writer.write(*tum_pose(message))

    def close(self) -> None:
        for writer in self.writers.values():
            writer.close()


def run_with_trajectories(service: Any, paths: dict[type[WireModel], Path | None]) -> int:
    """``service.run()`` with its ``trajectory_tap`` open (files closed however the service ends)."""
    tap = TrajectoryTap(paths)
    service.trajectory_tap = tap if tap.writers else None
    try:
        return int(service.run())
    finally:
        tap.close()


def register_estimating_service(
    subparsers: Any,
    name: str,
    help_text: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    start: Callable[[argparse.Namespace], Any],
    trajectories: dict[type[WireModel], tuple[str, str]],
) -> None:
    """``capataz NAME``: a service that publishes estimates. Its options (``add_arguments``), then one TUM
    file option per estimate type (``{type: (flag, what it writes)}``); its handler builds the service
    (``start(args)``) and runs it with those files open (:func:`run_with_trajectories`)."""
    parser = subparsers.add_parser(name, help=help_text)
    add_arguments(parser)
    dests = {cls: add_trajectory_argument(parser, what, flag) for cls, (flag, what) in trajectories.items()}

    def run(args: argparse.Namespace) -> int:
        service = start(args)
        return run_with_trajectories(service, {cls: getattr(args, dest) for cls, dest in dests.items()})

    parser.set_defaults(handler=run)


def write_with_truth(out_dir: Path, name: str, estimate: Trajectory, truth: Trajectory) -> dict[str, Any]:
    """Write ``{name}.tum`` and ``{name}_truth.tum`` (truth at the estimate's stamps) and return capataz's
    APE of the pair (translation RMSE m, rotation RMSE deg) with the files and the evo command."""
    est_path = write_tum(Path(out_dir) / f"{name}.tum", estimate)
    truth_path = write_tum(Path(out_dir) / f"{name}_truth.tum", truth)
    rotation_only = not np.any(estimate.p_world_body_m) and not np.any(truth.p_world_body_m)
    translation = rotation = math.nan
    if len(estimate) and not rotation_only:
        translation = ape_translation_rmse_m(
            estimate.stamps_s, estimate.p_world_body_m, truth.stamps_s, truth.p_world_body_m
        )
    rotation = ape_rotation_rmse_deg(
        estimate.stamps_s, estimate.q_world_body, truth.stamps_s, truth.q_world_body
    )
    relation = "-r angle_deg" if rotation_only else "-r trans_part"
    return {
        "file": str(est_path),
        "truth": str(truth_path),
        "poses": len(estimate),
        "ape_translation_rmse_m": translation,
        "ape_rotation_rmse_deg": rotation,
        "evo": f"evo_ape tum {truth_path} {est_path} {relation}",
    }


def truth_at(
    stamps_s: np.ndarray, truth_stamps_s: np.ndarray, p_m: np.ndarray, q_wxyz: np.ndarray
) -> Trajectory:
    """The ground-truth poses at ``stamps_s`` (each must be one of ``truth_stamps_s``, within 1 us)."""
    idx = np.clip(np.searchsorted(truth_stamps_s, stamps_s - 1e-9), 0, len(truth_stamps_s) - 1)
    if np.any(np.abs(truth_stamps_s[idx] - stamps_s) > 1e-6):
        raise ValueError("an estimate's stamp has no ground-truth pose")
    return Trajectory(np.asarray(stamps_s, dtype=np.float64), p_m[idx], q_wxyz[idx])
