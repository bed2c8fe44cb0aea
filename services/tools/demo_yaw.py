"""Yaw demo: paper A's simulated hover (2041 frames) through the cached-spectrum yaw core, in one process.

``report_yaw`` (the summary, ``yaw.png`` like paper A's Fig. 4 and ``yaw.json``) takes only estimates and
truth, so estimates that came through the cluster are reported the same way.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from common.metrics import accumulated_mean_error, yaw_error_rad, yaw_error_stats
from common.sim.flight import Flight, hover_flight
from common.types import FloatArray
from common.yaw import (
    EstimateMethod,
    Provenance,
    YawSettings,
    YawTracker,
    make_patch_grid,
)
from services.tools.flight_prior import FlightPrior
from services.tools.report import write_json

logger = logging.getLogger(__name__)


AME_WINDOW = 100


@dataclass(frozen=True)
class TrackedRun:
    """The core over a frame sequence: integrated yaw (N,) from 0, per-frame ms (N - 1,), flags."""

    yaw_rad: FloatArray
    ms_per_frame: FloatArray
    low_confidence: npt.NDArray[np.bool_]
    methods: dict[str, int]
    provenance: dict[str, int] = field(default_factory=dict)


def track_frames(
    frames: Iterable[npt.NDArray[np.uint8]], settings: YawSettings, flight: Flight | None = None
) -> TrackedRun:
    """Run ``YawTracker.track`` over frames; only the tracking calls are timed (not rendering).

    With ``flight`` (whose frames these are) the tracker is the one a master builds for the flight's rig,
    with the frame stamps, the gyro prior and the level views from the flight's IMU, as the master gets
    them from the camera's stream (:class:`~services.tools.flight_prior.FlightPrior`).
    """
    iterator = iter(frames)
    first = next(iterator)
    prior = None if flight is None else FlightPrior(flight)
    if prior is None:
        tracker = YawTracker(settings, make_patch_grid(first.shape, settings))
    else:
        tracker = prior.tracker(settings)
    stamps = flight.frame_stamps_s if flight is not None else None
    state = tracker.initial_state(
        first,
        stamp_s=float(stamps[0]) if stamps is not None else None,
        R_level_body=None if prior is None else prior.tilt(0),
    )
    yaw = [0.0]
    ms: list[float] = []
    low = [False]
    methods = {m.value: 0 for m in EstimateMethod}
    provenance = {p.value: 0 for p in Provenance}
    for k, frame in enumerate(iterator, start=1):
        start = time.perf_counter()
        if prior is None or stamps is None:
            state, estimate = tracker.track(state, frame)
        else:
            stamp, gyro, tilt = float(stamps[k]), prior.gyro_delta_rad(k), prior.tilt(k)
            state, estimate = tracker.track(state, frame, stamp, gyro, tilt)
        ms.append((time.perf_counter() - start) * 1e3)
        yaw.append(estimate.yaw_rad)
        low.append(estimate.low_confidence)
        methods[estimate.method.value] += 1
        provenance[estimate.provenance.value] += 1
    return TrackedRun(np.asarray(yaw), np.asarray(ms), np.asarray(low, dtype=np.bool_), methods, provenance)


def _plot(
    path: Path,
    stamps_s: FloatArray,
    estimated_deg: FloatArray,
    true_deg: FloatArray,
    ame_deg: FloatArray,
    label: str,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    top.plot(stamps_s, true_deg, color="black", lw=1.5, label="truth")
    top.plot(stamps_s, estimated_deg, color="tab:red", lw=1.0, ls="--", label=label)
    top.set_ylabel("yaw [deg]")
    top.set_title("(a) yaw: estimated vs true (absolute, on the flight's reference)")
    top.legend(loc="best")
    top.grid(alpha=0.3)
    bottom.plot(stamps_s[: ame_deg.size], ame_deg, color="tab:blue", lw=1.0)
    bottom.set_ylabel(f"eps_N, N={AME_WINDOW} [deg]")
    bottom.set_xlabel("flight time [s]")
    bottom.set_title(f"(b) accumulated mean error (paper A eq. 8), max {ame_deg.max():.3f} deg")
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report_yaw(
    out_dir: Path,
    stamps_s: npt.ArrayLike,
    estimated_yaw_rad: npt.ArrayLike,
    true_yaw_rad: npt.ArrayLike,
    *,
    ms_per_frame: npt.ArrayLike | None = None,
    low_confidence: npt.ArrayLike | None = None,
    label: str = "yaw core",
    extra: Mapping[str, Any] | None = None,
    stem: str = "yaw",
) -> dict[str, Any]:
    """Summarise, plot (``out_dir/<stem>.png``) and store (``out_dir/<stem>.json``) a yaw run vs the truth.

    ``estimated_yaw_rad`` (N,) is integrated from 0 at frame 0 (it is aligned to the truth's first value);
    ``true_yaw_rad`` (N,) is the flight's unwrapped yaw. Prints a short summary; returns it as a flat dict.
    """
    stamps = np.asarray(stamps_s, dtype=np.float64)
    true = np.asarray(true_yaw_rad, dtype=np.float64)
    estimated = np.asarray(estimated_yaw_rad, dtype=np.float64) + true[0]
    stats = yaw_error_stats(estimated, true, AME_WINDOW)
    error_deg = np.degrees(yaw_error_rad(estimated, true))
    ame_deg = accumulated_mean_error(error_deg, AME_WINDOW) if error_deg.size > AME_WINDOW else np.zeros(0)
    summary: dict[str, Any] = {"label": label, **asdict(stats)}
    if ms_per_frame is not None:
        ms = np.asarray(ms_per_frame, dtype=np.float64)
        summary["ms_per_frame_median"] = float(np.median(ms))
        summary["ms_per_frame_mean"] = float(np.mean(ms))
    if low_confidence is not None:
        summary["low_confidence_frames"] = int(np.count_nonzero(low_confidence))
    summary.update(extra or {})
    if ame_deg.size:
        _plot(out_dir / f"{stem}.png", stamps, np.degrees(estimated), np.degrees(true), ame_deg, label)
    series = {
        "stamps_s": stamps,
        "estimated_yaw_deg": np.degrees(estimated),
        "true_yaw_deg": np.degrees(true),
        "ame_deg": ame_deg,
    }
    path = write_json(out_dir / f"{stem}.json", {"summary": summary, "series": series})
    ms_text = f", {summary['ms_per_frame_median']:.2f} ms/frame (median)" if ms_per_frame is not None else ""
    print(
        f"yaw [{label}]: {stats.frames} frames{ms_text}; error mean {stats.mean_deg:+.3f} deg, "
        f"rms {stats.rms_deg:.3f} deg, max |e| {stats.max_abs_deg:.3f} deg, "
        f"final {stats.final_deg:+.3f} deg; "
        f"max accumulated mean error (eq. 8, N={AME_WINDOW}) {stats.max_ame_deg:.3f} deg (paper A: ~3 deg)"
    )
    print(f"wrote {out_dir / (stem + '.png')} and {path}")
    return summary


def run_demo(out_dir: Path) -> dict[str, Any]:
    """Paper A's hover (``hover_flight(seed=0)``, 2041 frames) through the core; writes yaw.png/yaw.json."""
    flight = hover_flight(seed=0)
    settings = YawSettings()
    logger.info("yaw demo: %d frames of the simulated hover", flight.n_frames)
    run = track_frames(flight.frames(), settings, flight)
    return report_yaw(
        out_dir,
        flight.frame_stamps_s,
        run.yaw_rad,
        flight.yaw_rad,
        ms_per_frame=run.ms_per_frame,
        low_confidence=run.low_confidence,
        label="yaw core (in-process)",
        extra={
            **{f"method_{k}": v for k, v in run.methods.items()},
            **{f"provenance_{k}": v for k, v in run.provenance.items()},
        },
    )
