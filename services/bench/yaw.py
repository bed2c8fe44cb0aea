"""Yaw core vs the paper's cv2.phaseCorrelate per patch pair: ms/frame on one core and accuracy, same frames.

Both run single-threaded: ``cv2.setNumThreads(1)``; numpy's FFT (pocketfft) never spawns threads. The
frames of the simulated hover are rendered once beforehand; only the per-frame yaw work is timed. The
baseline runs on the core's grid (same 8x5 patch centres, 64 px full-resolution patches, which the core
covers with 32 px patches at pyramid level 1) and on candidate grids of its own, the most accurate of
which is reported too. A micro-benchmark of the patch transforms (numpy batched rfft2 vs a loop of
cv2.dft) shows which FFT backend is faster; the core's default is the measured winner.
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from common.metrics import yaw_error_stats
from common.sim.flight import hover_flight
from common.yaw import FftBackend, YawSettings, make_patch_grid
from common.yaw.correlation import forward_transform, inverse_transform, windowed_patches
from common.yaw.reference import reference_pair, reference_settings
from services.demo_yaw import track_frames

logger = logging.getLogger(__name__)

NAME = "yaw"

#: Baseline grids tried besides the core's: (patch px, columns, rows) at full resolution.
BASELINE_GRIDS: tuple[tuple[int, int, int], ...] = ((64, 8, 5), (96, 7, 4), (128, 5, 3), (128, 6, 4))

U8Frames = list[npt.NDArray[np.uint8]]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=2041, help="hover frames (default: all 2041)")
    parser.add_argument("--seed", type=int, default=0, help="hover flight seed")
    parser.add_argument("--quick", action="store_true", help="only the baseline on the core's grid")
    parser.add_argument(
        "--drop-step", type=int, default=4, help="also run on every N-th frame (dropped frames); 0 = skip"
    )


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


def _run_baseline(frames: U8Frames, settings: YawSettings) -> tuple[npt.NDArray[np.float64], list[float]]:
    grid = make_patch_grid(frames[0].shape, settings)
    yaw = np.zeros(len(frames))
    ms: list[float] = []
    for k in range(1, len(frames)):
        start = time.perf_counter()
        delta = reference_pair(frames[k - 1], frames[k], grid, settings).delta_yaw_rad
        ms.append((time.perf_counter() - start) * 1e3)
        yaw[k] = yaw[k - 1] + delta
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
    cv2.setNumThreads(1)
    flight = hover_flight(seed=args.seed, n_frames=max(int(args.frames), 2))
    logger.info("rendering %d hover frames", flight.n_frames)
    frames: U8Frames = list(flight.frames())
    truth = flight.yaw_rad
    settings = YawSettings()
    layout = f"{settings.grid_cols}x{settings.grid_rows}"
    core_grid = f"{layout} x {settings.patch_size_px}px @ level {settings.pyramid_level}"
    rows: list[dict[str, Any]] = []

    logger.info("core (%s, %s FFT)", core_grid, settings.fft_backend.value)
    core = track_frames(frames, settings)
    rows.append(
        _row(f"core ({settings.fft_backend.value} fft)", core_grid, core.ms_per_frame, core.yaw_rad, truth)
    )
    other_backend = next(b for b in FftBackend if b is not settings.fft_backend)
    other = track_frames(frames, replace(settings, fft_backend=other_backend))
    rows.append(
        _row(f"core ({other_backend.value} fft)", core_grid, other.ms_per_frame, other.yaw_rad, truth)
    )

    grids = BASELINE_GRIDS[:1] if args.quick else BASELINE_GRIDS
    baseline_rows = []
    for patch_px, cols, rows_n in grids:
        label = f"{cols}x{rows_n} x {patch_px}px @ level 0"
        logger.info("baseline cv2.phaseCorrelate (%s)", label)
        yaw, ms = _run_baseline(frames, reference_settings(patch_px, cols, rows_n))
        baseline_rows.append(_row("baseline cv2.phaseCorrelate", label, ms, yaw, truth))
    on_core_grid = baseline_rows[0]
    on_core_grid["method"] = "baseline on the core's grid"
    best = min(baseline_rows, key=lambda r: r["max_ame_deg"])
    rows.extend(baseline_rows)
    for row in rows:
        row["speedup"] = on_core_grid["ms_median"] / row["ms_median"]

    step = int(args.drop_step)
    if step > 1:
        kept = frames[::step]
        kept_truth = truth[::step]
        logger.info("dropped frames: every %d-th frame (%d frames)", step, len(kept))
        dropped = track_frames(kept, settings)
        grid_label = f"{core_grid}, every {step}th frame"
        rows.append(
            _row("core, dropped frames", grid_label, dropped.ms_per_frame, dropped.yaw_rad, kept_truth)
        )
        rows[-1]["speedup"] = float("nan")
        yaw, ms = _run_baseline(kept, reference_settings(*BASELINE_GRIDS[0]))
        rows.append(_row("baseline, dropped frames", grid_label, ms, yaw, kept_truth))
        rows[-1]["speedup"] = float("nan")

    core_row = rows[0]
    micro = fft_microbench(frames[0], settings)
    result: dict[str, Any] = {
        "frames": flight.n_frames,
        "threads": "1 (cv2.setNumThreads(1); numpy.fft is single-threaded)",
        "core_settings": core_grid,
        "core_ms_median": core_row["ms_median"],
        "baseline_ms_median": on_core_grid["ms_median"],
        "speedup": on_core_grid["ms_median"] / core_row["ms_median"],
        "core_max_ame_deg": core_row["max_ame_deg"],
        "baseline_max_ame_deg": on_core_grid["max_ame_deg"],
        "core_final_yaw_error_deg": core_row["final_err_deg"],
        "baseline_final_yaw_error_deg": on_core_grid["final_err_deg"],
        "baseline_best_grid": best["grid"],
        "baseline_best_ms_median": best["ms_median"],
        "baseline_best_max_ame_deg": best["max_ame_deg"],
        "speedup_vs_best_baseline": best["ms_median"] / core_row["ms_median"],
        "core_low_confidence_frames": int(np.count_nonzero(core.low_confidence)),
        "core_methods": core.methods,
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
