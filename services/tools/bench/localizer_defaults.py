"""``capataz bench localizer --suite defaults``: the model tracker with **default settings only**, across
model scales, frame rates and motions, plus the real cube video (:mod:`services.tools.bench.localizer_cube`).

Scenes (rendered, exact poses, no odometry):

- ``small``: the tabletop part scaled to 0.1 m (bounding-box diagonal), seen from 0.3-0.6 m;
- ``large``: the same part scaled to 1 m, seen from 2-4 m (texture scaled alike);
- (both: the clutter scaled with the orbit, :func:`object_world`, so the camera stays inside the room);
- ``office``: the built-in office and its 320x240 camera flying its ellipse.

Each at 5, 20 and 60 fps; motion ``slow`` (at most 0.6 % of the distance and 0.7 deg per frame; the office
at a quarter of its speed) and ``fast`` (the object flight's 3 % of the distance and 2 deg per frame; the
office at its own speed); starts exact, 1.5 % of the distance / 2 deg off and 4.5 % / 5 deg off (10 mm and
30 mm at the object flight's 0.66 m, scaled by distance; random directions by seed); ``--seeds`` runs each
(own flight and filter seed; ``--quick``: 1 seed, 90 frames).

Per cell: ``position_median_share`` (median position error over the distance to the model in view, frames of
runs not lost), ``rotation_median_deg``, ``lost_runs`` (a run is lost when more than 10 % of its frames
from frame 10 on are off by more than 5 % of the distance or 5 deg, or it ends ``lost``),
``false_tracking_frames`` (state ``tracking`` while more than 5 % of the distance off) and
``false_reject_frames`` (state not ``tracking`` while within 1 % and 1 deg), ``step_ms_median`` (CPU time of a
full step, this process, shared host). ``meets`` is the issue's cell goal: 0 lost, <= 1 % and <= 0.5 deg.
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import CapatazError
from common.geometry import R_BODY_CAMERA_FORWARD
from common.localization.model import SceneModel, scene_from_dict, scene_to_dict
from common.localization.office import default_scene, office_camera
from common.localization.pose import CameraPose
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings, TrackingStatus
from common.localization.tracking import pose_errors_mm_deg, track_model
from common.sim.objects import (
    OBJECT_RENDER,
    CameraFlight,
    object_camera,
    object_flight,
    offset_pose,
    render_camera_flight,
    scaled_scene,
    tabletop_model,
    tabletop_scene,
)
from common.sim.office_run import DEFAULT_FLIGHT_RENDER
from common.sim.scene import default_flight, render_flight
from services.tools.bench.localizer_cube import cube_runs

logger = logging.getLogger(__name__)

#: the part's bounding-box diagonal (m) and the object flight's mean distance (m)
PART_SIZE_M = 0.427
ORBIT_M = 0.66
#: scale of the world and of the orbit's distance per object scene
OBJECT_SCALES = {"small": (0.1 / PART_SIZE_M, 0.45 / (0.1 / PART_SIZE_M) / ORBIT_M),
                 "large": (1.0 / PART_SIZE_M, 3.0 / (1.0 / PART_SIZE_M) / ORBIT_M)}  # fmt: skip
RATES_HZ = (5.0, 20.0, 60.0)
#: per-frame limits (share of the mean distance, deg) per motion; the office's speed factor
MOTIONS = {"slow": (0.006, 0.7, 0.25), "fast": (0.03, 2.0, 1.0)}
#: start errors (share of the distance, deg)
STARTS = {"exact": (0.0, 0.0), "near": (0.015, 2.0), "far": (0.045, 5.0)}
OFF_SHARE, OFF_DEG = 0.05, 5.0
GOAL_SHARE, GOAL_DEG = 0.01, 0.5


def add_defaults_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group(
        "defaults suite",
        "default settings across scales, rates and motions, and the cube (localizer_defaults.json); --seeds "
        "runs per cell and start, --frames per run",
    )
    group.add_argument("--quick", action="store_true", help="defaults suite: 1 seed, 90 frames per run")
    group.add_argument("--cells", nargs="+", help="defaults suite: only cells named scene/rate/motion")
    group.add_argument("--cube-dir", type=Path, default=Path("../shared/data/visp_cube"), help="cube data")
    group.add_argument("--cube-runs", type=int, default=12, help="cube runs (0: none; default 12)")


def _object_cell(scene: str, rate: float, motion: str, frames: int, seed: int) -> tuple[Any, ...]:
    scale, distance_scale = OBJECT_SCALES[scene]
    mean_d = scale * distance_scale * ORBIT_M
    share, deg, _ = MOTIONS[motion]
    flight = object_flight(frames, seed, rate, scale=scale, distance_scale=distance_scale,
                           max_step_m=share * mean_d, max_step_rad=float(np.radians(deg)))  # fmt: skip
    camera = object_camera()
    options = replace(OBJECT_RENDER, texture_frequency=OBJECT_RENDER.texture_frequency / scale)
    world = object_world(scale, distance_scale)
    images = list(render_camera_flight(world, flight, camera, options, np.random.default_rng(seed)))
    return scaled_scene(tabletop_model(), scale), camera, flight, images


def object_world(scale: float, distance_scale: float) -> SceneModel:
    """What a scaled cell's camera sees: the part scaled by ``scale``, the clutter (table, markings, boxes,
    back wall) by ``scale x distance_scale``, i.e. with the orbit, so that the camera stays where the object
    flight keeps it, inside the room. Scaled with the part alone, the orbit left the room: the back wall hid
    the part from seed 2's flight (and from seed 4's, fast) for most of the run, and nothing could be
    tracked."""
    part = scene_to_dict(scaled_scene(tabletop_model(), scale))
    clutter = scene_to_dict(scaled_scene(tabletop_scene(with_part=False), scale * distance_scale))
    offset = len(part["vertices"])
    faces = part["faces"] + [{**f, "vertices": [v + offset for v in f["vertices"]]} for f in clutter["faces"]]
    return scene_from_dict(
        {"name": "tabletop+clutter", "vertices": part["vertices"] + clutter["vertices"], "faces": faces}
    )


def _office_cell(rate: float, motion: str, frames: int, seed: int) -> tuple[Any, ...]:
    speed = MOTIONS[motion][2]
    sim = default_flight(n_frames=frames, rate_hz=rate / speed)  # the same path, slower per frame
    poses = [CameraPose.from_body_state(s, R_BODY_CAMERA_FORWARD) for s in sim.states]
    flight = CameraFlight(
        times_s=np.arange(frames) / rate,
        p_world_camera_m=np.array([p.p_world_camera_m for p in poses]),
        R_world_camera=np.array([p.R_world_camera for p in poses]),
    )
    camera, scene = office_camera(), default_scene()
    images = list(render_flight(scene, sim, camera, DEFAULT_FLIGHT_RENDER, np.random.default_rng(seed)))
    return scene, camera, flight, images


def _run(
    tracker: ModelTracker, flight: CameraFlight, images: list[np.ndarray], start: CameraPose, seed: int
) -> dict[str, Any]:
    rng = np.random.default_rng(80_000 + seed)
    states, ms = [], []
    c0 = time.process_time()
    for state in track_model(tracker, images, flight.times_s, tracker.start(start), rng):
        ms.append((time.process_time() - c0) * 1e3)
        states.append(state)
        c0 = time.process_time()
    pos_mm, rot_deg = pose_errors_mm_deg(states, flight.p_world_camera_m, flight.R_world_camera)
    distance = np.array([tracker.viewing_distance_m(flight.pose(i)) for i in range(len(states))])
    share = 1e-3 * pos_mm / distance
    tracking = np.array([s.status is TrackingStatus.TRACKING for s in states])
    off = (share > OFF_SHARE) | (rot_deg > OFF_DEG)
    right = (share <= GOAL_SHARE) & (rot_deg <= 1.0)
    tail = off[10:] if off.size > 20 else off
    lost = bool(np.mean(tail) > 0.1) or states[-1].status is TrackingStatus.LOST
    far = share > OFF_SHARE
    return {"share": share, "rot": rot_deg, "lost": lost, "false_tracking": int(np.sum(tracking & far)),
            "false_reject": int(np.sum(~tracking & right)), "right": int(np.sum(right)),
            "off": int(np.sum(far)), "frames": len(states), "ms": ms[1:]}  # fmt: skip


def measure_cell(scene: str, rate: float, motion: str, frames: int, seeds: int) -> dict[str, Any]:
    runs = []
    for seed in range(seeds):
        if scene == "office":
            model, camera, flight, images = _office_cell(rate, motion, frames, seed)
        else:
            model, camera, flight, images = _object_cell(scene, rate, motion, frames, seed)
        tracker = ModelTracker(model, camera, TrackerSettings())
        d0 = tracker.viewing_distance_m(flight.pose(0))
        for k, (name, (share, deg)) in enumerate(STARTS.items()):
            start = offset_pose(flight.pose(0), share * d0, float(np.radians(deg)), 90_000 + 10 * seed + k)
            run = _run(tracker, flight, images, start, 10 * seed + k)
            run["start"] = name
            runs.append(run)
    kept = [r for r in runs if not r["lost"]] or [{"share": np.array([np.nan]), "rot": np.array([np.nan])}]
    share = float(np.median(np.concatenate([r["share"] for r in kept])))
    rot = float(np.median(np.concatenate([r["rot"] for r in kept])))
    lost = sum(r["lost"] for r in runs)
    row = {
        "cell": f"{scene}/{rate:g}/{motion}",
        "position_median_share": share,
        "rotation_median_deg": rot,
        "lost_runs": lost,
        "runs": len(runs),
        "lost_starts": [r["start"] for r in runs if r["lost"]],
        "frames": sum(r["frames"] for r in runs),
        "false_tracking_frames": sum(r["false_tracking"] for r in runs),
        "off_frames": sum(r["off"] for r in runs),
        "false_reject_frames": sum(r["false_reject"] for r in runs),
        "right_frames": sum(r["right"] for r in runs),
        "step_ms_median": float(np.median(np.concatenate([r["ms"] for r in runs]))),
    }
    row["meets"] = bool(lost == 0 and share <= GOAL_SHARE and rot <= GOAL_DEG)
    logger.info("defaults %s", row)
    return row


def run_defaults(args: argparse.Namespace) -> dict[str, Any]:
    if getattr(args, "cube_runs", 0) > 0 and not (args.cube_dir / "cube.cao").is_file():
        raise CapatazError(f"no cube data in {args.cube_dir} (--cube-dir; --cube-runs 0 to skip the cube)")
    quick = getattr(args, "quick", False)
    seeds = 1 if quick else args.seeds
    frames = 90 if quick else args.frames
    cells = [(s, r, m) for s in ("small", "large", "office") for r in RATES_HZ for m in MOTIONS]
    if getattr(args, "cells", None):
        names = {f"{c[0]}/{c[1]:g}/{c[2]}" for c in cells}
        unknown = sorted(set(args.cells) - names)
        if unknown:
            raise CapatazError(f"unknown cell(s) {unknown}; cells are scene/rate/motion, e.g. small/20/slow")
        cells = [c for c in cells if f"{c[0]}/{c[1]:g}/{c[2]}" in args.cells]
    rows = [measure_cell(s, r, m, frames, seeds) for s, r, m in cells]
    frames_all = sum(r["frames"] for r in rows)
    result: dict[str, Any] = {
        "bench_name": "localizer_defaults",
        "settings": "defaults only (TrackerSettings())",
        "reduced": seeds < 5 or len(cells) < 18,
        "seeds": seeds,
        "frames_per_run": frames,
        "cells": rows,
        "cells_meeting": sum(r["meets"] for r in rows),
        "false_tracking_share": sum(r["false_tracking_frames"] for r in rows) / max(frames_all, 1),
        "false_accept_share_of_off_frames": sum(r["false_tracking_frames"] for r in rows)
        / max(sum(r["off_frames"] for r in rows), 1),
        "false_reject_share_of_right_frames": sum(r["false_reject_frames"] for r in rows)
        / max(sum(r["right_frames"] for r in rows), 1),
        "table": [{k: v for k, v in r.items() if k != "lost_starts"} for r in rows],
    }
    if getattr(args, "cube_runs", 0) > 0:
        out = getattr(args, "out", Path("out/bench"))
        result["cube"] = cube_runs(args.cube_dir, args.cube_runs, TrackerSettings(), out)
    return result
