"""Consistency: whether the published uncertainties are honest (yaw, estimator, localizer against truth).

Per line (what is measured, :mod:`services.tools.bench.consistency_runs`): the share of errors within 1, 2
and 3 sigma (for d components: NEES within the chi-square quantile of the normal's 1-3 sigma probability)
and the mean NEES against its two-sided 95 % chi-square bounds (``common.consistency``). The target of issue
26: 2-sigma share in [0.90, 0.98] and the mean NEES within its bounds.

Seeds are split: the first half (``fit``) is what any variance model was tuned on, the second half
(``held_out``) is reported in the table; the JSON has both and all seeds together. The yaw's per-pair lines
compare each pair's published delta with the true yaw change (its ``delta_variance_rad2``); the accumulated
lines the published yaw with the truth at every frame (its ``yaw_variance_rad2``): correlated errors, so the
bounds (independent samples) are narrower than the mean NEES's true spread there. So each line also has
its mean NEES per seed and the bounds over seeds (``seed_lo``, ``seed_hi``: a bootstrap over whole seeds,
:func:`common.consistency.seed_bounds`), the spread the pooled mean really has for errors correlated
within a run: ``nees_within_seed_bounds`` says whether they contain the dof. And each line has the
chi-square test as it is meant for such series (:func:`common.consistency.ensemble_consistency`, Bar-Shalom's
Monte Carlo test): at each time step (scenario, flight or scene, and frame) the average NEES over the seeds
against its 95 % bounds; ``steps_in`` is the share of steps within them (about 0.95 when honest; target
>= 0.90), ``steps_hi`` above (overconfident), ``steps_lo`` below (cautious). ``--quick`` runs one
scenario, flight and scene with few frames on 2 seeds (a test runs it).
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from common.consistency import consistency, ensemble_consistency, seed_bounds
from common.sim.field import FIELD_SCENARIOS
from common.sim.flight import CAMERA_RATE_HZ, IMU_RATE_HZ, RANGE_RATE_HZ, FlightOptions
from services.runtime.usage import number_in
from services.tools.bench import (
    estimator_attitude_fit,
    estimator_drift_fit,
    localizer_covariance_fit,
    yaw_correlation_fit,
    yaw_held_fit,
    yaw_variance_fit,
)
from services.tools.bench.consistency_runs import (
    DOF,
    FLIGHTS,
    LOCALIZER_SCENES,
    MAX_GLARE,
    LineSamples,
    Samples,
    estimator_samples,
    localizer_samples,
    merge_samples,
    yaw_samples,
)

logger = logging.getLogger(__name__)

NAME = "consistency"
SUITES = ("yaw", "estimator", "localizer")
#: The issue's target for the 2-sigma share.
TARGET_2_SIGMA = (0.90, 0.98)
#: Least share of time steps whose average NEES over the seeds is within its 95 % chi-square bounds (an
#: honest estimator: about 0.95; the same floor as the 2-sigma share's)
TARGET_STEPS_WITHIN = 0.90


#: the estimator flights' sensors: option, bounds, default, help
FLIGHT_SENSOR_OPTIONS = (
    ("--imu-hz", 20.0, 4000.0, IMU_RATE_HZ, f"IMU rate of the estimator's flights (default {IMU_RATE_HZ:g})"),
    ("--camera-hz", 2.0, 200.0, CAMERA_RATE_HZ, f"their frame rate (fps, default {CAMERA_RATE_HZ:g})"),
    (
        "--range-hz", 2.0, 1000.0, RANGE_RATE_HZ,
        f"their rangefinder rate (default {RANGE_RATE_HZ:g}; 33 puts its samples between the IMU's, as a "
        "real rig's)",
    ),
    (
        "--frame-jitter-ms", 0.0, 20.0, 0.0,
        "each of their frames' stamps moved by up to this (ms, uniform): frames between the IMU's samples, "
        "as a real rig's (default 0: on the IMU's)",
    ),
)  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", type=int, default=20, help="seeds 0..N-1: first half fit, second held out")
    parser.add_argument("--suites", nargs="+", choices=SUITES, default=list(SUITES), help="suites (all)")
    parser.add_argument("--field-frames", type=int, default=600, help="frames per yaw field scenario")
    parser.add_argument("--scenarios", nargs="+", choices=list(FIELD_SCENARIOS), help="yaw scenarios (all)")
    parser.add_argument(
        "--glare", type=float, default=0.0, metavar="SHARE",
        help="share of each yaw scenario's frames washed out (sun glare, an exposure hiccup: nothing to "
        "measure), so that the bridged (gyro) and held (no IMU) pairs have lines; 0.08 measures them "
        "(0: off)",
    )  # fmt: skip
    parser.add_argument("--estimator-frames", type=int, default=None, help="frames per flight (all)")
    parser.add_argument("--flights", nargs="+", choices=list(FLIGHTS), help="estimator flights (both)")
    for flag, low, high, default, text in FLIGHT_SENSOR_OPTIONS:
        parser.add_argument(flag, type=number_in(float, low, high), default=default, help=text)
    parser.add_argument("--localizer-frames", type=int, default=150, help="frames per localizer run")
    parser.add_argument("--scenes", nargs="+", choices=list(LOCALIZER_SCENES), help="localizer scenes (both)")
    parser.add_argument(
        "--quick", action="store_true", help="2 seeds, one scenario/flight/scene each, few frames"
    )
    parser.add_argument(
        "--held-out-only", action="store_true", help="run only the held-out half of the seeds (the table's)"
    )
    fits = parser.add_mutually_exclusive_group()  # one fit per run, not the first of several
    for name, (what, _) in FITS.items():
        fits.add_argument(f"--fit-{name}", action="store_true", help=f"instead: fit {what}")


def _quick(args: argparse.Namespace) -> None:
    args.seeds = min(args.seeds, 2)
    args.field_frames = min(args.field_frames, 40)
    args.scenarios = args.scenarios or ["field"]
    args.estimator_frames = min(args.estimator_frames or 130, 130)
    args.flights = args.flights or ["paper_c"]
    args.localizer_frames = min(args.localizer_frames, 12)
    args.scenes = args.scenes or ["office"]


def _per_step(samples: LineSamples) -> list[list[float]]:
    """The NEES of each time step of merged seeds (a value per seed that has the step)."""
    steps: dict[str, list[float]] = {}
    for step, value in zip(samples.steps, samples.nees, strict=True):
        steps.setdefault(step, []).append(value)
    return list(steps.values())


def _summary(samples: Samples, runs: dict[str, list[list[float]]]) -> dict[str, dict[str, Any]]:
    """Each line's :class:`~common.consistency.Consistency`, whether it meets the 2-sigma target, the mean
    NEES per seed with the bounds over seeds (:func:`~common.consistency.seed_bounds`), and the per-step
    test over the seeds (:func:`~common.consistency.ensemble_consistency`, ``steps_*``)."""
    out = {}
    for line, values in samples.items():
        c: dict[str, Any] = dict(consistency(values.nees, DOF[line]).as_dict())
        share = c["within_2_sigma"]
        c["meets_2_sigma"] = bool(TARGET_2_SIGMA[0] <= share <= TARGET_2_SIGMA[1])
        per_seed = [run for run in runs.get(line, []) if run]
        c["nees_per_seed"] = [float(np.mean(run)) for run in per_seed]
        c["nees_seed_lower"], c["nees_seed_upper"] = seed_bounds(per_seed)
        c["nees_within_seed_bounds"] = bool(c["nees_seed_lower"] <= c["dof"] <= c["nees_seed_upper"])
        ensemble = ensemble_consistency(_per_step(values), DOF[line])
        c.update({f"steps_{key}": value for key, value in ensemble.as_dict().items()})
        c["meets_steps"] = bool(ensemble.within >= TARGET_STEPS_WITHIN)
        out[line] = c
    return out


def _fold_label(fold: dict[str, Any]) -> str:
    """A two-fold row's name: which fit seeds it was fitted on (it is scored on the others)."""
    return f"fit {fold['fit_seeds'][0]}-{fold['fit_seeds'][-1]}, scored on the others"


