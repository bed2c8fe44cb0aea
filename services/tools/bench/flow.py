"""Flow: how far the VO's tracker (and the yaw core) read a known sub-pixel shift (the VO's heading bias).

Paper C's flight gains its heading error where it starts and stops turning, when the ground moves 0.05-0.2 px
between frames (``docs/methods.md``). This bench measures the tracker alone on pairs whose shift is known,
with the VO's own :func:`common.estimation.vo.track_features` and settings (``--presmooth``: its
``presmooth_sigma_px``), and with the yaw core's phase correlation (its default settings; the mean shift
of its valid patches), on the same pairs. Two truth generators, each pair shifted by ``s`` px along a
direction that turns with the pair:

- ``band_limited``: a 1/f random texture shifted in the Fourier domain (an exact band-limited shift), then
  quantised to 8 bits as a camera does.
- ``rendered``: the simulator's nadir views (``render_ground_view``, the simulated flights' default camera
  and ground at paper C's 3.8 m), the camera moved by ``s`` pixels' worth of ground; noise-free, so the
  shift is all that differs.

Per tracker, generator and shift: the mean tracked displacement along the true shift over the true shift
(``ratio``; 1 is unbiased), its spread over the pairs, and the mean displacement across it. A ratio above 1
over-reads the motion: a slow turn then turns more in the VO than in truth.
"""

from __future__ import annotations

import argparse
import functools
import math
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from common.camera import CameraModel
from common.estimation.vo import VoSettings, prepare_frame, track_features
from common.sim.ground import GroundTexture, make_ground_texture, nadir_camera_pose, render_ground_view
from common.types import FloatArray, U8Array
from common.yaw import YawSettings, for_frame
from common.yaw.correlation import measure_patches, patch_spectra
from common.yaw.grid import make_patch_grid
from services.runtime.cli import number_in

NAME = "flow"
GENERATORS = ("band_limited", "rendered")
TRACKERS = ("vo", "yaw")
SIZE_PX = 384
SHIFTS_PX = (0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 1.0)
ALTITUDE_M = 3.8


def band_limited_pair(seed: int, shift_px: FloatArray, size_px: int = SIZE_PX) -> tuple[U8Array, U8Array]:
    """A 1/f texture and the same texture shifted by ``shift_px`` (x, y) in the Fourier domain, both 8-bit."""
    rng = np.random.default_rng(seed)
    k = np.fft.fftfreq(size_px)
    kx, ky = np.meshgrid(k, k)
    spectrum = np.fft.fft2(rng.normal(size=(size_px, size_px))) / np.maximum(np.hypot(kx, ky), 1.0 / size_px)
    a = np.real(np.fft.ifft2(spectrum))
    b = np.real(np.fft.ifft2(spectrum * np.exp(-2j * np.pi * (kx * shift_px[0] + ky * shift_px[1]))))
    lo, hi = float(a.min()), float(a.max())

    def to_u8(image: FloatArray) -> U8Array:
        return np.clip(np.round(40.0 + 175.0 * (image - lo) / (hi - lo)), 0, 255).astype(np.uint8)

    return to_u8(a), to_u8(b)


@functools.lru_cache(maxsize=1)
def _ground() -> GroundTexture:
    """The simulated flights' default ground (made once: 0.3-1 s a texture)."""
    return make_ground_texture(seed=0)


def rendered_pair(seed: int, shift_px: FloatArray) -> tuple[U8Array, U8Array]:
    """Two noise-free nadir views of paper C's ground, the second's camera moved so that the ground moves
    by ``shift_px`` (x right, y down) in the image."""
    camera, texture = CameraModel.default(), _ground()
    rng = np.random.default_rng(seed)
    x_m, y_m = rng.uniform(-3.0, 3.0, size=2)
    metres_per_px = ALTITUDE_M / camera.fx
    # a nadir camera at yaw 0 (R_BODY_CAMERA_DOWN): image x is world -y, image y is world -x; the ground
    # moves opposite to the camera
    a = render_ground_view(texture, camera, *nadir_camera_pose(x_m, y_m, ALTITUDE_M))
    dx_m, dy_m = shift_px[1] * metres_per_px, shift_px[0] * metres_per_px
    b = render_ground_view(texture, camera, *nadir_camera_pose(x_m + dx_m, y_m + dy_m, ALTITUDE_M))
    return a, b


