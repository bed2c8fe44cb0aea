"""Refine: a turning frame's second patch pass on every patch against the sub-grid of ``refine_max_patches``.

The core measures a pair again on frame k turned back by its first estimate when it turns more than
``refine_min_deg`` (:func:`common.yaw.stages.prealigned_pair`). That pass once measured every patch: on the
16x12 grid of a 1080p frame it doubled a turning frame's cost, and on the distributed path the master paid it
alone, with no previous spectra cached (its members hold them). ``refine_max_patches`` was chosen here.

Truth generator: nadir views of the simulator's ground texture, each pair turned by a known angle (0.5-2
deg, both signs) at ``--resolution``. For each cap (``--caps``; 4096 = every patch, the baseline), in turns
within each repeat: CPU ms of the in-process frame (``YawTracker.track``: both passes) and of the master's
conclude (``YawTracker.conclude`` without previous spectra: the refinement alone, as the master runs it
below ``refine_on_members_pixels``; a larger pass goes to the members, ``services/master/refine.py``),
and the pair's yaw error. The table gives each cap's median over the repeats, the p95 over every timed
call, its time over the baseline's in the same repeats, and the RMS yaw error over the pairs.

``--suite warp`` chose how the refinement turns frame k back (``common.yaw.stages.REFINE_INTERPOLATION``):
pure turns of 0.05-3 deg (both ways, no translation, sensor noise 2 DN) over the carpet and the checkerboard
at 320x240 (90 deg, 1 m), every turn refined (``refine_min_deg`` 0), for each interpolation (bilinear, the
baseline; bicubic; Lanczos): the mean error of each turn over ``--pairs`` places (a bias does not average
out), their largest and RMS, and the CPU ms of one level warp (160x120) against bilinear's, in turns.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from typing import Any
from unittest import mock

import cv2
import numpy as np

from common.camera import CameraModel
from common.sim.field import checkerboard_texture
from common.sim.ground import GroundTexture, make_ground_texture, nadir_camera_pose, render_ground_view
from common.types import U8Array
from common.yaw import YawSettings, YawTracker, stages
from common.yaw.correlation import measure_patches, patch_spectra
from common.yaw.global_align import warp_into
from common.yaw.grid import make_patch_grid
from common.yaw.stages import EstimateMethod, rotation_about
from services.runtime.cli import number_in, parse_size

NAME = "refine"
BASELINE_CAP = 4096
ALTITUDE_M = 1.5
HFOV_DEG = 70.0


#: the interpolations ``--suite warp`` compares, the baseline first
INTERPOLATIONS = {"bilinear": cv2.INTER_LINEAR, "bicubic": cv2.INTER_CUBIC, "lanczos": cv2.INTER_LANCZOS4}
#: the pure turns of ``--suite warp`` (deg)
WARP_TURNS_DEG = (0.05, 0.1, 0.2, 0.3, 0.4, 0.6, 0.8, 1.6, 3.0, -0.1, -0.3, -0.8)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--suite", choices=("caps", "warp"), default="caps",
        help="caps: refine_max_patches' cost (default); warp: the refinement's interpolation",
    )  # fmt: skip
    parser.add_argument("--resolution", default="1920x1080", help="frame WIDTHxHEIGHT")
    parser.add_argument("--grid", default="16x12", help="patch grid COLSxROWS")
    parser.add_argument("--patch-size", type=number_in(int, 8, 512), default=128, help="patch side (px)")
    parser.add_argument("--pyramid-level", type=number_in(int, 0, 4), default=0, help="pyramid level")
    parser.add_argument(
        "--caps", type=number_in(int, 8, BASELINE_CAP), nargs="+", default=[BASELINE_CAP, 48],
        help=f"refine_max_patches to compare ({BASELINE_CAP}: every patch, the baseline)",
    )  # fmt: skip
    parser.add_argument("--pairs", type=number_in(int, 1, 100), default=6, help="turned pairs")
    parser.add_argument("--repeats", type=number_in(int, 1, 100), default=5, help="turns of the caps")


def turned_pairs(camera: CameraModel, pairs: int) -> list[tuple[U8Array, U8Array, float]]:
    """``pairs`` nadir view pairs (a, b, turn in rad) over the ground texture, b turned 0.5-2 deg, both
    ways."""
    texture = make_ground_texture(seed=0)
    out = []
    for i, turn_deg in enumerate(np.linspace(0.5, 2.0, pairs) * np.where(np.arange(pairs) % 2, -1.0, 1.0)):
        x, y, yaw = 0.3 * i, -0.2 * i, math.radians(20.0 + 37.0 * i)
        turned = yaw + math.radians(turn_deg)
        a = render_ground_view(texture, camera, *nadir_camera_pose(x, y, ALTITUDE_M, yaw))
        b = render_ground_view(texture, camera, *nadir_camera_pose(x, y, ALTITUDE_M, turned))
        out.append((a, b, math.radians(float(turn_deg))))
    return out


def _one_pair(settings: YawSettings, a: U8Array, b: U8Array) -> tuple[float, float, float, bool]:
    """(in-process ms, master's conclude ms, estimated delta rad, refined?) of one pair."""
    tracker = YawTracker(settings, make_patch_grid(a.shape, settings))
    state = tracker.initial_state(a)
    start = time.process_time()
    _, estimate = tracker.track(state, b)
    in_process_ms = (time.process_time() - start) * 1e3
    previous = state.previous_spectra
    assert previous is not None  # initial_state caches frame a's spectra
    measurement = measure_patches(previous, patch_spectra(b, tracker.grid, None, settings), settings)
    bare = replace(state, previous_spectra=None)  # the master's: its members hold the spectra
    start = time.process_time()
    tracker.conclude(bare, b, measurement, None, None)
    conclude_ms = (time.process_time() - start) * 1e3
    return in_process_ms, conclude_ms, estimate.delta_yaw_rad, estimate.method is EstimateMethod.REFINED


def _turn_error_deg(
    tracker: YawTracker, texture: GroundTexture, turn_deg: float, rng: np.random.Generator
) -> float:
    """The refined estimate's error (deg) of one pure turn at a random place, with 2 DN sensor noise."""
    x, y, yaw = rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0), rng.uniform(-math.pi, math.pi)
    camera = tracker.settings.camera
    assert camera is not None
    views = []
    for turn in (0.0, math.radians(turn_deg)):
        view = render_ground_view(texture, camera, *nadir_camera_pose(x, y, 1.0, yaw + turn))
        views.append(np.clip(view + rng.normal(0.0, 2.0, view.shape), 0, 255).astype(np.uint8))
    _, estimate = tracker.track(tracker.initial_state(views[0]), views[1])
    return math.degrees(estimate.delta_yaw_rad) - turn_deg


