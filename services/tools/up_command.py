"""``capataz up``: start a described cluster locally, watch its yaw, and summarise every member at the end.

It fails at once when its router cannot listen (the port is taken), starts the camera unless ``--no-camera``,
and ends when the camera's flight ends (``--duration`` seconds, or ``--duration 0`` for until ^C). The final
table gives each member's start-up time, inputs, dropped frames, refused inputs and exit code.
"""

from __future__ import annotations

import argparse
import shlex
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from common.datasets.images import open_image_folder
from services.camera.settings import CameraSettings
from services.runtime.options import add_options
from services.runtime.transport import open_session
from services.runtime.usage import number_in
from services.tools.cluster_file import ClusterSpec, load_cluster
from services.tools.compose import compose_from_cluster
from services.tools.observe import StatsWatch, YawCollector, member_rows
from services.tools.report import print_table
from services.tools.secure import add_profile_arguments, profile_of
from services.tools.up import LocalCluster


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "up", help="start a described cluster locally as processes (router, camera, master, foremen, workers)"
    )
    parser.add_argument(
        "--cluster", type=Path, required=True, help="cluster file, e.g. deploy/clusters/2h8n.yml"
    )
    parser.add_argument(
        "--port", type=number_in(int, 0, 65535), default=7447, help="router port on 127.0.0.1 (0 = any free)"
    )
    parser.add_argument(
        "--camera",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also run the camera (uav stream)",
    )
    parser.add_argument(
        "--frames", type=number_in(int, 2), default=2041, help="frames of the camera's simulated flight"
    )
    parser.add_argument(
        "--fps",
        type=number_in(float, 0.0),
        default=20.0,
        help="camera frames per second (0 = as fast as possible)",
    )
    parser.add_argument(
        "--in-flight",
        type=number_in(int, 0),
        default=0,
        help="camera: max frames without a yaw (0 = free running)",
    )
    parser.add_argument(
        "--duration",
        type=number_in(float, 0.0),
        default=None,
        help="stop after this many seconds; 0 = run until interrupted (^C); "
        "default: when the camera's flight ends (until ^C without a camera)",
    )
    parser.add_argument("--logs", type=Path, default=Path("out/up"), help="log folder")
    parser.add_argument("--shm", action="store_true", help="zenoh shared memory on")
    parser.add_argument("--compose", type=Path, help="write the cluster as a docker-compose file and exit")
    parser.add_argument(
        "--publish-address",
        default="127.0.0.1",
        help="with --compose: host address the router's port is published on (0.0.0.0 = every interface)",
    )
    parser.add_argument(
        "--images", type=Path, help="run the camera on this image folder (checked before start)"
    )
    parser.add_argument(
        "--stamps", type=Path, help="per-image stamps of --images (index,stamp CSV or data.csv)"
    )
    parser.add_argument("--calibration", type=Path, help="camera calibration file for --images")
    add_options(parser, CameraSettings, ("frame_codec", "jpeg_quality"))  # the camera's, passed on
    parser.add_argument(
        "--master-args",
        default="",
        help='extra master options (yaw settings), e.g. "--grid 8x5 --patch-size 32"',
    )
    add_profile_arguments(parser, secure_by_default=True)
    parser.set_defaults(handler=run)


def write_compose(
    spec: ClusterSpec, path: Path, publish_address: str, camera_args: Sequence[str] = ()
) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    document = compose_from_cluster(
        spec, compose_dir=path.parent, publish_address=publish_address, camera_args=camera_args
    )
    path.write_text(
        f"# capataz up --cluster ... --compose: cluster {spec.name}\n"
        + yaml.safe_dump(document, sort_keys=False)
    )
    return path


def frame_codec_args(args: argparse.Namespace) -> list[str]:
    """The camera's ``--frame-codec`` (and ``--jpeg-quality``) options as given (none for mono8), checked
    here by the camera's settings (one error line before any process starts)."""
    camera = CameraSettings(frame_codec=args.frame_codec, jpeg_quality=args.jpeg_quality)
    if camera.frame_codec == "mono8":
        return []
    quality = ["--jpeg-quality", str(camera.jpeg_quality)] if camera.frame_codec == "jpeg" else []
    return ["--frame-codec", camera.frame_codec, *quality]