def _terms_fit_output(result: dict[str, Any]) -> dict[str, Any]:
    """The JSON and table of a fit by :func:`~services.tools.bench.yaw_variance_fit.fit_terms`: the fitted
    and in-use constants with their scores, then the two-fold rows."""
    table = [
        {"model": which, **result[which], **result[f"{which}_score"]} for which in ("fitted", "in_use")
    ] + [{"model": _fold_label(f), **f} for f in result["two_fold"]]
    return {"json": result, "table": table}


def _fit_yaw(fit_seeds: list[int], args: argparse.Namespace) -> dict[str, Any]:
    return _terms_fit_output(yaw_variance_fit.fit(fit_seeds, args.field_frames, args.scenarios))


def _fit_yaw_correlation(fit_seeds: list[int], args: argparse.Namespace) -> dict[str, Any]:
    result = yaw_correlation_fit.fit(fit_seeds, args.field_frames, args.scenarios)
    table = [{"model": name, **result[name]} for name in ("fitted", "in_use", "independent")]
    table += [{"model": _fold_label(f), **f} for f in result["two_fold"]]
    return {"json": result, "table": table}


def _fit_yaw_held(fit_seeds: list[int], args: argparse.Namespace) -> dict[str, Any]:
    glare = args.glare or HELD_FIT_GLARE
    return _terms_fit_output(yaw_held_fit.fit(fit_seeds, args.field_frames, glare, args.scenarios))


