"""Hidden-line removal: edges behind the model's own faces are not scored."""

from __future__ import annotations

import numpy as np

from common.camera import CameraModel
from common.localization.model import build_scene
from common.localization.pose import CameraPose
from common.localization.projection import project_posed_samples, sample_edges
from common.localization.visibility import visible_points

#: camera at y = -1 looking along +y (x right, z up in the world -> image y down)
R_WORLD_CAMERA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _wall_with_hidden_card() -> object:
    """A 1 m wall at y = 0 facing the camera, and a 0.2 m card 0.5 m behind it (also facing the camera):
    the card's four edges are hidden by the wall; a post beside the wall keeps its edges in view."""
    wall = [[-0.5, 0, -0.5], [0.5, 0, -0.5], [0.5, 0, 0.5], [-0.5, 0, 0.5]]
    card = [[-0.1, 0.5, -0.1], [0.1, 0.5, -0.1], [0.1, 0.5, 0.1], [-0.1, 0.5, 0.1]]
    post = [[0.8, 0.5, -0.1], [0.9, 0.5, -0.1], [0.9, 0.5, 0.1], [0.8, 0.5, 0.1]]
    vertices = wall + card + post
    faces = [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]  # counter-clockwise seen from -y
    return build_scene(vertices, faces, [0.5, 0.8, 0.2])


def test_a_face_hides_the_edges_behind_it() -> None:
    scene = _wall_with_hidden_card()
    camera = CameraModel.from_hfov(320, 240, 90.0)
    pose = CameraPose(np.array([0.0, -1.0, 0.0]), R_WORLD_CAMERA)
    samples = sample_edges(scene, 6)
    visible = visible_points(
        scene, samples.points_world_m, pose.R_camera_world, pose.p_world_camera_m, camera
    )
    centres = samples.centres_world_m
    card = np.abs(centres[:, 1] - 0.5) < 1e-9
    card &= np.abs(centres[:, 0]) < 0.2
    post = centres[:, 0] > 0.7
    wall = np.abs(centres[:, 1]) < 1e-9
    assert card.sum() == 4 and post.sum() == 4 and wall.sum() == 4
    assert not visible[card].any(), "the card's edges lie behind the wall"
    assert visible[wall].all() and visible[post].all()
    # the projection drops exactly the hidden points; without the mask they would be scored
    args = (samples, pose.R_camera_world[None], pose.p_world_camera_m[None], camera)
    plain = project_posed_samples(*args)
    masked = project_posed_samples(*args, visible=visible)
    card_kept = np.isin(plain.edge_ids, np.flatnonzero(card))
    assert plain.valid[0][card_kept].all()
    assert not masked.valid[0][card_kept].any()
    assert np.array_equal(masked.valid[0][~card_kept], plain.valid[0][~card_kept])


def test_seen_from_the_side_the_card_reappears() -> None:
    scene = _wall_with_hidden_card()
    camera = CameraModel.from_hfov(320, 240, 90.0)
    # between the wall and the card, looking along +y: nothing hides the card any more
    pose = CameraPose(np.array([0.0, 0.2, 1.0]), R_WORLD_CAMERA)
    samples = sample_edges(scene, 6)
    visible = visible_points(
        scene, samples.points_world_m, pose.R_camera_world, pose.p_world_camera_m, camera
    )
    assert visible.all()