def _warp_turn_errors(interpolation: int, places: int) -> dict[str, list[float]]:
    """Per floor, the refined turn's mean error (deg) over ``places`` places for each of
    :data:`WARP_TURNS_DEG`, the refinement warping with ``interpolation``."""
    settings = YawSettings(camera=CameraModel.from_hfov(320, 240, 90.0), refine_min_deg=0.0)
    tracker = YawTracker(settings, make_patch_grid((240, 320), settings))
    floors = {"carpet": make_ground_texture(seed=0), "checkerboard": checkerboard_texture(seed=0)}
    out: dict[str, list[float]] = {}
    with mock.patch.object(stages, "REFINE_INTERPOLATION", interpolation):
        for floor, texture in floors.items():
            rng = np.random.default_rng(7)  # the same places and noise for every interpolation
            out[floor] = [
                float(np.mean([_turn_error_deg(tracker, texture, turn, rng) for _ in range(places)]))
                for turn in WARP_TURNS_DEG
            ]
    return out


def run_warp(args: argparse.Namespace) -> dict[str, Any]:
    """``--suite warp``: the refinement's interpolation (see the module docstring)."""
    level = render_ground_view(make_ground_texture(seed=1), CameraModel.from_hfov(160, 120, 90.0),
                               *nadir_camera_pose(0.0, 0.0, 1.0))  # fmt: skip
    turn = rotation_about((79.5, 59.5), math.radians(0.4))
    timed: dict[str, list[float]] = {name: [] for name in INTERPOLATIONS}
    for _ in range(args.repeats):
        for name, flag in INTERPOLATIONS.items():
            for _ in range(20):
                start = time.process_time()
                warp_into(level, turn, level.shape, flag)
                timed[name].append((time.process_time() - start) * 1e3)
    errors = {name: _warp_turn_errors(flag, args.pairs) for name, flag in INTERPOLATIONS.items()}
    base_ms = float(np.median(timed["bilinear"]))
    table = []
    for name in INTERPOLATIONS:
        for floor, means in errors[name].items():
            ms = float(np.median(timed[name]))
            table.append({
                "interpolation": name, "floor": floor, "turns": len(means),
                "max_bias_deg": float(np.max(np.abs(means))),
                "rms_bias_deg": float(np.sqrt(np.mean(np.square(means)))),
                "warp_ms": ms, "warp_ms_p95": float(np.percentile(timed[name], 95)),
                "warp_vs_bilinear": ms / base_ms,
            })  # fmt: skip
    return {
        "json_name": "refine_warp",
        "table": table,
        "json": {"turns_deg": list(WARP_TURNS_DEG), "places": args.pairs, "mean_errors_deg": errors,
                 "timed_ms": timed, "repeats": args.repeats},
    }  # fmt: skip


