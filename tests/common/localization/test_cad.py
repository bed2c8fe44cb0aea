"""OBJ and ViSP .cao import: every construct, and bad files refused with one line naming the line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.datasets.models import ModelFileError, load_model
from common.localization.cad import ROUND_SEGMENTS, CadError, scene_from_cao, scene_from_obj
from common.localization.model import SceneModelError

CUBE_POINTS = """0 0 0
0 0 -0.08
0.165 0 -0.08
0.165 0 0
0.165 0.068 0
0.165 0.068 -0.08
0 0.068 -0.08
0 0.068 0
"""
CUBE_FACES = """4 0 1 2 3 name=front
4 1 6 5 2
4 4 5 6 7
4 0 3 4 7
4 5 4 3 2
4 0 7 6 1
"""
#: a box (faces from points), a standalone line, a face from lines, a cylinder and a circle
FULL_CAO = f"""V1
# 3D Points
12                  # number of points
{CUBE_POINTS}0.3 0 0
0.4 0 0
0.4 0.1 0
0.5 0.5 0.5
# 3D Lines
4
8 9 name=l0
9 10
10 8
0 11
# Faces from 3D lines
1
3 0 1 2
# Faces from 3D points
6
{CUBE_FACES}# 3D cylinders
1
8 11 0.02
# 3D circles
1
0.03 9 10 8
"""


def _edge_set(scene: object) -> set[tuple[tuple[float, ...], tuple[float, ...]]]:
    edges = scene.edges_world_m
    out = set()
    for a, b in np.round(edges, 6):
        key = (tuple(a.tolist()), tuple(b.tolist()))
        out.add(min(key, key[::-1]))
    return out


def test_cao_every_construct() -> None:
    scene = scene_from_cao(FULL_CAO)
    box_edges = 12
    triangle_edges = 3
    standalone_line = 1  # 0 -> 11
    cylinder = 3 * ROUND_SEGMENTS  # smooth sides + two rims
    circle = ROUND_SEGMENTS
    assert scene.n_edges == box_edges + triangle_edges + standalone_line + cylinder + circle
    assert int(scene.edge_smooth.sum()) == ROUND_SEGMENTS  # cylinder sides: limbs only
    assert int(np.sum(scene.edge_faces[:, 0] < 0)) == standalone_line + circle
    # box faces are counter-clockwise from outside: every normal points away from the box centre
    centre = np.array([0.0825, 0.034, -0.04])
    for f in range(6):
        polygon = scene.face_polygon_world_m(f)
        assert scene.face_normals[f] @ (polygon.mean(axis=0) - centre) > 0.0
    # the circle's segments lie at its radius around point 9, in the plane of points 9, 10, 8 (z = 0)
    circle_edges = scene.edges_world_m[scene.edge_faces[:, 0] < 0]
    radii = np.linalg.norm(circle_edges.reshape(-1, 3) - [0.4, 0.0, 0.0], axis=1)
    on_circle = np.isclose(radii, 0.03)
    assert on_circle.sum() == 2 * ROUND_SEGMENTS
    assert np.allclose(circle_edges.reshape(-1, 3)[on_circle, 2], 0.0)


def test_cao_load_sub_part_with_transform(tmp_path: Path) -> None:
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "plate.cao").write_text(
        "V1\n4\n0 0 0\n0.1 0 0\n0.1 0.1 0\n0 0.1 0\n0\n0\n1\n4 0 1 2 3\n"
    )
    top = 'V1\nload("parts/plate.cao", t=[1.0, 2.0, 3.0], tu=[0.0, 0.0, 1.5707963267948966])\n1\n0 0 0\n'
    (tmp_path / "top.cao").write_text(top)
    scene = load_model(tmp_path / "top.cao")
    corners = {tuple(np.round(p, 6).tolist()) for p in scene.edges_world_m.reshape(-1, 3)}
    # plate corner (0.1, 0, 0) turned 90 deg about z -> (0, 0.1, 0), then shifted by t
    assert (1.0, 2.1, 3.0) in corners
    assert (0.9, 2.1, 3.0) in corners
    assert scene.n_faces == 1


def test_cao_load_cycle_is_refused(tmp_path: Path) -> None:
    (tmp_path / "a.cao").write_text('V1\nload("a.cao")\n0\n')
    with pytest.raises(CadError, match="nested deeper"):
        load_model(tmp_path / "a.cao")


OBJ = """# an L-shaped plate (non-convex face) with a wire
o part
v 0 0 0
v 0.2 0 0
v 0.2 0.1 0
v 0.1 0.1 0
v 0.1 0.2 0
v 0 0.2 0
vt 0 0
vn 0 0 1
f 1/1/1 2/1/1 3/1/1 4//1 5 6
v 0 0 0.1
l 1 -1
"""


def test_obj_non_convex_face_is_triangulated_and_lines_kept() -> None:
    scene = scene_from_obj(OBJ)
    assert scene.n_faces == 4  # 6 corners -> 4 triangles
    # only the outline and the wire are edges: inner diagonals join coplanar triangles
    assert scene.n_edges == 6 + 1
    assert np.allclose(scene.face_normals, [0.0, 0.0, 1.0])
    areas = sum(
        0.5
        * np.linalg.norm(np.cross(*(scene.face_polygon_world_m(f)[1:] - scene.face_polygon_world_m(f)[0])))
        for f in range(scene.n_faces)
    )
    assert np.isclose(areas, 0.2 * 0.1 + 0.1 * 0.1)


def test_obj_smooth_tessellation_keeps_only_creases() -> None:
    # a 12-sided prism: sides meet at 30 deg... use 16 sides (22.5 deg, below the crease angle)
    n = 16
    angles = np.arange(n) * 2 * np.pi / n
    lines = [f"v {np.cos(a):.6f} {np.sin(a):.6f} 0" for a in angles]
    lines += [f"v {np.cos(a):.6f} {np.sin(a):.6f} 1" for a in angles]
    lines += [f"f {i + 1} {(i + 1) % n + 1} {(i + 1) % n + n + 1} {i + n + 1}" for i in range(n)]
    scene = scene_from_obj("\n".join(lines))
    assert int(scene.edge_smooth.sum()) == n
    assert scene.n_edges == 3 * n


#: the readers by format (the ``<format>`` an error names)
READERS = {"cao": scene_from_cao, "obj": scene_from_obj}


@pytest.mark.parametrize(
    ("fmt", "text", "line", "message"),
    [
        ("cao", "V2\n0\n", 1, "starts with 'V1'"),
        ("cao", "V1\n2\n0 0 0\n1 1\n", 4, "3 numbers"),
        ("cao", "V1\n2\n0 0 0\n1 1 x\n", 4, "not a number"),
        ("cao", "V1\n1\n0 0 0\n1\n0 5\n", 5, "out of range"),
        ("cao", "V1\n3\n0 0 0\n1 0 0\n0 1 0\n0\n0\n1\n4 0 1 2\n", 9, "announces 4"),
        ("cao", "V1\n3\n0 0 0\n1 0 0\n0 1 0\n2\n0 1\n1 2\n1\n2 0 1\n", 10, "announces 2"),
        ("cao", "V1\n3\n0 0 0\n1 0 0\n0 1 0\n0\n0\n0\n1\n0 1 -0.1\n", 10, "radius must be positive"),
        ("cao", "V1\n3\n0 0 0\n1 0 0\n2 0 0\n0\n0\n0\n0\n1\n0.1 0 1 2\n", 11, "collinear"),
        ("cao", "V1\n1\n0 0 0\nthree\n", 4, "number of 3D lines"),
        ("cao", "V1\n2\n0 0 0\n", 3, "file ends"),
        ("cao", 'V1\nload("x.cao")\n', 2, "not available"),
        ("obj", "v 0 0\n", 1, "3 or 4 numbers"),
        ("obj", "v 0 0 0\nv 1 0 0\nf 1 2\n", 3, "at least 3"),
        ("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4, "out of range"),
        ("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", 4, "out of range"),
        ("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a\n", 4, "not a vertex index"),
        ("obj", "v 0 0 0\nv 1 0 0\ncurv 0 1 1 2\n", 3, "unknown OBJ statement"),
        ("obj", "v 0 0 nan\n", 1, "not finite"),
        ("obj", "v 0 0 0\nl 1\n", 2, "at least 2"),
    ],
)
def test_bad_file_names_its_format_and_line(fmt: str, text: str, line: int, message: str) -> None:
    with pytest.raises(CadError, match=rf"<{fmt}>:{line}: .*{message}"):
        READERS[fmt](text)


@pytest.mark.parametrize(
    ("fmt", "text", "error", "message"),
    [
        ("cao", "V1\n4\n0 0 0\n1 0 0\n1 1 0.5\n0 1 0\n0\n0\n1\n4 0 1 2 3\n", CadError, "not planar"),
        ("obj", "v 0 0 0\nv 1 1 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 4\n", SceneModelError, "face 0"),
    ],
)
def test_face_that_is_no_polygon_is_refused(
    fmt: str, text: str, error: type[Exception], message: str
) -> None:
    """A non-planar .cao face, a self-intersecting OBJ face."""
    with pytest.raises(error, match=message):
        READERS[fmt](text)


def test_load_model_by_suffix_and_bad_files(tmp_path: Path) -> None:
    obj = tmp_path / "part.obj"
    obj.write_text(OBJ)
    assert load_model(obj, scale=1000.0).size_m == pytest.approx(1000.0 * np.sqrt(0.2**2 + 0.2**2 + 0.1**2))
    with pytest.raises(ModelFileError, match="unknown format"):
        load_model(tmp_path / "part.stl")
    with pytest.raises(ModelFileError, match="not a file"):
        load_model(tmp_path / "missing.cao")
    binary = tmp_path / "binary.cao"
    binary.write_bytes(b"\xff\xfe\x00V1")
    with pytest.raises(ModelFileError, match="not text"):
        load_model(binary)
    broken = tmp_path / "broken.json"
    broken.write_text('{"vertices": [[0, 0, 0],\n  [1, 0')
    with pytest.raises(ModelFileError, match="line 2"):
        load_model(broken)
