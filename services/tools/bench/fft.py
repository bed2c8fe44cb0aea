"""FFT: the patch transforms of the yaw core by patch size: numpy in one batch and in runs, scipy, OpenCV.

The run length of the core's transforms (:data:`~common.yaw.correlation.FFT_RUN_PIXELS`) and the default
backend (scipy) were chosen here. For each patch size a frame's worth of random windowed patches is
transformed forward (real to half spectra) and back, one thread: ``batch`` is one call of numpy's transforms
over all patches (the baseline), ``runs`` the same calls over the core's runs
(:func:`~common.yaw.correlation.run_slices`, :func:`~common.yaw.correlation.fft_run` patches each),
``scipy`` scipy's single-precision transforms over the same runs (the core's default), ``opencv`` a loop of
``cv2.dft`` (full spectra). The variants take turns within each repeat (the shared host's load hits them
alike); the table gives each one's median microseconds a patch over the repeats, the p95 over every timed
call, and its time over ``batch``'s in the same repeats. ``runs`` and ``batch`` must give the same bits
(checked: ``bit_identical``); ``max_relative_difference`` is how far scipy's are from numpy's.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from common.yaw.correlation import fft_run, forward_transform, inverse_transform, run_slices
from common.yaw.settings import FftBackend
from services.runtime.cli import number_in

NAME = "fft"
VARIANTS = ("batch", "runs", "scipy", "opencv")
DIRECTIONS = ("forward", "inverse")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--sizes", type=number_in(int, 8, 512), nargs="+", default=[32, 64, 128, 256], help="patch sides (px)"
    )
    parser.add_argument(
        "--patches", type=number_in(int, 1, 4096), default=192, help="patches of a frame (each size)"
    )
    parser.add_argument("--repeats", type=number_in(int, 1, 200), default=15, help="turns of the variants")
    parser.add_argument("--calls", type=number_in(int, 1, 100), default=5, help="timed calls a turn")


def _in_runs(
    size: int, patches: np.ndarray, backend: FftBackend
) -> tuple[Callable[[], Any], Callable[[], Any]]:
    """(forward, inverse) of ``backend`` over ``patches`` in the core's runs (:func:`run_slices`)."""
    half = forward_transform(patches, backend)

    def forward() -> Any:
        out = np.empty(half.shape, dtype=np.complex64)
        for part in run_slices(len(patches), size):
            out[part] = forward_transform(patches[part], backend)
        return out

    def inverse() -> Any:
        out = np.empty(patches.shape, dtype=np.float32)
        for part in run_slices(len(patches), size):
            out[part] = inverse_transform(half[part], size, backend)
        return out

    return forward, inverse


def _transforms(size: int, patches: np.ndarray) -> dict[str, tuple[Callable[[], Any], Callable[[], Any]]]:
    """Each variant's (forward, inverse) over ``patches`` (n, size, size) float32."""
    half = forward_transform(patches, FftBackend.NUMPY)
    full = forward_transform(patches, FftBackend.OPENCV)
    return {
        "batch": (
            lambda: forward_transform(patches, FftBackend.NUMPY),
            lambda: inverse_transform(half, size, FftBackend.NUMPY),
        ),
        "runs": _in_runs(size, patches, FftBackend.NUMPY),
        "scipy": _in_runs(size, patches, FftBackend.SCIPY),
        "opencv": (
            lambda: forward_transform(patches, FftBackend.OPENCV),
            lambda: inverse_transform(full, size, FftBackend.OPENCV),
        ),
    }


def _relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference of ``a`` from ``b`` over ``b``'s largest magnitude."""
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _timed_us(func: Callable[[], Any], calls: int, per: int) -> list[float]:
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        func()
        times.append((time.perf_counter() - start) * 1e6 / per)
    return times


def run(args: argparse.Namespace) -> dict[str, Any]:
    cv2.setNumThreads(1)
    rng = np.random.default_rng(0)
    table: list[dict[str, Any]] = []
    raw: dict[str, Any] = {}
    for size in args.sizes:
        patches = rng.normal(0.0, 30.0, (args.patches, size, size)).astype(np.float32)
        variants = _transforms(size, patches)
        same = bool(
            np.array_equal(variants["runs"][0](), variants["batch"][0]())
            and np.array_equal(variants["runs"][1](), variants["batch"][1]())
        )
        # scipy transforms in single precision: how far its bits are from numpy's (double inside)
        scipy_difference = max(
            _relative_difference(variants["scipy"][d](), variants["batch"][d]()) for d in range(2)
        )
        times: dict[str, dict[str, list[list[float]]]] = {v: {"forward": [], "inverse": []} for v in VARIANTS}
        for forward, inverse in variants.values():  # warm: plans, pages
            forward()
            inverse()
        for _ in range(args.repeats):
            for name, (forward, inverse) in variants.items():
                times[name]["forward"].append(_timed_us(forward, args.calls, args.patches))
                times[name]["inverse"].append(_timed_us(inverse, args.calls, args.patches))
        raw[str(size)] = times
        base = {d: float(np.median([np.median(r) for r in times["batch"][d]])) for d in DIRECTIONS}
        for name in VARIANTS:
            row: dict[str, Any] = {"patch_px": size, "patches": args.patches, "variant": name,
                                   "run": fft_run(size) if name in ("runs", "scipy") else None}  # fmt: skip
            for d in DIRECTIONS:
                medians = [float(np.median(r)) for r in times[name][d]]
                row[f"{d}_us"] = float(np.median(medians))
                row[f"{d}_us_p95"] = float(np.percentile(np.concatenate(times[name][d]), 95))
                row[f"{d}_vs_batch"] = row[f"{d}_us"] / base[d]
            row["bit_identical"] = same if name == "runs" else None
            row["max_relative_difference"] = scipy_difference if name == "scipy" else None
            table.append(row)
    return {
        "table": table,
        "json": {"patches": args.patches, "repeats": args.repeats, "calls": args.calls, "runs_us": raw},
    }