def _along_across(mean_px: FloatArray, shift_px: FloatArray) -> tuple[float, float]:
    along_unit = shift_px / np.linalg.norm(shift_px)
    return float(mean_px @ along_unit), float(mean_px @ np.array([-along_unit[1], along_unit[0]]))


def measure(a: U8Array, b: U8Array, shift_px: FloatArray, settings: VoSettings) -> tuple[float, float]:
    """Mean tracked displacement (px) along and across the true shift, by the VO's tracker."""
    p0, p1 = track_features(prepare_frame(a, None, settings), prepare_frame(b, None, settings), settings)
    if len(p0) == 0:
        return math.nan, math.nan
    return _along_across(np.mean(p1 - p0, axis=0), shift_px)


def measure_yaw_core(
    a: U8Array, b: U8Array, shift_px: FloatArray, settings: YawSettings
) -> tuple[float, float]:
    """Mean patch shift (full-resolution px) along and across the true shift, by the yaw core's phase
    correlation (its valid patches)."""
    settings = for_frame(settings, a.shape)
    grid = make_patch_grid(a.shape, settings)
    m = measure_patches(
        patch_spectra(a, grid, None, settings), patch_spectra(b, grid, None, settings), settings
    )
    if not np.any(m.valid):
        return math.nan, math.nan
    return _along_across(np.mean(m.shift_px[m.valid], axis=0), shift_px)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--shifts", type=number_in(float, 0.005, 4.0), nargs="+", default=list(SHIFTS_PX),
        help="true shifts (px)",
    )  # fmt: skip
    parser.add_argument("--pairs", type=number_in(int, 1, 100), default=6, help="pairs per shift")
    parser.add_argument("--generators", nargs="+", choices=GENERATORS, default=list(GENERATORS), help="(all)")
    parser.add_argument(
        "--trackers", nargs="+", choices=TRACKERS, default=list(TRACKERS),
        help="vo: the VO's Lucas-Kanade; yaw: the yaw core's phase correlation (both)",
    )  # fmt: skip
    parser.add_argument(
        "--presmooth", type=number_in(float, 0.0, 5.0), default=0.0, help="VoSettings.presmooth_sigma_px"
    )


def run(args: argparse.Namespace) -> dict[str, Any]:
    cv2.setNumThreads(1)
    vo_settings, yaw_settings = VoSettings(presmooth_sigma_px=args.presmooth), YawSettings()
    trackers: dict[str, Callable[[U8Array, U8Array, FloatArray], tuple[float, float]]] = {
        "vo": lambda a, b, d: measure(a, b, d, vo_settings),
        "yaw": lambda a, b, d: measure_yaw_core(a, b, d, yaw_settings),
    }
    table = []
    raw: dict[str, dict[str, list[list[float]]]] = {}
    for generator in args.generators:
        make = band_limited_pair if generator == "band_limited" else rendered_pair
        for shift in args.shifts:
            pairs = []
            for pair in range(args.pairs):
                angle = 2.0 * math.pi * (pair + 0.5) / args.pairs
                shift_px = shift * np.array([math.cos(angle), math.sin(angle)])
                pairs.append((*make(pair, shift_px), shift_px))
            for tracker in args.trackers:
                read = [trackers[tracker](a, b, d) for a, b, d in pairs]
                ratios, across = [r[0] / shift for r in read], [r[1] for r in read]
                raw.setdefault(f"{tracker} {generator}", {})[f"{shift:g}"] = [ratios, across]
                table.append({
                    "tracker": tracker, "generator": generator, "shift_px": shift, "pairs": args.pairs,
                    "ratio": float(np.nanmean(ratios)), "ratio_std": float(np.nanstd(ratios)),
                    "across_px": float(np.nanmean(across)),
                })  # fmt: skip
    return {"table": table, "json": {"presmooth_sigma_px": args.presmooth, "pairs": raw}}
