"""Transport: frame codecs of the camera-to-master link: bytes, CPU and field-suite yaw per codec vs mono8.

The codecs are the camera's ``--frame-codec`` (:mod:`common.wire.frame_codec`).

Bytes and CPU are measured on paper A's camera (the simulated hover's 752x480 frames): per codec, the median
bytes per frame, the stream's bandwidth at 20 fps, and the encode and decode CPU per frame (median and p95 of
``time.process_time`` over ``--repeats`` passes over ``--timing-frames`` frames, the codecs taking turns in
each pass so that they share the host's load alike; one thread: ``cv2.setNumThreads(1)``). The accuracy runs
the yaw core as ``capataz bench yaw --suite field`` runs it (:func:`~services.tools.bench.yaw_field.run_core`:
the flight's calibration and its gyro prior) on every flight of the field suite (its scenarios and the hover,
``--seeds`` seeds of ``--frames`` frames each), once on the rendered frames (mono8) and once per codec on the
same frames passed through encode and decode: the RMS of the integrated yaw's error against the truth (all
flights' frames pooled, and the worst flight's), and the largest difference to mono8's yaw in the same run
(0 for a lossless codec: its decoded frames are bit-identical, which the bench checks). CPU figures are
process time on a shared host: compare the rows of one run.
"""

from __future__ import annotations

import argparse
import logging
import time
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import CapatazError
from common.metrics import yaw_error_rad
from common.sim.field import FIELD_SCENARIOS, field_flight
from common.sim.flight import Flight, hover_flight
from common.wire import frame_codec
from common.yaw import YawSettings
from services.tools.bench.yaw_field import SCENARIOS_HELP, run_core, scenario_names

logger = logging.getLogger(__name__)

NAME = "transport"
#: (row label, codec, JPEG quality) of each measured transport; mono8 first (the reference)
VARIANTS: tuple[tuple[str, str, int], ...] = (
    ("mono8", "mono8", frame_codec.DEFAULT_JPEG_QUALITY),
    ("png", "png", frame_codec.DEFAULT_JPEG_QUALITY),
    ("zstd", "zstd", frame_codec.DEFAULT_JPEG_QUALITY),
    ("jpeg q95", "jpeg", 95),
    ("jpeg q90", "jpeg", 90),
    ("jpeg q75", "jpeg", 75),
)
#: the camera's frame rate the bandwidth is stated at
CAMERA_FPS = 20.0

U8 = npt.NDArray[np.uint8]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", type=int, default=2, help="seeds of every field flight (0..N-1)")
    parser.add_argument("--frames", type=int, default=150, help="frames of every field flight (>= 2)")
    parser.add_argument("--scenarios", default="", help=SCENARIOS_HELP)
    parser.add_argument(
        "--timing-frames", type=int, default=40, help="752x480 hover frames whose bytes and CPU are measured"
    )
    parser.add_argument("--repeats", type=int, default=5, help="passes over the timed frames per codec")


def _through(frames: list[U8], codec: str, quality: int) -> tuple[list[U8], list[int]]:
    """``frames`` as a master receives them over ``codec`` (encoded, then decoded), and their bytes."""
    passed, sizes = [], []
    for frame in frames:
        data = frame_codec.encode(frame, codec, quality)
        sizes.append(len(data))
        passed.append(frame_codec.decode(data, codec, frame.shape[1], frame.shape[0]))
    return passed, sizes


def codec_costs(frames: list[U8], repeats: int) -> dict[str, dict[str, Any]]:
    """Per variant: median bytes per frame, encode and decode CPU ms (median, p95), and whether every decoded
    frame equals the sent one. The variants take turns within each of ``repeats`` passes."""
    encode_ms: dict[str, list[float]] = {label: [] for label, _, _ in VARIANTS}
    decode_ms: dict[str, list[float]] = {label: [] for label, _, _ in VARIANTS}
    sizes: dict[str, list[int]] = {label: [] for label, _, _ in VARIANTS}
    identical = dict.fromkeys(encode_ms, True)
    for _ in range(repeats):
        for label, codec, quality in VARIANTS:
            for frame in frames:
                t0 = time.process_time()
                data = frame_codec.encode(frame, codec, quality)
                t1 = time.process_time()
                decoded = frame_codec.decode(data, codec, frame.shape[1], frame.shape[0])
                t2 = time.process_time()
                encode_ms[label].append((t1 - t0) * 1e3)
                decode_ms[label].append((t2 - t1) * 1e3)
                sizes[label].append(len(data))
                identical[label] &= bool(np.array_equal(decoded, frame))
    return {
        label: {
            "bytes_median": float(np.median(sizes[label])),
            "encode_ms_median": float(np.median(encode_ms[label])),
            "encode_ms_p95": float(np.percentile(encode_ms[label], 95)),
            "decode_ms_median": float(np.median(decode_ms[label])),
            "decode_ms_p95": float(np.percentile(decode_ms[label], 95)),
            "bit_identical": identical[label],
        }
        for label in encode_ms
    }