def _per_part_table(
    result: dict[str, Any], constants: tuple[str, ...], part: str, names: list[str]
) -> list[dict[str, Any]]:
    """A fit's rows (fitted, in use, the two folds), one per flight or scene (``part``) of ``names``, each
    with the row's ``constants`` and that part's scores."""
    rows: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
        (which, result[which], result[f"{which}_score"]) for which in ("fitted", "in_use")
    ]
    rows += [(_fold_label(f), f, f) for f in result["two_fold"]]
    return [
        {"model": model, **{k: c[k] for k in constants}, part: name, **score[name]}
        for model, c, score in rows
        for name in names
    ]


def _fit_drift(fit_seeds: list[int], args: argparse.Namespace) -> dict[str, Any]:
    result = estimator_drift_fit.fit(fit_seeds, args.estimator_frames, args.flights)
    constants = ("drift_per_pair", "MIN_VAR_XY_M2")
    table = _per_part_table(result, constants, "flight", args.flights or list(FLIGHTS))
    return {"json": result, "table": table}


def _fit_attitude(fit_seeds: list[int], args: argparse.Namespace) -> dict[str, Any]:
    result = estimator_attitude_fit.fit(fit_seeds, args.estimator_frames, args.flights)
    rows: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
        ("fitted (both flights)", result["fitted"], result["fitted_score"]),
        (
            f"yaw on {result['cautious_yaw_flight']} alone",
            result["cautious_yaw"],
            result["cautious_yaw_score"],
        ),
        ("in use", result["in_use"], result["in_use_score"]),
    ]
    rows += [(_fold_label(f), f, f) for f in result["two_fold"]]
    table = [
        {"model": model, **{k: c[k] for k in estimator_attitude_fit.CONSTANTS},
         "flight": name, "tilt_nees_per_axis": score["tilt"][name]["mean_nees"],
         "tilt_in_2sd": score["tilt"][name]["within_2_sigma"], "yaw_nees": score["yaw"][name]["mean_nees"],
         "yaw_in_2sd": score["yaw"][name]["within_2_sigma"]}
        for model, c, score in rows
        for name in (args.flights or list(FLIGHTS))
    ]  # fmt: skip
    return {"json": result, "table": table}


def _fit_localizer(fit_seeds: list[int], args: argparse.Namespace) -> dict[str, Any]:
    result = localizer_covariance_fit.fit(fit_seeds, args.localizer_frames, args.scenes)
    scenes = args.scenes or list(LOCALIZER_SCENES)
    table = _per_part_table(result, localizer_covariance_fit.CONSTANTS, "scene", scenes)
    return {"json": result, "table": table}


#: the share of frames washed out for ``--fit-yaw-held`` when ``--glare`` is not given (the bench's figure)
HELD_FIT_GLARE = 0.08

