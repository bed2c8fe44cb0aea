"""``capataz bench yaw --suite field``: every field scenario (and the hover) through the core and the paper's
method on the same frames.

The core runs as a user would fly it: the flight's calibration in its settings and the gyro's integrated
rotation between the frame stamps as its prior (``capataz/uav/{uav}/imu`` in the cluster), the body's yaw
rate as the image turns with it (the flight's camera mount and IMU axes) and on the IMU's clock; none in the
scenarios without an IMU. The baseline is the paper's method (``cv2.phaseCorrelate`` per 64 px patch
pair, RANSAC homography, no prior). Errors are per pair on the *published* (integrated) delta, wrapped;
beside the errors of all pairs, the held and bridged pairs over 2 deg. Max AME is paper A's eq. 8 with
N = 100. Both methods take turns on blocks of frames on one thread. Per-frame cost is the thread's CPU
time (``time.thread_time``): on a shared machine wall-clock p99 measures the neighbours' load, not the
method.
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from common.consistency import error_consistency
from common.errors import CapatazError
from common.metrics import accumulated_mean_error, yaw_error_rad
from common.sim.field import FIELD_LENSES, FIELD_RATES_HZ, FIELD_SCENARIOS, field_flight, scenario_camera
from common.sim.flight import CAMERA_RATE_HZ, Flight, hover_flight
from common.types import FloatArray
from common.yaw import Provenance, YawSettings, for_frame, make_patch_grid
from common.yaw.reference import reference_pair, reference_settings
from services.runtime.cli import parse_size
from services.runtime.usage import number_in
from services.tools.flight_prior import FlightPrior, Level

logger = logging.getLogger(__name__)

BLOCK_FRAMES = 32
AME_WINDOW = 100


@dataclass
class _Series:
    """What one method published: integrated deltas (N - 1,), ms per pair, bridged/held pairs, and each
    pair's provenance (the baseline's are all measured); the core's also each pair's delta variance and the
    yaw's variance after it (``bench consistency``)."""

    delta_rad: list[float] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)
    bridged: int = 0
    provenance: list[Provenance] = field(default_factory=list)
    delta_variance_rad2: list[float] = field(default_factory=list)
    yaw_variance_rad2: list[float] = field(default_factory=list)


class _Core:
    """The core as a user's master runs it on the flight's rig (:class:`FlightPrior`: the gyro prior, and
    the level views as ``level`` says)."""

    def __init__(
        self,
        flight: Flight,
        frames: list[npt.NDArray[np.uint8]],
        settings: YawSettings,
        use_imu: bool = True,
        level: Level = Level.NONE,
    ) -> None:
        self.flight = flight
        self.prior = FlightPrior(flight, use_imu, level)
        self.tracker = self.prior.tracker(settings)
        self.state = self.tracker.initial_state(
            frames[0], stamp_s=float(flight.frame_stamps_s[0]), R_level_body=self.prior.tilt(0)
        )

    def step(self, k: int, frame: npt.NDArray[np.uint8], series: _Series) -> None:
        t1 = float(self.flight.frame_stamps_s[k])
        start = time.thread_time()
        gyro, tilt = self.prior.gyro_delta_rad(k), self.prior.tilt(k)
        self.state, estimate = self.tracker.track(self.state, frame, t1, gyro, tilt)
        series.ms.append((time.thread_time() - start) * 1e3)
        series.delta_rad.append(estimate.delta_yaw_rad)
        series.bridged += int(estimate.provenance is not Provenance.MEASURED)
        series.provenance.append(estimate.provenance)
        series.delta_variance_rad2.append(estimate.delta_variance_rad2)
        series.yaw_variance_rad2.append(estimate.yaw_variance_rad2)


class _Baseline:
    def __init__(self, frames: list[npt.NDArray[np.uint8]]) -> None:
        self.settings = reference_settings()
        self.grid = make_patch_grid(frames[0].shape, self.settings)
        self.previous = frames[0]

    def step(self, k: int, frame: npt.NDArray[np.uint8], series: _Series) -> None:
        start = time.thread_time()
        delta = reference_pair(self.previous, frame, self.grid, self.settings).delta_yaw_rad
        series.ms.append((time.thread_time() - start) * 1e3)
        series.delta_rad.append(delta)
        self.previous = frame


