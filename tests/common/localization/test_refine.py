"""Refinement from the motion model's prediction as well as the best particle, kept by the matched outline:
a texture trap (the model's outline painted smaller on its own face) fools the match fraction, not it."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from common.localization.pose import CameraPose
from common.localization.projection import project_pose_samples
from common.localization.refine import EdgeFit, RefineSettings, match_measures, refine_best
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerSettings
from common.sim.objects import object_camera, object_flight, tabletop_model, tabletop_scene
from common.sim.scene import render_view


@pytest.fixture(scope="module")
def tracker() -> ModelTracker:
    return ModelTracker(tabletop_model(), object_camera(), TrackerSettings())


def _trap_image(tracker: ModelTracker, truth: CameraPose, trap: CameraPose) -> np.ndarray:
    """The scene at ``truth`` with the model's visible edges at ``trap`` painted on it (texture)."""
    image = render_view(tabletop_scene(), truth.R_world_camera, truth.p_world_camera_m, tracker.camera)
    proj = project_pose_samples(
        tracker.samples,
        trap.R_camera_world,
        trap.p_world_camera_m,
        tracker.camera,
        visible=tracker._visible(trap),
    )
    out = image.copy()
    for e in range(proj.valid.shape[1]):
        ok = proj.valid[0, e]
        if ok.sum() < 2:
            continue
        pts = np.stack([proj.u_px[0, e][ok], proj.v_px[0, e][ok]], axis=1)
        step = (pts[-1] - pts[0]) / (len(pts) - 1)
        # texture: dashes over the sample points 0-1, 4-5 of each edge (half the edge, in spots)
        for first in range(0, len(pts), 4):
            a, b = pts[first] - step / 2, pts[min(first + 1, len(pts) - 1)] + step / 2
            cv2.line(out, (int(a[0] + 0.5), int(a[1] + 0.5)), (int(b[0] + 0.5), int(b[1] + 0.5)), 230, 2)
    return out


def test_refinement_from_the_prediction_beats_a_texture_trap(tracker: ModelTracker) -> None:
    truth = object_flight(2, seed=2).pose(0)
    # the trap: the camera 15 % farther back along its axis (the model drawn smaller, on its own face)
    axis = truth.R_world_camera[:, 2]
    distance = tracker.viewing_distance_m(truth)
    trap = CameraPose(truth.p_world_camera_m - 0.15 * distance * axis, truth.R_world_camera)
    image = _trap_image(tracker, truth, trap)
    params = replace(RefineSettings(), iterations=3, search_px=8)
    fit = EdgeFit(tracker.samples, tracker.camera, tracker.edges(image), params, tracker._visible(truth))
    prediction = CameraPose(truth.p_world_camera_m + np.array([0.002, -0.001, 0.001]), truth.R_world_camera)
    positions, rotations = trap.p_world_camera_m[None], trap.R_world_camera[None]
    # the best particle alone stays in the trap, and its match fraction does not tell
    alone, alone_pose = refine_best(fit, positions, rotations, np.zeros(1), 1)
    assert np.linalg.norm(alone_pose.p_world_camera_m - truth.p_world_camera_m) > 0.05 * distance
    at_truth, _, _ = match_measures(fit, truth.R_camera_world, truth.t_camera_world_m)
    assert alone.match_fraction >= at_truth - 0.1, "the trap should fool the fraction (test set-up)"
    # with the prediction refined too, the matched outline picks the pose at the truth
    both, pose = refine_best(fit, positions, rotations, np.zeros(1), 1, also=(prediction,))
    assert np.linalg.norm(pose.p_world_camera_m - truth.p_world_camera_m) < 0.005 * distance
    assert both.outline_px > alone.outline_px
