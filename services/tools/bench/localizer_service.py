"""``capataz bench localizer --suite service``: the real cube video through the services over Zenoh, with
default settings, against the same video in-process (issue 25's service line).

One router, one localizer process (``--model cube.cao``, the video's calibration, the start ``cube.0.pos``,
``--mount camera``: ``pose/pf`` is the camera's pose) and the camera replaying ``cube/*.pgm`` at
``CUBE_FPS`` times each ``--rates`` factor (1 = the video's rate, 4 = four times faster), waiting for the
localizer before its first frame; optionally with ``--busy N`` busy-loop processes for the whole run. Each
published pose is judged by the cube suite's own edge-alignment measure (:class:`EdgeAlignment`, not the
tracker's); a run **holds** when every frame that got a pose is aligned and the last frame got one. The
in-process reference is the cube suite's run from ``cube.0.pos``. Also reported, from the localizer's
health: frames dropped (latest wins once tracking), backlog overflow and catch-ups (frames that arrived
while a search ran are queued, not dropped: the first pose is frame 0's and nothing overflows).
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from common.datasets.calibration import ros_yaml_text
from common.geometry import matrix_from_quaternion
from common.localization.pose import CameraPose
from common.sim.objects import offset_pose
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import PoseEstimate
from services.runtime.transport import open_session, zbytes
from services.tools.bench import busy_loops
from services.tools.bench.localizer_cube import (
    ALIGNED_MIN,
    CUBE_FPS,
    START_OFFSET_DEG,
    START_OFFSET_MM,
    Cube,
    EdgeAlignment,
    cube_runs,
    load_cube,
)
from services.tools.bench.security import small_cluster
from services.tools.bench.takeover import counters_of
from services.tools.up import LocalCluster

logger = logging.getLogger(__name__)

LOCALIZER = "localizer/cube/0"


def add_service_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("service suite", "the cube video through the services over Zenoh")
    group.add_argument("--rates", type=float, nargs="+", default=[1.0, 4.0], help="replay speed factors")
    group.add_argument("--busy", type=int, default=0, help="busy-loop processes during each run (0: none)")
    group.add_argument(
        "--starts",
        type=int,
        default=1,
        help="starts: cube.0.pos, then the cube suite's 5 mm / 2 deg off ones",
    )


def start_of(cube: Cube, r: int) -> CameraPose:
    """Run ``r``'s start, as the cube suite's: ``cube.0.pos``, then starts 5 mm / 2 deg off it by seed."""
    offset = (1e-3 * START_OFFSET_MM, float(np.radians(START_OFFSET_DEG)))
    return cube.start if r == 0 else offset_pose(cube.start, *offset, 60_000 + r)


def service_run(
    cube_dir: Path, cube: Cube, out_dir: Path, rate: float, busy: int, r: int = 0
) -> dict[str, Any]:
    """One replay of the cube video at ``rate`` x its rate through router, localizer and camera processes,
    the localizer started from run ``r``'s start (:func:`start_of`)."""
    calibration = out_dir / "cube_camera.yaml"
    calibration.parent.mkdir(parents=True, exist_ok=True)
    calibration.write_text(ros_yaml_text(cube.camera))
    rvec, tvec = start_of(cube, r).rvec_tvec()
    poses: dict[int, PoseEstimate] = {}
    lock = threading.Lock()

    def on_pose(sample: Any) -> None:
        message = decode(zbytes(sample.payload), zbytes(sample.attachment), PoseEstimate)
        with lock:
            poses[message.seq] = message

    n = len(cube.images)
    fps = CUBE_FPS * rate
    with busy_loops(busy), LocalCluster(small_cluster(), out_dir / f"logs_{r}_{rate:g}x") as cluster:
        cluster.start_router()
        cluster.spawn(LOCALIZER, [
            "localizer", *cluster.transport_args(), "--node", "cube", "--uav", "uav0",
            "--model", str(cube_dir / "cube.cao"), "--calibration", str(calibration), "--mount", "camera",
            "--initial-pose", *(f"{v:.10g}" for v in (*rvec, *tvec)),
        ])  # fmt: skip
        cluster.wait_alive({LOCALIZER})
        with open_session(cluster.observer_transport()) as session:
            subscriber = session.declare_subscriber(keys.pose_pf_key("uav0"), on_pose)
            time.sleep(0.3)  # the observer's route
            camera = cluster.spawn("camera/cube/0", [
                "camera", *cluster.transport_args(), "--node", "cube", "--uav", "uav0",
                "--images", str(cube_dir / "cube"), "--calibration", str(calibration), "--fps", f"{fps:g}",
                "--wait-for", "localizer", "--no-sensors",
            ])  # fmt: skip
            camera.wait(60.0 + n / fps)
            deadline = time.monotonic() + 20.0  # the queued frames' poses
            while time.monotonic() < deadline and (n - 1) not in poses:
                time.sleep(0.1)
            counters = counters_of(session, LOCALIZER)
            subscriber.undeclare()
    measure = EdgeAlignment(cube.scene, cube.camera)
    aligned = {}
    for seq, pose in sorted(poses.items()):
        camera_pose = CameraPose(pose.p_world_body_m, matrix_from_quaternion(pose.q_world_body))
        aligned[seq] = measure(cube.images[seq], camera_pose)[0]
    got = sorted(aligned)
    first_tracked = next((s for s in got if poses[s].tracking_state == "tracking"), None)
    return {
        "start": r,
        "rate": rate,
        "fps": fps,
        "busy_loops": busy,
        "frames": n,
        "frames_with_pose": len(got),
        "first_pose_seq": got[0] if got else None,
        "first_missing_seq": next((s for s in range(n) if s not in aligned), None),
        "last_frame_has_pose": (n - 1) in aligned,
        "misaligned_frames": sum(a < ALIGNED_MIN for a in aligned.values()),
        "aligned_median": float(np.median(list(aligned.values()))) if aligned else 0.0,
        "first_tracked_seq": first_tracked,
        "held": bool(aligned) and (n - 1) in aligned and all(a >= ALIGNED_MIN for a in aligned.values()),
        "dropped_frames": counters.get("dropped_frames", 0),
        "backlog_overflow": counters.get("backlog_overflow", 0),
        "catch_ups": counters.get("catch_ups", 0),
    }


def run_service(args: argparse.Namespace) -> dict[str, Any]:
    """The in-process runs, then one service run per start and ``--rates`` factor; a held verdict is every
    frame aligned (and, through the services, a pose for the last frame)."""
    out_dir = Path(args.out) / "localizer_service"
    reference = [
        row["misaligned_frames"] == 0 for row in cube_runs(args.cube_dir, runs=args.starts)["per_run"]
    ]
    cube = load_cube(args.cube_dir)  # read once: every run replays the same video
    runs = [
        service_run(args.cube_dir, cube, out_dir, rate, args.busy, r)
        for r in range(args.starts)
        for rate in args.rates
    ]
    for row in runs:
        row["in_process_held"] = reference[row["start"]]
        logger.info("cube through the services: %s", row)
    return {
        "bench_name": "localizer_service",
        "in_process_held": sum(reference),
        "starts": args.starts,
        "runs": runs,
        "same_verdicts": all(r["held"] == r["in_process_held"] for r in runs),
        "table": [{k: v for k, v in r.items() if k not in ("fps",)} for r in runs],
    }
