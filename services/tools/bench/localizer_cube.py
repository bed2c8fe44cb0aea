"""``capataz bench localizer --suite defaults``, the real part: ViSP's hand-held cube video with defaults.

Data: ``--cube-dir`` (default ``../shared/data/visp_cube``; see its README): 218 frames of an 8.4 cm cube,
the model ``cube.cao``, the intrinsics in ``cube.xml``, the start ``cube.0.pos`` (ViSP's cMo: translation,
then theta-u). No stamps come with the frames: they are taken at ``CUBE_FPS``.

Runs: ``runs - 9`` from ``cube.0.pos`` (own filter seeds; at least one) and 9 from starts 5 mm / 2 deg off
it (random directions, by seed), default tracker settings only. No ground truth after frame 0, so every
frame is judged by an **edge-alignment measure** of this module, not the tracker's own: the model's
visible outline (20 points per edge, hidden lines removed) is projected at the estimate, and for every point
the nearest image edge pixel along the projected normal whose gradient lies within 20 deg of that normal
(either polarity) is looked up within 6 px in a Canny map of its own thresholds (30/90). ``aligned`` is the
share of the points with such an edge within ``ALIGN_PX``; ``offset_px`` the median distance of the found
ones. A frame is **aligned** when ``aligned >= ALIGNED_MIN``; a run is **held** when every frame is aligned
and its final pose agrees with the run nearest the runs' median final position (the same cube, the same
camera: the runs that hold converge on one pose) as far as the image tells: the model's outline projected
from both within ``ALIGN_PX`` (root median square). Stricter, ``held_within_mm_deg``: within ``AGREE_MM`` /
``AGREE_DEG`` of it (a depth difference of 1-2 % of the distance hardly moves a small model's outline).
Overlays (the projected model on the frame) of the first run at frames 0, 50, 100, 150, 190, 217:
``<out>/localizer_cube_<frame>.png``, and the six at half size on one sheet,
``<out>/localizer_cube_overlays.png`` (the README's picture).
"""

from __future__ import annotations

import logging
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.camera import CameraModel
from common.datasets.models import load_model
from common.errors import CapatazError
from common.localization.model import SceneModel
from common.localization.pose import CameraPose, rotation_angle_rad
from common.localization.process_noise import residual_px
from common.localization.projection import ProjectedSamples, project_pose_samples, sample_edges
from common.localization.refine import oriented_offsets
from common.localization.scoring import extract_image_edges
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings, TrackingStatus
from common.localization.tracking import track_model
from common.localization.visibility import visible_points
from common.sim.objects import offset_pose

logger = logging.getLogger(__name__)

#: frame rate assumed for the stamps (the video comes without them; ViSP grabs at about 30 Hz)
CUBE_FPS = 30.0
#: start offsets of the perturbed runs
START_OFFSET_MM, START_OFFSET_DEG = 5.0, 2.0
#: a frame is aligned when this share of the outline has an oriented image edge within ALIGN_PX
ALIGNED_MIN = 0.5
ALIGN_PX = 1.5
#: a held run's final pose lies this close to the runs' median final pose
AGREE_MM, AGREE_DEG = 10.0, 3.0
OVERLAY_FRAMES = (0, 50, 100, 150, 190, 217)


@dataclass(frozen=True)
class Cube:
    scene: SceneModel
    camera: CameraModel
    images: list[np.ndarray]
    start: CameraPose


def load_cube(directory: Path) -> Cube:
    """The cube's model, camera, frames and start pose; one clear error when something is missing."""
    try:
        scene = load_model(directory / "cube.cao")
        cam = ET.parse(directory / "cube.xml").getroot().find("camera")
        if cam is None:
            raise CapatazError(f"{directory / 'cube.xml'}: no <camera>")
        value = {k: float(cam.findtext(k) or "nan") for k in ("px", "py", "u0", "v0")}
        numbers = [float(x) for x in (directory / "cube.0.pos").read_text().split()[:6]]
        files = sorted((directory / "cube").glob("image*.pgm"))
    except (OSError, ET.ParseError, ValueError) as exc:
        raise CapatazError(f"cannot read the cube data in {directory}: {exc}") from None
    read = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files]
    images = [np.asarray(i) for i in read if i is not None]
    if not images or len(images) != len(read) or len(numbers) != 6:
        raise CapatazError(f"{directory}: expected cube/image*.pgm and 6 numbers in cube.0.pos")
    h, w = images[0].shape
    camera = CameraModel(w, h, value["px"], value["py"], value["u0"], value["v0"])
    start = CameraPose.from_rvec_tvec(numbers[3:], numbers[:3])  # cMo: t first, then theta-u
    return Cube(scene, camera, images, start)


