"""Pieces of ``capataz bench estimator``: the seed sweep over the two flights and the step timings.

- :func:`sweep`: each flight (paper C's turns, the agile flight) and seed through the rectified and the
  traditional estimator (fed the same stream, frames rendered once); ATE RMSE and RPE per metre of the
  horizontal VO position (:mod:`common.metrics`), final error, attitude RMSE; medians and maxima over seeds.
- :func:`time_ekf_steps`, :func:`time_vo_steps`: one filter predict + accelerometer update and one VO step
  (rectification included, rendering excluded) with warm-up and repetitions; median, p95 and the host's CPU
  steal over the measurement (``/proc/stat``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.estimation.ekf import AttitudeAltitudeEkf
from common.estimation.eskf import BiasAwareEkf
from common.estimation.replay import evaluate, run_estimators, standard_estimators
from common.estimation.vo import MotionModel, VoPose, VoSettings
from common.estimation.vo_chain import advance_vo_chain, prepare_view, start_vo_chain
from common.geometry import R_BODY_CAMERA_DOWN, matrix_from_euler
from common.sim.flight import Flight, agile_flight, turns_flight
from common.sim.stream import flight_measurements

logger = logging.getLogger(__name__)

#: The flights of the sweep.
FLIGHTS: dict[str, Callable[[int], Flight]] = {
    "paper_c": lambda seed: turns_flight(seed=seed),
    "agile": lambda seed: agile_flight(seed=seed),
}

#: Per-seed figures summarised by median and maximum.
SEED_FIELDS = (
    "ate_rmse_cm_rectified",
    "ate_rmse_cm_traditional",
    "rpe_pct_rectified",
    "rpe_pct_traditional",
    "final_error_cm_rectified",
    "final_error_cm_traditional",
    "att_rmse_deg",
    "att_rmse_deg_tilt",
    "att_rmse_deg_yaw",
    "rpe_along_pct_rectified",
    "rpe_cross_pct_rectified",
)


def seed_figures(flight: Flight, names: tuple[str, ...] = ("rectified", "traditional")) -> dict[str, float]:
    """One flight through the estimators: the per-seed figures of :data:`SEED_FIELDS` (and the reference
    filter's, when ``rectified_paper_c`` is among ``names``)."""
    runs = run_estimators(standard_estimators(flight, 0, names), flight_measurements(flight))
    errors = {name: evaluate(runs[name], flight) for name in names}
    out: dict[str, float] = {}
    for name, err in errors.items():
        out[f"ate_rmse_cm_{name}"] = 100.0 * err.ate_rmse_m
        out[f"rpe_pct_{name}"] = err.rpe_pct
        out[f"final_error_cm_{name}"] = 100.0 * err.vo_final_error_m
        # which part of the relative error is scale (along the path) and which heading (across it)
        out[f"rpe_along_pct_{name}"] = err.rpe_along_pct
        out[f"rpe_cross_pct_{name}"] = err.rpe_cross_pct
    for name in names:
        if name not in ("rectified", "traditional"):
            out[f"att_rmse_deg_{name}"] = float(np.max(errors[name].att_rmse_deg))
    rect = errors["rectified"].att_rmse_deg
    out["att_rmse_deg"] = float(np.max(rect))
    # the attitude line's axis: roll/pitch (what the rectification uses) or yaw (the VO's heading drift)
    out["att_rmse_deg_tilt"] = float(max(rect[0], rect[1]))
    out["att_rmse_deg_yaw"] = float(rect[2])
    return out


def summarize_seeds(rows: list[dict[str, float]]) -> dict[str, Any]:
    """Medians and maxima over seeds, and the share of seeds where rectified ATE <= traditional ATE."""
    summary: dict[str, Any] = {}
    for key in rows[0]:
        values = np.array([row[key] for row in rows], dtype=np.float64)
        summary[key] = {"median": float(np.median(values)), "max": float(np.max(values))}
    better = [row["ate_rmse_cm_rectified"] <= row["ate_rmse_cm_traditional"] for row in rows]
    summary["rectified_better_share"] = float(np.mean(better))
    summary["rectified_better_seeds"] = int(np.sum(better))
    summary["per_seed"] = rows
    return summary


#: The repository root (for the code fingerprint).
ROOT = Path(__file__).resolve().parents[3]


def code_fingerprint(root: Path = ROOT) -> str:
    """Hash of the sources a seed's figures depend on (the estimator cores, the simulator, the metrics and
    this module): a stored per-seed result is reused only when none of them changed."""
    digest = hashlib.sha256()
    common = root / "common"
    files = sorted(
        [
            *(common / "estimation").glob("*.py"),
            *(common / "sim").glob("*.py"),
            common / "metrics.py",
            common / "geometry.py",
            Path(__file__).resolve(),
        ]
    )
    for path in files:
        if path.exists():
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _seed_job(job: tuple[str, int, tuple[str, ...]]) -> dict[str, float]:
    flight_name, seed, names = job
    logging.disable(logging.WARNING)  # per-frame warnings of a 20-seed sweep would drown the log
    cv2.setNumThreads(1)
    t0 = time.perf_counter()
    row = {"seed": float(seed), **seed_figures(FLIGHTS[flight_name](seed), names)}
    row["wall_s"] = time.perf_counter() - t0
    return row


def sweep(
    flights: tuple[str, ...],
    seeds: int,
    reference: bool,
    log: Callable[[str], None] | None = None,
    jobs: int = 1,
    cache_dir: Path | None = None,
    any_vehicle: bool = False,
) -> dict[str, Any]:
    """Seeds ``0 .. seeds - 1`` of each flight; ``reference`` adds paper C's 5-state filter, ``any_vehicle``
    the proposal without knowing the vehicle (the service's default). ``jobs``
    processes run seeds side by side; with ``cache_dir`` each seed's figures are stored there under the
    :func:`code_fingerprint` and reused while the code is unchanged (an interrupted sweep resumes)."""
    names = (
        ("rectified", "traditional")
        + (("rectified_paper_c",) if reference else ())
        + (("rectified_any_vehicle",) if any_vehicle else ())
    )
    fingerprint = code_fingerprint()
    todo: list[tuple[str, int, tuple[str, ...]]] = []
    done: dict[tuple[str, int], dict[str, float]] = {}
    # seeds interleaved across flights: a sweep cut short still covers every flight
    for seed in range(seeds):
        for flight_name in flights:
            cached = _load_seed(cache_dir, fingerprint, flight_name, seed, names)
            if cached is not None:
                done[(flight_name, seed)] = cached
            else:
                todo.append((flight_name, seed, names))

    def record(job: tuple[str, int, tuple[str, ...]], row: dict[str, float]) -> None:
        done[(job[0], job[1])] = row
        _store_seed(cache_dir, fingerprint, job[0], job[1], names, row)
        if log is not None:
            log(
                f"{job[0]} seed {job[1]}: ATE rect {row['ate_rmse_cm_rectified']:.2f} cm, "
                f"trad {row['ate_rmse_cm_traditional']:.2f} cm, "
                f"RPE rect {row['rpe_pct_rectified']:.3f} %, "
                f"trad {row['rpe_pct_traditional']:.3f} %, att {row['att_rmse_deg']:.3f} deg "
                f"({row['wall_s']:.0f} s)"
            )

    if jobs <= 1 or len(todo) <= 1:
        for job in todo:
            record(job, _seed_job(job))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(_seed_job, job): job for job in todo}
            for future in as_completed(futures):
                record(futures[future], future.result())
    out: dict[str, Any] = {}
    for flight_name in flights:
        rows = [done[(flight_name, seed)] for seed in range(seeds)]
        out[flight_name] = summarize_seeds([{k: v for k, v in row.items() if k != "wall_s"} for row in rows])
    return out


