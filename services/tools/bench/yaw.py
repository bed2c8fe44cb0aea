"""Yaw core vs the paper's cv2.phaseCorrelate per patch pair: ms/frame on one core and accuracy, same frames.

Both run single-threaded: ``cv2.setNumThreads(1)``; numpy's FFT never spawns threads, scipy's is called with
``workers=1``. The
frames of the simulated hover are rendered once beforehand; only the per-frame yaw work is timed, with all
methods taking turns on blocks of 32 frames so that they share the (shared, noisy) machine's load alike. The
baseline runs on the core's grid (same 8x5 patch centres, 64 px full-resolution patches, which the core
covers with 32 px patches at pyramid level 1) and on candidate grids of its own, the most accurate of
which is reported too. The core runs with each FFT backend (its default first), and a micro-benchmark of
the patch transforms (scipy's and numpy's batched rfft2, a loop of cv2.dft) shows which is faster; the
core's default is the measured winner.
"""

from __future__ import annotations

import argparse
import functools
import logging
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import CapatazError
from common.metrics import yaw_error_stats
from common.sim.flight import hover_flight
from common.yaw import FftBackend, YawSettings, YawTracker, for_frame, make_patch_grid
from common.yaw.correlation import forward_transform, inverse_transform, windowed_patches
from common.yaw.reference import reference_pair, reference_settings
from services.tools.bench.yaw_field import add_field_arguments, run_field

logger = logging.getLogger(__name__)

NAME = "yaw"

#: Baseline grids tried besides the core's: (patch px, columns, rows) at full resolution.
BASELINE_GRIDS: tuple[tuple[int, int, int], ...] = ((64, 8, 5), (96, 7, 4), (128, 5, 3), (128, 6, 4))

U8Frames = list[npt.NDArray[np.uint8]]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--suite", choices=["hover", "field"], default="hover", help="which suite runs")
    parser.add_argument("--seed", type=int, default=0, help="hover flight seed")
    hover = parser.add_argument_group("hover suite", "the paper's flight (out/bench/yaw.json)")
    hover.add_argument("--frames", type=int, default=2041, help="hover frames (default: all 2041)")
    hover.add_argument("--quick", action="store_true", help="only the baseline on the core's grid")
    hover.add_argument(
        "--drop-step", type=int, default=4, help="also run on every N-th frame (dropped frames); 0 = skip"
    )
    add_field_arguments(parser)


def _median_us(func: Callable[[], object], repeats: int = 300) -> float:
    func()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e6)


def fft_microbench(frame: npt.NDArray[np.uint8], settings: YawSettings) -> dict[str, float]:
    """Median microseconds of the forward and inverse patch transforms of one frame, per backend."""
    grid = make_patch_grid(frame.shape, settings)
    patches, _ = windowed_patches(grid.crop(frame, grid.all_indices), settings)
    result: dict[str, float] = {
        "patches": float(grid.n_patches),
        "patch_size_px": float(settings.patch_size_px),
    }
    size = settings.patch_size_px
    for backend in FftBackend:
        spectra = forward_transform(patches, backend)

        def forward(b: FftBackend = backend) -> object:
            return forward_transform(patches, b)

        def inverse(b: FftBackend = backend, s: Any = spectra) -> object:
            return inverse_transform(s, size, b)

        result[f"{backend.value}_forward_us"] = _median_us(forward)
        result[f"{backend.value}_inverse_us"] = _median_us(inverse)
    return result


class _CoreRunner:
    """The core as a per-frame step (``YawTracker.track``) with its own explicit state."""

    def __init__(self, first: npt.NDArray[np.uint8], settings: YawSettings) -> None:
        self.tracker = YawTracker(settings, make_patch_grid(first.shape, settings))
        self.state = self.tracker.initial_state(first)

    def step(self, frame: npt.NDArray[np.uint8]) -> float:
        self.state, estimate = self.tracker.track(self.state, frame)
        return estimate.delta_yaw_rad


class _BaselineRunner:
    """The paper's method as a per-frame step: cv2.phaseCorrelate of every patch pair (both spectra)."""

    def __init__(self, first: npt.NDArray[np.uint8], settings: YawSettings) -> None:
        self.settings = settings
        self.grid = make_patch_grid(first.shape, settings)
        self.previous = first

    def step(self, frame: npt.NDArray[np.uint8]) -> float:
        delta = reference_pair(self.previous, frame, self.grid, self.settings).delta_yaw_rad
        self.previous = frame
        return delta


Runner = _CoreRunner | _BaselineRunner


#: Frames each method runs in a row before the next method takes its turn (see ``_interleaved``).
BLOCK_FRAMES = 32