def pair_stats(series: _Series, true_yaw_rad: FloatArray) -> dict[str, Any]:
    """The issue's fields for one method on one flight."""
    deltas = np.asarray(series.delta_rad)
    error_rad = yaw_error_rad(deltas, np.diff(true_yaw_rad))
    pair_err = np.abs(np.degrees(error_rad))
    yaw = np.concatenate([[0.0], np.cumsum(deltas)])
    yaw_err_rad = yaw_error_rad(yaw, true_yaw_rad - true_yaw_rad[0])
    err_deg = np.degrees(yaw_err_rad)
    ame = accumulated_mean_error(err_deg, AME_WINDOW) if err_deg.size > AME_WINDOW else np.array([math.nan])
    ms = np.asarray(series.ms)
    provenance = series.provenance or [Provenance.MEASURED] * deltas.size
    unmeasured = np.array([p is not Provenance.MEASURED for p in provenance], dtype=bool)
    held = np.array([p is Provenance.HELD for p in provenance], dtype=bool)
    return {
        "pairs": int(deltas.size),
        "median_abs_err_deg": float(np.median(pair_err)),
        "p99_abs_err_deg": float(np.percentile(pair_err, 99)),
        "pairs_over_5deg": int(np.count_nonzero(pair_err > 5.0)),
        "max_ame_deg": float(np.max(ame)),
        "final_err_deg": float(err_deg[-1]),
        "ms_median": float(np.median(ms)),
        "ms_p99": float(np.percentile(ms, 99)),
        "bridged_pairs": int(series.bridged),
        "held_pairs": int(np.count_nonzero(held)),
        "unmeasured_over_2deg": int(np.count_nonzero(unmeasured & (pair_err > 2.0))),
        "unmeasured_max_err_deg": float(np.max(pair_err[unmeasured])) if unmeasured.any() else 0.0,
        **_measured_consistency(series.delta_variance_rad2, error_rad, ~unmeasured),
        **_yaw_consistency(series.yaw_variance_rad2, yaw_err_rad[1:]),
    }


def _measured_consistency(
    delta_variance_rad2: list[float], error_rad: FloatArray, measured: npt.NDArray[np.bool_]
) -> dict[str, float]:
    """The measured pairs' errors against the variance published with them (the core's; the baseline
    publishes none): the share within 2 sigma and the mean NEES (``bench consistency`` splits them by
    seed)."""
    if not delta_variance_rad2:
        return {}
    error = error_rad[measured]
    variance = np.asarray(delta_variance_rad2, dtype=np.float64)[measured]
    if not error.size:
        return {"measured_within_2_sigma": math.nan, "measured_mean_nees": math.nan}
    scored = error_consistency(error, variance)
    return {"measured_within_2_sigma": scored.within_2_sigma, "measured_mean_nees": scored.nees_mean}


def _yaw_consistency(yaw_variance_rad2: list[float], error_rad: FloatArray) -> dict[str, float]:
    """The published (integrated) yaw's error at every frame after the first against the yaw variance
    published with it: the share within 2 sigma and the mean NEES (the core's; the baseline publishes none).
    A bias that every pair shares grows with the pairs, not with their square root: this is where it shows."""
    if not yaw_variance_rad2:
        return {}
    scored = error_consistency(error_rad, np.asarray(yaw_variance_rad2, dtype=np.float64))
    return {"yaw_within_2_sigma": scored.within_2_sigma, "yaw_mean_nees": scored.nees_mean}