def _seed_path(
    cache_dir: Path, fingerprint: str, flight_name: str, seed: int, names: tuple[str, ...]
) -> Path:
    return cache_dir / f"{flight_name}_{seed}_{'-'.join(names)}_{fingerprint}.json"


def _load_seed(
    cache_dir: Path | None, fingerprint: str, flight_name: str, seed: int, names: tuple[str, ...]
) -> dict[str, float] | None:
    if cache_dir is None:
        return None
    path = _seed_path(cache_dir, fingerprint, flight_name, seed, names)
    try:
        row = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(row, dict) or not all(isinstance(v, (int, float)) for v in row.values()):
        logger.warning("ignoring %s: not a seed result", path)
        return None
    return {str(k): float(v) for k, v in row.items()}


def _store_seed(
    cache_dir: Path | None,
    fingerprint: str,
    flight_name: str,
    seed: int,
    names: tuple[str, ...],
    row: dict[str, float],
) -> None:
    if cache_dir is None:
        return
    cache_dir.mkdir(parents=True, exist_ok=True)
    _seed_path(cache_dir, fingerprint, flight_name, seed, names).write_text(json.dumps(row))


# ---- timing ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Timing:
    """Step times (median, p95, in the unit of the name) and the CPU steal share during the measurement."""

    median: float
    p90: float
    p95: float
    samples: int
    steal_pct: float