def _interleaved(
    frames: U8Frames, makers: list[Callable[[npt.NDArray[np.uint8]], Runner]], block: int = BLOCK_FRAMES
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Methods take turns on blocks of ``block`` frames, so all see the same (shared, noisy) machine load
    within a fraction of a second, while each keeps its caches warm inside a block as it would alone.

    Returns the integrated yaw (methods, N) and the ms per step (methods, N - 1).
    """
    runners = [make(frames[0]) for make in makers]
    yaw = np.zeros((len(runners), len(frames)))
    ms = np.zeros((len(runners), len(frames) - 1))
    for first in range(1, len(frames), block):
        for m, runner in enumerate(runners):
            for k in range(first, min(first + block, len(frames))):
                start = time.perf_counter()
                delta = runner.step(frames[k])
                ms[m, k - 1] = (time.perf_counter() - start) * 1e3
                yaw[m, k] = yaw[m, k - 1] + delta
    return yaw, ms


def _row(
    method: str, grid: str, ms: list[float] | npt.NDArray[np.float64], yaw: Any, truth: Any
) -> dict[str, Any]:
    stats = yaw_error_stats(np.asarray(yaw) + truth[0], truth)
    return {
        "method": method,
        "grid": grid,
        "ms_median": float(np.median(ms)),
        "speedup": 1.0,
        "max_ame_deg": stats.max_ame_deg,
        "final_err_deg": stats.final_deg,
        "rms_deg": stats.rms_deg,
        "max_abs_deg": stats.max_abs_deg,
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.suite == "field":
        if args.field_frames < 102 or args.hover_frames < 102:
            raise CapatazError("--field-frames and --hover-frames must be >= 102 (max AME needs N = 100)")
        return run_field(args)
    cv2.setNumThreads(1)
    flight = hover_flight(seed=args.seed, n_frames=max(int(args.frames), 2))
    logger.info("rendering %d hover frames", flight.n_frames)
    frames: U8Frames = list(flight.frames())
    truth = flight.yaw_rad
    settings = YawSettings()
    layout = f"{settings.grid_cols}x{settings.grid_rows}"
    level = for_frame(settings, frames[0].shape).pyramid_level
    core_grid = f"{layout} x {settings.patch_size_px}px @ level {level}"
    rows: list[dict[str, Any]] = []

    others = [b for b in FftBackend if b is not settings.fft_backend]
    grids = BASELINE_GRIDS[:1] if args.quick else BASELINE_GRIDS
    labels = [f"core ({b.value} fft)" for b in [settings.fft_backend, *others]]
    makers: list[Callable[[npt.NDArray[np.uint8]], Runner]] = [
        functools.partial(_CoreRunner, settings=replace(settings, fft_backend=b))
        for b in [settings.fft_backend, *others]
    ]
    grid_labels = [core_grid] * len(makers)
    for patch_px, cols, rows_n in grids:
        labels.append("baseline cv2.phaseCorrelate")
        grid_labels.append(f"{cols}x{rows_n} x {patch_px}px @ level 0")
        makers.append(functools.partial(_BaselineRunner, settings=reference_settings(patch_px, cols, rows_n)))
    logger.info("core and baseline, in turns of %d frames: %s", BLOCK_FRAMES, ", ".join(grid_labels))
    yaw, ms = _interleaved(frames, makers)
    for m in range(len(makers)):
        rows.append(_row(labels[m], grid_labels[m], ms[m], yaw[m], truth))
    core_index, baseline_index = 0, 1 + len(others)
    rows[baseline_index]["method"] = "baseline on the core's grid"
    on_core_grid = rows[baseline_index]
    best = min(rows[baseline_index:], key=lambda r: r["max_ame_deg"])
    for row in rows:
        row["speedup"] = on_core_grid["ms_median"] / row["ms_median"]
    per_frame_ratio = float(np.median(ms[baseline_index] / ms[core_index]))

    step = int(args.drop_step)
    if step > 1:
        kept = frames[::step]
        kept_truth = truth[::step]
        logger.info("dropped frames: every %d-th frame (%d frames)", step, len(kept))
        yaw_d, ms_d = _interleaved(
            kept,
            [lambda f: _CoreRunner(f, settings), lambda f: _BaselineRunner(f, reference_settings(*grids[0]))],
        )
        rows.append(
            _row("core, dropped frames", f"{core_grid}, every {step}th frame", ms_d[0], yaw_d[0], kept_truth)
        )
        rows.append(
            _row(
                "baseline, dropped frames",
                f"{grid_labels[baseline_index]}, every {step}th frame",
                ms_d[1],
                yaw_d[1],
                kept_truth,
            )
        )
        for row in rows[-2:]:
            row["speedup"] = float("nan")

    core_row = rows[0]
    micro = fft_microbench(frames[0], settings)
    result: dict[str, Any] = {
        "frames": flight.n_frames,
        "threads": "1 (cv2.setNumThreads(1); numpy.fft single-threaded; scipy.fft workers=1)",
        "core_settings": core_grid,
        "core_ms_median": core_row["ms_median"],
        "baseline_ms_median": on_core_grid["ms_median"],
        "speedup": on_core_grid["ms_median"] / core_row["ms_median"],
        "speedup_per_frame_median": per_frame_ratio,
        "core_max_ame_deg": core_row["max_ame_deg"],
        "baseline_max_ame_deg": on_core_grid["max_ame_deg"],
        "core_final_yaw_error_deg": core_row["final_err_deg"],
        "baseline_final_yaw_error_deg": on_core_grid["final_err_deg"],
        "baseline_best_grid": best["grid"],
        "baseline_best_ms_median": best["ms_median"],
        "baseline_best_max_ame_deg": best["max_ame_deg"],
        "speedup_vs_best_baseline": best["ms_median"] / core_row["ms_median"],
        "fft_microbench_us": micro,
        "dropped_frames_step": step if step > 1 else None,
        "core_dropped_max_ame_deg": next(
            (r["max_ame_deg"] for r in rows if r["method"] == "core, dropped frames"), None
        ),
        "baseline_dropped_max_ame_deg": next(
            (r["max_ame_deg"] for r in rows if r["method"] == "baseline, dropped frames"), None
        ),
        "table": rows,
    }
    print(
        "patch transforms, median us per frame "
        + ", ".join(f"{k}={v:.0f}" for k, v in micro.items() if k.endswith("_us"))
    )
    return result