class EdgeAlignment:
    """The per-frame measure of the module docstring (its own Canny and sampling, not the tracker's)."""

    def __init__(self, scene: SceneModel, camera: CameraModel) -> None:
        self.scene, self.camera = scene, camera
        self.samples = sample_edges(scene, 20)

    def project(self, pose: CameraPose, with_normals: bool = False) -> ProjectedSamples:
        """The model's sample points seen from ``pose`` (hidden ones removed): one pose, particle axis 1."""
        visible = visible_points(
            self.scene, self.samples.points_world_m, pose.R_camera_world, pose.p_world_camera_m, self.camera
        )
        return project_pose_samples(
            self.samples,
            pose.R_camera_world,
            pose.p_world_camera_m,
            self.camera,
            with_normals=with_normals,
            visible=visible,
        )

    def __call__(self, image: np.ndarray, pose: CameraPose) -> tuple[float, float]:
        edges = extract_image_edges(image, canny_low=30, canny_high=90, with_gradients=True)
        proj = self.project(pose, with_normals=True)
        valid = proj.valid[0]
        if valid.sum() < 10:
            return 0.0, float("inf")
        assert proj.normal_u is not None and proj.normal_v is not None
        d = oriented_offsets(
            proj.u_px[0][valid].astype(np.float64),
            proj.v_px[0][valid].astype(np.float64),
            proj.normal_u[0][valid].astype(np.float64),
            proj.normal_v[0][valid].astype(np.float64),
            edges,
            6,
            float(np.cos(np.radians(20.0))),
        )
        found = np.abs(d[np.isfinite(d)])
        aligned = float(np.mean(np.abs(np.nan_to_num(d, nan=np.inf)) <= ALIGN_PX))
        return aligned, float(np.median(found)) if found.size else float("inf")


def overlay(image: np.ndarray, samples_px: tuple[np.ndarray, np.ndarray], path: Path) -> None:
    rgb = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    for u, v in zip(*samples_px, strict=True):
        cv2.circle(rgb, (int(u + 0.5), int(v + 0.5)), 1, (0, 0, 255), -1)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), rgb)


def overlay_sheet(paths: list[Path], out_path: Path, columns: int = 3) -> Path:
    """The overlays ``paths`` (one frame each, named ``..._<frame>.png``) at half size on one sheet,
    ``columns`` across, each labelled with its frame number (the README's picture of the cube run)."""
    tiles = []
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise CapatazError(f"{path}: not an image")
        tile = cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2), interpolation=cv2.INTER_AREA)
        label = f"frame {int(path.stem.rsplit('_', 1)[-1])}"
        cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    if not tiles:
        raise CapatazError("no overlays to put on a sheet")
    blank = np.zeros_like(tiles[0])
    rows = [tiles[i : i + columns] for i in range(0, len(tiles), columns)]
    rows[-1] = rows[-1] + [blank] * (columns - len(rows[-1]))
    sheet = np.vstack([np.hstack(row) for row in rows])
    out_path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out_path), sheet)
    return out_path