def run_flight(
    flight: Flight, settings: YawSettings, use_imu: bool = True, level: Level = Level.NONE
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Core and baseline on the same (pre-rendered) frames, in turns of ``BLOCK_FRAMES``."""
    frames = list(flight.frames())
    core, base = _Core(flight, frames, settings, use_imu, level), _Baseline(frames)
    core_series, base_series = _Series(), _Series()
    for first in range(1, len(frames), BLOCK_FRAMES):
        block = range(first, min(first + BLOCK_FRAMES, len(frames)))
        for k in block:
            core.step(k, frames[k], core_series)
        for k in block:
            base.step(k, frames[k], base_series)
    return pair_stats(core_series, flight.yaw_rad), pair_stats(base_series, flight.yaw_rad)


def run_core(
    flight: Flight,
    settings: YawSettings,
    frames: list[npt.NDArray[np.uint8]] | None = None,
    gyro: bool = True,
    level: Level = Level.NONE,
) -> _Series:
    """The core alone on a flight (frames given: already rendered), as :func:`run_flight` runs it: the
    flight's calibration and the gyro prior (``gyro`` False: no IMU, untrusted pairs are held)."""
    frames = list(flight.frames()) if frames is None else frames
    core = _Core(flight, frames, settings, gyro, level)
    series = _Series()
    for k in range(1, len(frames)):
        core.step(k, frames[k], series)
    return series


#: the help of an option naming a subset of the field suite (:func:`scenario_names`)
SCENARIOS_HELP = (
    f"comma-separated subset of the field suite (default all: {', '.join(FIELD_SCENARIOS)}, hover)"
)


def scenario_names(text: str) -> list[str]:
    """The field suite's scenarios and the hover named in ``text`` (comma-separated; empty: all of them), in
    the suite's order; an unknown name is one error line."""
    names = [*FIELD_SCENARIOS, "hover"]
    if not text:
        return names
    wanted = [n.strip() for n in text.split(",") if n.strip()]
    unknown = sorted(set(wanted) - set(names))
    if unknown:
        raise CapatazError(f"unknown field scenario(s) {unknown}; known: {', '.join(names)}")
    return [n for n in names if n in wanted]


def add_field_arguments(parser: argparse.ArgumentParser) -> None:
    """``bench yaw``'s options of this suite (``--suite field``), a group of its own in ``--help``."""
    group = parser.add_argument_group(
        "field suite",
        "every field scenario and the hover, core (calibration + gyro prior) vs the paper's method "
        "(out/bench/yaw_field.json)",
    )
    group.add_argument("--field-frames", type=int, default=600, help="frames per field scenario (>= 102)")
    group.add_argument("--hover-frames", type=int, default=2041, help="hover frames of the field suite")
    group.add_argument("--field-scenarios", default="", help=SCENARIOS_HELP)
    group.add_argument(
        "--field-size",
        default="320x240",
        help="frame size of the field scenarios (WxH; default 320x240): each lens keeps its field of view",
    )
    group.add_argument(
        "--field-lens",
        choices=list(FIELD_LENSES),
        default=None,
        help="fly every field scenario with this lens instead of its own (default: each scenario's)",
    )
    group.add_argument(
        "--field-fps",
        type=number_in(float, *FIELD_RATES_HZ),
        default=CAMERA_RATE_HZ,
        help=f"frame rate of the field scenarios (default {CAMERA_RATE_HZ:g}); --field-frames frames at it",
    )
    group.add_argument(
        "--field-level",
        choices=[m.value for m in Level],
        default=Level.NONE.value,
        help="each frame's tilt for the core's level views: none (default, as a master's default), imu (as "
        "a master with --level-views: the IMU's specific force over 3 s, flights with an IMU) or truth (the "
        "flight's attitude)",
    )
    group.add_argument(
        "--field-pyramid-level",
        type=number_in(int, 0, 4),
        default=None,
        help="the core's pyramid level (default: by the frame's size, as a master does)",
    )


def run_field(args: argparse.Namespace) -> dict[str, Any]:
    cv2.setNumThreads(1)
    size = parse_size(args.field_size, "--field-size", "640x480")
    settings = YawSettings(pyramid_level=args.field_pyramid_level)
    scenarios: dict[str, Any] = {}
    baseline: dict[str, Any] = {}
    rows: list[dict[str, Any]] = []
    names = scenario_names(args.field_scenarios)
    for name in names:
        logger.info("scenario %s: rendering and running", name)
        use_imu = True
        if name == "hover":
            flight: Flight = hover_flight(
                seed=args.seed, n_frames=max(int(args.hover_frames), AME_WINDOW + 2)
            )
        else:
            scenario = FIELD_SCENARIOS[name]
            camera = scenario_camera(scenario, *size, lens=args.field_lens)
            flight = field_flight(
                scenario,
                seed=args.seed,
                n_frames=args.field_frames,
                camera=camera,
                camera_rate_hz=args.field_fps,
            )
            use_imu = scenario.use_imu
        core, base = run_flight(flight, settings, use_imu, Level(args.field_level))
        core["pyramid_level"] = for_frame(settings, flight.camera.shape).pyramid_level
        scenarios[name], baseline[name] = core, base
        for method, stats in (("core", core), ("baseline", base)):
            rows.append({"scenario": name, "method": method, **stats})
        rows[-1]["speedup"] = base["ms_median"] / core["ms_median"]
        rows[-2]["speedup"] = 1.0
    field_names = [n for n in names if n != "hover"] or ["hover"]
    payload = {
        "field_size": "{}x{}".format(*size),
        "field_lens": args.field_lens,
        "field_fps": args.field_fps,
        "field_level": args.field_level,
        "scenarios": scenarios,
        "baseline": baseline,
        "worst_max_ame_deg": max(scenarios[n]["max_ame_deg"] for n in field_names),
        "total_pairs_over_5deg": sum(scenarios[n]["pairs_over_5deg"] for n in field_names),
        "total_unmeasured_over_2deg": sum(scenarios[n]["unmeasured_over_2deg"] for n in field_names),
    }
    return {"json_name": "yaw_field", "json": payload, "table": rows}