def _flights(names: list[str], seeds: int, frames: int) -> list[tuple[str, Flight, bool]]:
    """(name/seed, flight, gyro prior used) of every flight of the suite, as ``bench yaw --suite field``."""
    flights = []
    for name in names:
        for seed in range(seeds):
            if name == "hover":
                flights.append((f"hover/{seed}", hover_flight(seed=seed, n_frames=frames), True))
            else:
                scenario = FIELD_SCENARIOS[name]
                flight = field_flight(scenario, seed=seed, n_frames=frames)
                flights.append((f"{name}/{seed}", flight, scenario.use_imu))
    return flights


def yaw_through_codecs(flight: Flight, use_imu: bool, settings: YawSettings) -> dict[str, dict[str, Any]]:
    """The core's integrated yaw on one flight per variant: its error against the truth (deg, per frame), its
    largest difference to mono8's yaw, the bytes per frame and whether the decoded frames are the rendered
    ones."""
    rendered = list(flight.frames())
    truth = flight.yaw_rad - flight.yaw_rad[0]
    reference: npt.NDArray[np.float64] | None = None
    out: dict[str, dict[str, Any]] = {}
    for label, codec, quality in VARIANTS:
        passed, sizes = _through(rendered, codec, quality)
        series = run_core(flight, settings, passed, use_imu)
        yaw = np.concatenate([[0.0], np.cumsum(series.delta_rad)])
        reference = yaw if reference is None else reference
        out[label] = {
            "error_deg": np.degrees(yaw_error_rad(yaw, truth)),
            "max_diff_to_mono8_deg": float(np.max(np.abs(np.degrees(yaw_error_rad(yaw, reference))))),
            "bytes_ratio": float(np.median(sizes)) / rendered[0].size,
            "bit_identical": all(np.array_equal(a, b) for a, b in zip(passed, rendered, strict=True)),
        }
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.seeds < 1 or args.frames < 2 or args.timing_frames < 1 or args.repeats < 1:
        raise CapatazError("--seeds, --timing-frames and --repeats must be >= 1 and --frames >= 2")
    names = scenario_names(args.scenarios)
    cv2.setNumThreads(1)
    hover = hover_flight(seed=0, n_frames=max(args.timing_frames, 2))
    timed = list(hover.frames())[: args.timing_frames]
    height, width = timed[0].shape
    logger.info("bytes and CPU: %d frames of %dx%d, %d passes", len(timed), width, height, args.repeats)
    costs = codec_costs(timed, args.repeats)
    settings = YawSettings()
    errors: dict[str, list[npt.NDArray[np.float64]]] = {label: [] for label, _, _ in VARIANTS}
    flights_out: dict[str, dict[str, Any]] = {}
    for flight_name, flight, use_imu in _flights(names, args.seeds, args.frames):
        logger.info("yaw through each codec: %s", flight_name)
        result = yaw_through_codecs(flight, use_imu, settings)
        flights_out[flight_name] = {}
        for label, stats in result.items():
            errors[label].append(stats.pop("error_deg"))
            stats["rms_deg"] = float(np.sqrt(np.mean(errors[label][-1] ** 2)))
            flights_out[flight_name][label] = stats
    raw = costs["mono8"]["bytes_median"]
    rows = []
    for label, codec, quality in VARIANTS:
        cost = costs[label]
        per_flight = [flights_out[f][label] for f in flights_out]
        pooled = np.concatenate(errors[label])
        rows.append(
            {
                "codec": label,
                "bytes_per_frame": cost["bytes_median"],
                "ratio": cost["bytes_median"] / raw,
                "Mbit_s_at_20fps": cost["bytes_median"] * 8 * CAMERA_FPS / 1e6,
                "encode_ms": cost["encode_ms_median"],
                "encode_ms_p95": cost["encode_ms_p95"],
                "decode_ms": cost["decode_ms_median"],
                "decode_ms_p95": cost["decode_ms_p95"],
                "field_ratio": float(np.median([f["bytes_ratio"] for f in per_flight])),
                "yaw_rms_deg": float(np.sqrt(np.mean(pooled**2))),
                "worst_flight_rms_deg": max(f["rms_deg"] for f in per_flight),
                "max_diff_to_mono8_deg": max(f["max_diff_to_mono8_deg"] for f in per_flight),
                "bit_identical": cost["bit_identical"] and all(f["bit_identical"] for f in per_flight),
                "lossless": codec in frame_codec.LOSSLESS,
                "quality": quality if codec == "jpeg" else None,
            }
        )
    return {
        "table": rows,
        "flights": flights_out,
        "settings": {
            "timing_frames": f"{len(timed)} x {width}x{height} (hover seed 0)",
            "repeats": args.repeats,
            "field_flights": list(flights_out),
            "frames_per_flight": args.frames,
            "camera_fps": CAMERA_FPS,
            "png_level": frame_codec.PNG_LEVEL,
            "zstd_level": frame_codec.ZSTD_LEVEL,
        },
        "note": "CPU is process time on a shared host (one thread): compare the rows of one run. "
        "bytes_per_frame, ratio, Mbit_s_at_20fps: the 752x480 hover; field_ratio: the field flights' frames",
    }
