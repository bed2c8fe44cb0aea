"""Scene model: the built-in office, the JSON format, derived edges and validation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from common.localization.model import (
    SceneModel,
    SceneModelError,
    build_scene,
    scene_from_json,
    scene_to_dict,
)


def test_default_scene_has_a_few_hundred_edges_with_unit_normals(office: SceneModel) -> None:
    assert 200 <= office.n_edges <= 400
    assert np.allclose(np.linalg.norm(office.face_normals, axis=1), 1.0)
    # every face lies on its plane
    for f in range(office.n_faces):
        assert np.allclose(office.face_polygon_world_m(f) @ office.face_normals[f], office.face_offsets_m[f])
    # adjacent faces exist and are valid indices
    assert np.all(office.edge_faces[:, 0] >= 0)
    assert np.all(office.edge_faces < office.n_faces)


def test_floor_faces_up_and_walls_face_the_room(office: SceneModel) -> None:
    centre = np.array([5.0, 4.0, 1.5])
    # the camera inside the room sees the front of every room face
    signed = office.face_normals @ centre - office.face_offsets_m
    assert np.all(signed[:6] > 0.0)
    assert np.allclose(office.face_normals[0], [0.0, 0.0, 1.0])


def test_json_round_trip_keeps_faces_and_edges(office: SceneModel) -> None:
    again = scene_from_json(json.dumps(scene_to_dict(office)))
    assert again.name == office.name
    assert again.n_edges == office.n_edges
    assert np.allclose(again.edges_world_m, office.edges_world_m)
    assert np.array_equal(again.edge_faces, office.edge_faces)


def test_side_between_coplanar_faces_of_equal_albedo_is_dropped() -> None:
    vertices = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]]
    same = build_scene(vertices, [[0, 1, 2, 3], [1, 4, 5, 2]], [0.5, 0.5])
    other = build_scene(vertices, [[0, 1, 2, 3], [1, 4, 5, 2]], [0.5, 0.9])
    assert same.n_edges == 6
    assert other.n_edges == 7
    shared = [i for i in range(other.n_edges) if other.edge_faces[i, 1] >= 0]
    assert len(shared) == 1
    assert sorted(other.edge_faces[shared[0]].tolist()) == [0, 1]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("not json", "not valid JSON"),
        ('{"faces": []}', "lacks the key"),
        ('{"vertices": [[0,0,0],[1,0,0],[0,1,0]], "faces": [{"vertices": [0, 1, 7]}]}', "vertex indices"),
        (
            '{"vertices": [[0,0,0],[1,0,0],[0,1,0]], "faces": [{"vertices": [0, 1, 2], "albedo": 3}]}',
            "albedo",
        ),
        ('{"vertices": [[0,0,0],[1,0,0],[1,1,1],[0,1,0]], "faces": [{"vertices": [0, 1, 2, 3]}]}', "planar"),
        ('{"vertices": [[0,0,0],[1,0,0],[2,0,0]], "faces": [{"vertices": [0, 1, 2]}]}', "degenerate"),
        ('{"vertices": [[0,0],[1,0],[2,0]], "faces": []}', "shape"),
    ],
)
def test_malformed_scene_files_are_refused_with_a_reason(text: str, message: str) -> None:
    with pytest.raises(SceneModelError, match=message):
        scene_from_json(text)


def test_json_schema_lines_groups_and_errors_naming_the_place() -> None:
    from common.localization.model import scene_from_json

    text = json.dumps(
        {
            "name": "wedge",
            "vertices": [
                [0, 0, 0],
                [1, 0, 0],
                [1, 0, 1],
                [0, 0, 1],
                [1, 1, 0],
                [0, 1, 0],
                [0, 0, 2],
                [1, 0, 2],
            ],
            "faces": [{"vertices": [0, 1, 2, 3], "group": 4}, {"vertices": [1, 4, 5, 0], "group": 4}],
            "lines": [[6, 7]],
            "crease_angle_deg": 10.0,
        }
    )
    scene = scene_from_json(text)
    shared = [i for i in range(scene.n_edges) if scene.edge_faces[i, 1] >= 0]
    assert len(shared) == 1 and scene.edge_smooth[shared[0]]  # same group: smooth despite 90 deg
    standalone = np.flatnonzero(scene.edge_faces[:, 0] < 0)
    assert len(standalone) == 1 and np.allclose(scene.edges_world_m[standalone[0]][:, 2], 2.0)
    with pytest.raises(SceneModelError, match="line 2"):
        scene_from_json('{"vertices": [\n  [0, 0, x]]}')
    with pytest.raises(SceneModelError, match="unknown key"):
        scene_from_json('{"vertices": [[0, 0, 0]], "lnes": []}')
    with pytest.raises(SceneModelError, match="line 0"):
        scene_from_json('{"vertices": [[0, 0, 0], [1, 1, 1]], "lines": [[0, 0]]}')


def test_non_convex_face_is_triangulated_without_inner_edges() -> None:
    # a U-shaped outline: 8 corners -> 6 triangles, only the 8 outline sides remain edges
    u = [[0, 0, 0], [3, 0, 0], [3, 3, 0], [2, 3, 0], [2, 1, 0], [1, 1, 0], [1, 3, 0], [0, 3, 0]]
    scene = build_scene(u, [list(range(8))], [0.5])
    assert scene.n_faces == 6 and scene.n_edges == 8
    area = sum(
        0.5
        * np.linalg.norm(np.cross(*(scene.face_polygon_world_m(f)[1:] - scene.face_polygon_world_m(f)[0])))
        for f in range(scene.n_faces)
    )
    assert area == pytest.approx(9.0 - 2.0)