def run(args: argparse.Namespace) -> dict[str, Any]:
    cv2.setNumThreads(1)
    if args.suite == "warp":
        return run_warp(args)
    width, height = parse_size(args.resolution, "--resolution", "1920x1080")
    cols, rows = parse_size(args.grid, "--grid", "16x12")
    camera = CameraModel.from_hfov(width, height, HFOV_DEG)
    pairs = turned_pairs(camera, args.pairs)
    base = YawSettings(
        grid_cols=cols, grid_rows=rows, patch_size_px=args.patch_size, pyramid_level=args.pyramid_level
    )
    caps = list(dict.fromkeys([BASELINE_CAP, *args.caps]))
    timed: dict[int, dict[str, list[list[float]]]] = {c: {"in_process": [], "conclude": []} for c in caps}
    errors: dict[int, list[float]] = {c: [] for c in caps}
    refined: dict[int, int] = dict.fromkeys(caps, 0)
    for repeat in range(args.repeats):
        for cap in caps:
            settings = replace(base, refine_max_patches=cap)
            runs = [_one_pair(settings, a, b) for a, b, _ in pairs]
            timed[cap]["in_process"].append([r[0] for r in runs])
            timed[cap]["conclude"].append([r[1] for r in runs])
            if repeat == 0:
                errors[cap] = [math.degrees(r[2] - turn) for r, (_, _, turn) in zip(runs, pairs, strict=True)]
                refined[cap] = sum(r[3] for r in runs)
    medians = {c: {k: float(np.median([np.median(r) for r in v])) for k, v in timed[c].items()} for c in caps}
    table = []
    for cap in caps:
        row: dict[str, Any] = {"refine_max_patches": cap, "pairs": len(pairs), "refined": refined[cap]}
        for kind in ("in_process", "conclude"):
            row[f"{kind}_ms"] = medians[cap][kind]
            row[f"{kind}_ms_p95"] = float(np.percentile(np.concatenate(timed[cap][kind]), 95))
            row[f"{kind}_vs_all"] = medians[cap][kind] / medians[BASELINE_CAP][kind]
        row["yaw_error_rms_deg"] = float(np.sqrt(np.mean(np.square(errors[cap]))))
        row["yaw_error_max_deg"] = float(np.max(np.abs(errors[cap])))
        table.append(row)
    return {
        "table": table,
        "json": {
            "resolution": [width, height], "grid": [cols, rows], "patch_size_px": args.patch_size,
            "pyramid_level": args.pyramid_level, "repeats": args.repeats, "timed_ms": timed,
            "yaw_errors_deg": errors,
        },
    }  # fmt: skip