def run(args: argparse.Namespace) -> int:
    spec = load_cluster(args.cluster)
    camera_args = ["--frames", str(args.frames)]
    frames = args.frames
    if args.images is not None:  # refused here, in one line, before any process starts
        frames = len(open_image_folder(args.images, args.stamps, fps=args.fps))
        camera_args = ["--images", str(args.images)]
        camera_args += ["--stamps", str(args.stamps)] if args.stamps else []
        camera_args += ["--calibration", str(args.calibration)] if args.calibration else []
    codec_args = frame_codec_args(args)
    camera_args += codec_args
    if args.compose:
        print(f"wrote {write_compose(spec, args.compose, args.publish_address, codec_args)}")
        return 0
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        secure = profile_of(args, (spec.uav,), tuple(h.name for h in spec.hosts))
        with LocalCluster(
            spec,
            args.logs,
            port=args.port or None,
            shared_memory=args.shm,
            master_args=shlex.split(args.master_args),
            secure=secure,
            zenoh_config=args.zenoh_config,
        ) as cluster:
            t0 = time.monotonic()
            cluster.start()
            alive_after_s = cluster.wait_alive(cluster.expected_members())
            print(
                f"cluster {spec.name} up in {time.monotonic() - t0:.1f} s: router {cluster.router}, "
                f"{len(spec.hosts)} hosts, {spec.n_workers} workers, logs in {args.logs}"
            )
            with open_session(cluster.observer_transport()) as session:
                collector, watch = YawCollector(session, spec.uav), StatsWatch(session)
                camera = None
                if args.camera or args.images is not None:
                    camera = cluster.start_camera(
                        [
                            *camera_args,
                            "--fps",
                            str(args.fps),
                            "--in-flight",
                            str(args.in_flight),
                        ]
                    )
                    alive_after_s.update(cluster.wait_alive({camera}))
                watch_until_done(cluster, collector, stop, args.duration, camera, t0, frames)
                stats = watch.snapshot()
                collector.close()
                watch.close()
            codes = cluster.stop()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    print(f"received {len(collector.estimates)} yaw estimates")
    newest = collector.estimates.get(collector.newest())
    if newest is not None:
        print(f"master: {newest.dropped_frames} of {newest.seq + 1} frames dropped (latest-wins hand-off)")
    names = sorted(cluster.processes, key=lambda n: (n.split("/")[0] != "router", n))
    print_table(
        member_rows(names, alive_after_s, stats, codes), title="members (counters as of their last stats)"
    )
    return 0


def watch_until_done(
    cluster: LocalCluster,
    collector: YawCollector,
    stop: threading.Event,
    duration_s: float | None,
    camera: str | None,
    t0: float,
    frames: int,
) -> None:
    """Print each new yaw once a second until ^C, ``duration_s`` (0 = no limit) or the camera's end."""
    last = -1
    camera_done_logged = False
    while not stop.wait(1.0):
        newest = collector.newest()
        if newest != last:
            estimate = collector.estimates[newest]
            # one write a line: a client printing to the same terminal never lands inside it
            sys.stdout.write(
                f"yaw frame {newest}: {estimate.yaw_rad:+.4f} rad, "
                f"{estimate.timings_ms.get('total', 0.0):.1f} ms, members {estimate.members}\n"
            )
            sys.stdout.flush()
            last = newest
        if duration_s and time.monotonic() - t0 > duration_s:
            return
        if camera is not None and cluster.processes[camera].poll() is not None and not camera_done_logged:
            if duration_s is None:
                collector.wait_for(frames, 5.0)  # the yaw of the last frames (bounded)
                return
            print("camera finished its flight; the cluster stays up (^C to stop)")
            camera_done_logged = True