#: ``--fit-NAME`` runs a fit instead of the bench (one per run): what it fits (its help), and the function
FITS: dict[str, tuple[str, Callable[[list[int], argparse.Namespace], dict[str, Any]]]] = {
    "yaw": (
        "the measured yaw pair's variance model on the fit seeds (maximum likelihood, a two-fold check "
        "within them) and print the constants (services/tools/bench/yaw_variance_fit.py)",
        _fit_yaw,
    ),
    "yaw-correlation": (
        "the measured yaw pairs' correlation in time (share and time constant, maximum likelihood of each "
        "run's errors, a two-fold check) and print it (bench/yaw_correlation_fit.py)",
        _fit_yaw_correlation,
    ),
    "yaw-held": (
        "a held yaw pair's variance (no gyro; the frames washed out as --glare does, 0.08 unless a share "
        "above 0 is given) by maximum likelihood, a two-fold check (bench/yaw_held_fit.py)",
        _fit_yaw_held,
    ),
    "drift": (
        "the estimator's published horizontal drift (per pair and height) and floor on the fit seeds' "
        "flights (maximum likelihood, a two-fold check; bench/estimator_drift_fit.py)",
        _fit_drift,
    ),
    "attitude": (
        "the estimator's published tilt scale and yaw floor and drift on the fit seeds' flights (maximum "
        "likelihood, a two-fold check; bench/estimator_attitude_fit.py)",
        _fit_attitude,
    ),
    "localizer": (
        "the localizer's published covariance scale and edge-agreement reference and power on the fit "
        "seeds' scenes (maximum likelihood of the 6-dof errors, a two-fold check; "
        "bench/localizer_covariance_fit.py)",
        _fit_localizer,
    ),
}


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.quick:
        _quick(args)
    if args.seeds < 2:
        raise SystemExit(f"--seeds must be >= 2 (half fit, half held out), got {args.seeds}")
    if not 0.0 <= args.glare <= MAX_GLARE:
        raise SystemExit(f"--glare must be a share in [0, {MAX_GLARE}], got {args.glare}")
    cv2.setNumThreads(1)
    t0 = time.perf_counter()
    fit_seeds = list(range(args.seeds // 2))
    for name, (_, fit) in FITS.items():
        if getattr(args, f"fit_{name.replace('-', '_')}"):
            return fit(fit_seeds, args)
    held_seeds = list(range(args.seeds // 2, args.seeds))
    groups: dict[str, Samples] = {"fit": {}, "held_out": {}}
    #: per group and line, each seed's samples (for the bounds over seeds)
    runs: dict[str, dict[str, list[list[float]]]] = {"fit": {}, "held_out": {}, "all": {}}
    rates = FlightOptions(
        imu_rate_hz=args.imu_hz, camera_rate_hz=args.camera_hz, range_rate_hz=args.range_hz,
        frame_jitter_s=args.frame_jitter_ms / 1000.0,
    )  # fmt: skip
    for seed in held_seeds if args.held_out_only else range(args.seeds):
        name = "fit" if seed in fit_seeds else "held_out"
        seed_samples: Samples = {}
        if "yaw" in args.suites:
            merge_samples(seed_samples, yaw_samples(seed, args.field_frames, args.scenarios, args.glare))
        if "estimator" in args.suites:
            merge_samples(seed_samples, estimator_samples(seed, args.estimator_frames, args.flights, rates))
        if "localizer" in args.suites:
            merge_samples(seed_samples, localizer_samples(seed, args.localizer_frames, args.scenes))
        merge_samples(groups[name], seed_samples)
        for line, values in seed_samples.items():
            for kind in (name, "all"):
                runs[kind].setdefault(line, []).append(values.nees)
        logger.info("consistency: seed %d done (%.0f s)", seed, time.perf_counter() - t0)
    every: Samples = {}
    for samples in groups.values():
        merge_samples(every, samples)
    summaries = {kind: _summary(samples, runs[kind]) for kind, samples in (*groups.items(), ("all", every))}
    table = [
        {
            "line": line,
            "seeds": f"{held_seeds[0]}-{held_seeds[-1]}",
            "samples": c["samples"],
            "dof": c["dof"],
            "in_1sd": c["within_1_sigma"],
            "in_2sd": c["within_2_sigma"],
            "in_3sd": c["within_3_sigma"],
            "nees": c["nees_mean"],
            "nees_lo": c["nees_lower"],
            "nees_hi": c["nees_upper"],
            "nees_ok": c["nees_within_bounds"],
            "seed_lo": c["nees_seed_lower"],
            "seed_hi": c["nees_seed_upper"],
            "steps": c["steps_steps"],
            "steps_in": c["steps_within"],
            "steps_hi": c["steps_above"],
            "steps_lo": c["steps_below"],
            "2sd_ok": c["meets_2_sigma"],
            "steps_ok": c["meets_steps"],
            "fit_in_2sd": summaries["fit"].get(line, {}).get("within_2_sigma", math.nan),
            "fit_nees": summaries["fit"].get(line, {}).get("nees_mean", math.nan),
        }
        for line, c in sorted(summaries["held_out"].items())
    ]
    payload = {
        "fit_seeds": fit_seeds,
        "held_out_seeds": held_seeds,
        "target_2_sigma": list(TARGET_2_SIGMA),
        "target_steps_within": TARGET_STEPS_WITHIN,
        "nees_bound_probability": 0.95,
        "settings": {
            "suites": list(args.suites),
            "field_frames": args.field_frames,
            "scenarios": args.scenarios or list(FIELD_SCENARIOS),
            "glare": args.glare,
            "estimator_frames": args.estimator_frames,
            "flights": args.flights or list(FLIGHTS),
            "imu_hz": args.imu_hz,
            "camera_hz": args.camera_hz,
            "range_hz": args.range_hz,
            "frame_jitter_ms": args.frame_jitter_ms,
            "localizer_frames": args.localizer_frames,
            "scenes": args.scenes or list(LOCALIZER_SCENES),
            "quick": bool(args.quick),
            "held_out_only": bool(args.held_out_only),
        },
        "lines": summaries,
        "wall_s": time.perf_counter() - t0,
    }
    return {"json": payload, "table": table}