def cpu_times(stat_path: Path = Path("/proc/stat")) -> tuple[float, float]:
    """``(steal, total)`` jiffies of all CPUs from ``/proc/stat`` (nan, nan where it does not exist)."""
    try:
        fields = stat_path.read_text().splitlines()[0].split()
    except OSError:
        return float("nan"), float("nan")
    values = [float(v) for v in fields[1:]]
    steal = values[7] if len(values) > 7 else 0.0
    return steal, float(sum(values[:8]))


def _timing(samples: list[float], before: tuple[float, float], after: tuple[float, float]) -> Timing:
    total = after[1] - before[1]
    steal = 100.0 * (after[0] - before[0]) / total if total > 0 else float("nan")
    arr = np.asarray(samples, dtype=np.float64)
    return Timing(
        float(np.median(arr)),
        float(np.percentile(arr, 90)),
        float(np.percentile(arr, 95)),
        int(arr.size),
        steal,
    )


def time_ekf_steps(flight: Flight, filter_kind: str, n_steps: int, repeats: int, warmup: int = 500) -> Timing:
    """Wall time (us) of one ``predict + update_accelerometer`` on the flight's IMU samples (the bias
    filter's predict with the accelerometer, as the coupling calls it): ``repeats`` passes over ``n_steps``
    samples, the first ``warmup`` steps of each pass not counted (the compiled kernels are built before)."""
    ekf: AttitudeAltitudeEkf | BiasAwareEkf = (
        BiasAwareEkf() if filter_kind == "bias" else AttitudeAltitudeEkf()
    )
    imu = flight.imu
    n = min(n_steps, imu.n_samples - 1)
    gyro = [imu.gyro_rad_s[k] for k in range(n + 1)]
    accel = [imu.accel_m_s2[k] for k in range(n + 1)]
    dts = np.diff(imu.stamps_s[: n + 1]).tolist()
    clock = time.perf_counter_ns
    samples: list[float] = []
    before = cpu_times()
    for _ in range(repeats):
        state: Any = ekf.initial_state(imu.true_q_world_body[0], float(imu.true_p_world_body_m[0, 2]), 0.0)
        for k in range(n):
            t0 = clock()
            if isinstance(ekf, BiasAwareEkf):  # its predict integrates the accelerometer too
                state = ekf.predict(state, gyro[k + 1], dts[k], accel[k + 1])
            else:
                state = ekf.predict(state, gyro[k + 1], dts[k])
            state = ekf.update_accelerometer(state, accel[k + 1]).state
            dt_ns = clock() - t0
            if k >= warmup:
                samples.append(dt_ns * 1e-3)
    return _timing(samples, before, cpu_times())


def time_vo_steps(
    flight: Flight, start: int, frames: int, repeats: int, rectify: bool, settings: VoSettings | None = None
) -> tuple[Timing, float]:
    """Wall time (ms) of one VO step (rectification with the true roll and pitch, preparation, the pair,
    the composition) over pre-rendered frames, the first pass a warm-up; and the final horizontal error
    (cm) of that chain against the truth, for comparing settings on accuracy too."""
    vo_settings = settings or VoSettings()
    images = [flight.frame(i) for i in range(start, start + frames)]
    K, R_bc = flight.camera.K, flight.R_body_camera
    model = MotionModel.LEVEL_FREE_YAW if rectify else MotionModel.FREE
    samples: list[float] = []
    before = cpu_times()
    final_cm = float("nan")
    for rep in range(repeats + 1):
        chain = None
        for j, image in enumerate(images):
            i = start + j
            rp = (float(flight.euler_rad[i, 0]), float(flight.euler_rad[i, 1])) if rectify else None
            h = float(flight.p_world_body_m[i, 2])
            t0 = time.perf_counter_ns()
            frame = prepare_view(image, K, R_bc, rp, vo_settings)
            if chain is None:
                R0 = flight.R_world_body[i] @ R_bc
                if rectify:
                    R0 = matrix_from_euler(0.0, 0.0, float(flight.euler_rad[i, 2])) @ R_BODY_CAMERA_DOWN
                chain = start_vo_chain(frame, VoPose(R0, flight.p_world_body_m[i].copy()), h)
                continue
            chain = advance_vo_chain(chain, frame, h, K, vo_settings, model).state
            dt_ns = time.perf_counter_ns() - t0
            if rep > 0:
                samples.append(dt_ns * 1e-6)
        if chain is not None:
            end = start + len(images) - 1
            final_cm = 100.0 * float(
                np.linalg.norm(chain.pose.p_n_camera_m[:2] - flight.p_world_body_m[end, :2])
            )
    return _timing(samples, before, cpu_times()), final_cm