def cube_runs(
    directory: Path, runs: int = 12, config: TrackerSettings | None = None, out_dir: Path | None = None
) -> dict[str, Any]:
    """The cube suite: ``runs`` runs (see the module docstring), per run the alignment per frame."""
    cube = load_cube(directory)
    tracker = ModelTracker(cube.scene, cube.camera, config or TrackerSettings())
    measure = EdgeAlignment(cube.scene, cube.camera)
    times_s = np.arange(len(cube.images)) / CUBE_FPS
    rows: list[dict[str, Any]] = []
    finals = []
    exact = max(1, runs - 9)
    for r in range(runs):
        offset = (1e-3 * START_OFFSET_MM, float(np.radians(START_OFFSET_DEG)))
        start = cube.start if r < exact else offset_pose(cube.start, *offset, 60_000 + r)
        rng = np.random.default_rng(70_000 + r)
        aligned: list[float] = []
        offsets: list[float] = []
        ms: list[float] = []
        statuses: list[str] = []
        c0 = time.process_time()
        for i, state in enumerate(track_model(tracker, cube.images, times_s, tracker.start(start), rng)):
            ms.append((time.process_time() - c0) * 1e3)
            a, off = measure(cube.images[i], state.pose)
            aligned.append(a)
            offsets.append(off)
            statuses.append(state.status.value)
            if r == 0 and out_dir is not None and i in OVERLAY_FRAMES:
                _overlay_frame(measure, cube, state.pose, i, out_dir)
            c0 = time.process_time()
        finals.append(state.pose)
        if r == 0 and out_dir is not None:
            frames = [out_dir / f"localizer_cube_{i:03d}.png" for i in OVERLAY_FRAMES if i < len(cube.images)]
            overlay_sheet(frames, out_dir / "localizer_cube_overlays.png")
        bad = [i for i, a in enumerate(aligned) if a < ALIGNED_MIN]
        rows.append(
            {
                "start": "cube.0.pos" if r < exact else f"{START_OFFSET_MM} mm / {START_OFFSET_DEG} deg off",
                "aligned_median": float(np.median(aligned)),
                "aligned_min": float(np.min(aligned)),
                "offset_px_median": float(np.median(offsets)),
                "misaligned_frames": len(bad),
                "first_misaligned_frame": bad[0] if bad else None,
                "tracking_while_misaligned": sum(statuses[i] == TrackingStatus.TRACKING.value for i in bad),
                "not_tracking_while_aligned": sum(
                    s != TrackingStatus.TRACKING.value and a >= ALIGNED_MIN
                    for s, a in zip(statuses, aligned, strict=True)
                ),
                "final_status": statuses[-1],
                "step_ms_median": float(np.median(ms[1:])),
                "first_step_ms": ms[0],
                "aligned_per_frame": [round(a, 3) for a in aligned],
            }
        )
        logger.info("cube run %d: %s", r, {k: v for k, v in rows[-1].items() if k != "aligned_per_frame"})
    centre = np.median([p.p_world_camera_m for p in finals], axis=0)
    ref = finals[int(np.argmin([np.linalg.norm(p.p_world_camera_m - centre) for p in finals]))]
    points = measure.samples.points_world_m.reshape(-1, 3)
    for row, pose in zip(rows, finals, strict=True):
        row["final_off_median_mm"] = 1e3 * float(np.linalg.norm(pose.p_world_camera_m - centre))
        row["final_off_median_deg"] = float(
            np.degrees(rotation_angle_rad(pose.R_world_camera, ref.R_world_camera))
        )
        # the same final pose as far as the image can tell: the outlines within ALIGN_PX
        row["final_outline_off_px"] = residual_px(ref, pose, points, cube.camera)
        row["held"] = bool(row["misaligned_frames"] == 0 and row["final_outline_off_px"] <= ALIGN_PX)
        row["held_within_mm_deg"] = bool(
            row["misaligned_frames"] == 0
            and row["final_off_median_mm"] <= AGREE_MM
            and row["final_off_median_deg"] <= AGREE_DEG
        )
    return {
        "frames": len(cube.images),
        "fps_assumed": CUBE_FPS,
        "held_runs": sum(r["held"] for r in rows),
        "held_runs_within_mm_deg": sum(r["held_within_mm_deg"] for r in rows),
        "runs": runs,
        "aligned_min_share": ALIGNED_MIN,
        "align_px": ALIGN_PX,
        "per_run": rows,
    }


def _overlay_frame(measure: EdgeAlignment, cube: Cube, pose: CameraPose, i: int, out_dir: Path) -> None:
    proj = measure.project(pose)  # the measure's scene and camera are the cube's
    valid = proj.valid[0]
    path = out_dir / f"localizer_cube_{i:03d}.png"
    overlay(cube.images[i], (proj.u_px[0][valid], proj.v_px[0][valid]), path)
