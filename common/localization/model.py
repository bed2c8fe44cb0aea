"""Known 3D model of an indoor environment: planar faces and the edges between them (paper B's "model").

File format (JSON, one object; units metres, ENU world, ground at ``z = 0``)::

    {
      "name": "office",
      "vertices": [[x, y, z], ...],
      "faces": [{"vertices": [i, j, k, ...], "albedo": 0.6}, ...]
    }

Each face is a planar convex polygon of at least 3 vertex indices, listed counter-clockwise when seen from
its visible side (right-hand rule: the normal points at the viewer). ``albedo`` in [0, 1] is the face's
brightness before shading. Edges are derived from the faces: every polygon side becomes an edge, sides
shared by several faces are merged, and a side between two coplanar faces of the same albedo is dropped
(it shows no contrast in an image). Every edge remembers up to two adjacent faces for back-face culling.

Decals (doors, windows, pictures) are faces a centimetre in front of a wall with another albedo.
:func:`default_scene` builds the built-in office (a room with doors, windows, pictures and furniture
boxes, about 280 edges).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.types import FloatArray

IntArray = npt.NDArray[np.int64]

#: Vertices closer than this are the same point when edges are merged (m).
_MERGE_TOLERANCE_M = 1e-6
#: A face whose vertices leave its plane by more than this is rejected (m).
_PLANARITY_TOLERANCE_M = 1e-3


class SceneModelError(InputError):
    """A scene description is malformed (shape, indices, non-planar face, albedo)."""


@dataclass(frozen=True)
class SceneModel:
    """Faces and edges of a static 3D scene in the world frame.

    ``faces`` holds each face's vertex indices; ``face_normals`` (F, 3) are unit normals towards the visible
    side and ``face_offsets_m`` (F,) the plane offsets (``n . x = d``). ``edges_world_m`` (E, 2, 3) are the
    edge end points; ``edge_faces`` (E, 2) the adjacent face indices (-1 where an edge has one face).
    """

    name: str
    vertices_world_m: FloatArray
    faces: tuple[tuple[int, ...], ...]
    face_albedo: FloatArray
    face_normals: FloatArray
    face_offsets_m: FloatArray
    edges_world_m: FloatArray
    edge_faces: IntArray

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def n_edges(self) -> int:
        return int(self.edges_world_m.shape[0])

    def face_polygon_world_m(self, face: int) -> FloatArray:
        """Vertices (K, 3) of one face, in order."""
        return self.vertices_world_m[list(self.faces[face])]


def _newell_normal(polygon: FloatArray) -> FloatArray:
    """Unnormalised polygon normal by Newell's method (robust for any planar polygon)."""
    nxt = np.roll(polygon, -1, axis=0)
    return np.array(
        [
            np.sum((polygon[:, 1] - nxt[:, 1]) * (polygon[:, 2] + nxt[:, 2])),
            np.sum((polygon[:, 2] - nxt[:, 2]) * (polygon[:, 0] + nxt[:, 0])),
            np.sum((polygon[:, 0] - nxt[:, 0]) * (polygon[:, 1] + nxt[:, 1])),
        ]
    )


def build_scene(
    vertices_world_m: npt.ArrayLike,
    faces: Sequence[Sequence[int]],
    face_albedo: npt.ArrayLike,
    name: str = "scene",
) -> SceneModel:
    """Validate faces and derive their normals and edges; raises :class:`SceneModelError`."""
    vertices = np.asarray(vertices_world_m, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.shape[0] < 3:
        raise SceneModelError(f"vertices must have shape (V >= 3, 3), got {vertices.shape}")
    if not np.all(np.isfinite(vertices)):
        raise SceneModelError("vertices must be finite")
    albedo = np.asarray(face_albedo, dtype=np.float64)
    if albedo.shape != (len(faces),):
        raise SceneModelError(f"face_albedo must have shape ({len(faces)},), got {albedo.shape}")
    if not np.all((albedo >= 0.0) & (albedo <= 1.0)):
        raise SceneModelError("face albedo must lie in [0, 1]")
    if len(faces) == 0:
        raise SceneModelError("a scene needs at least one face")
    face_tuples: list[tuple[int, ...]] = []
    normals = np.empty((len(faces), 3))
    offsets = np.empty(len(faces))
    for f, face in enumerate(faces):
        ids = tuple(int(i) for i in face)
        if len(ids) < 3 or min(ids) < 0 or max(ids) >= len(vertices) or len(set(ids)) != len(ids):
            raise SceneModelError(f"face {f} must list >= 3 distinct vertex indices in [0, {len(vertices)})")
        polygon = vertices[list(ids)]
        normal = _newell_normal(polygon)
        norm = float(np.linalg.norm(normal))
        if norm < 1e-9:
            raise SceneModelError(f"face {f} is degenerate (zero area)")
        normal /= norm
        offset = float(normal @ polygon.mean(axis=0))
        if np.max(np.abs(polygon @ normal - offset)) > _PLANARITY_TOLERANCE_M:
            raise SceneModelError(f"face {f} is not planar")
        face_tuples.append(ids)
        normals[f] = normal
        offsets[f] = offset
    edges, edge_faces = _derive_edges(vertices, face_tuples, normals, albedo)
    return SceneModel(
        name=name,
        vertices_world_m=vertices,
        faces=tuple(face_tuples),
        face_albedo=albedo,
        face_normals=normals,
        face_offsets_m=offsets,
        edges_world_m=edges,
        edge_faces=edge_faces,
    )


def _derive_edges(
    vertices: FloatArray, faces: list[tuple[int, ...]], normals: FloatArray, albedo: FloatArray
) -> tuple[FloatArray, IntArray]:
    """Polygon sides merged by end-point coordinates; contrast-free sides between coplanar faces dropped."""
    keys = np.round(vertices / _MERGE_TOLERANCE_M).astype(np.int64)
    sides: dict[tuple[tuple[int, ...], tuple[int, ...]], list[int]] = {}
    ends: dict[tuple[tuple[int, ...], tuple[int, ...]], tuple[int, int]] = {}
    for f, ids in enumerate(faces):
        for a, b in zip(ids, ids[1:] + ids[:1], strict=True):
            ka, kb = tuple(keys[a].tolist()), tuple(keys[b].tolist())
            key = (ka, kb) if ka <= kb else (kb, ka)
            sides.setdefault(key, []).append(f)
            ends.setdefault(key, (a, b))
    edge_list: list[FloatArray] = []
    face_pairs: list[tuple[int, int]] = []
    for key, adjacent in sides.items():
        first = adjacent[0]
        second = adjacent[1] if len(adjacent) > 1 else -1
        if (
            second >= 0
            and float(normals[first] @ normals[second]) > 1.0 - 1e-9
            and abs(albedo[first] - albedo[second]) < 1e-9
        ):
            continue
        a, b = ends[key]
        edge_list.append(vertices[[a, b]])
        face_pairs.append((first, second))
    return np.asarray(edge_list, dtype=np.float64).reshape(-1, 2, 3), np.asarray(face_pairs, dtype=np.int64)


def scene_from_dict(description: Mapping[str, Any]) -> SceneModel:
    """Scene of a parsed JSON description (see the module docstring); raises :class:`SceneModelError`."""
    if not isinstance(description, Mapping):
        raise SceneModelError("a scene description must be a JSON object")
    try:
        vertices = description["vertices"]
        faces_raw = description["faces"]
    except KeyError as exc:
        raise SceneModelError(f"scene description lacks the key {exc}") from None
    if not isinstance(faces_raw, list):
        raise SceneModelError("'faces' must be a list of objects")
    faces: list[list[int]] = []
    albedo: list[float] = []
    for i, face in enumerate(faces_raw):
        if not isinstance(face, Mapping) or "vertices" not in face:
            raise SceneModelError(f"face {i} must be an object with 'vertices' (and optional 'albedo')")
        faces.append([int(v) for v in face["vertices"]])
        albedo.append(float(face.get("albedo", 0.5)))
    try:
        vertex_array = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneModelError("'vertices' must be a list of [x, y, z] numbers") from None
    return build_scene(vertex_array, faces, albedo, name=str(description.get("name", "scene")))


def scene_from_json(text: str) -> SceneModel:
    """Scene of a JSON document (see the module docstring); raises :class:`SceneModelError`."""
    try:
        description = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SceneModelError(f"scene file is not valid JSON: {exc}") from None
    return scene_from_dict(description)


def scene_to_dict(scene: SceneModel) -> dict[str, Any]:
    """The JSON description of a scene (inverse of :func:`scene_from_dict`)."""
    return {
        "name": scene.name,
        "vertices": scene.vertices_world_m.tolist(),
        "faces": [
            {"vertices": list(face), "albedo": float(a)}
            for face, a in zip(scene.faces, scene.face_albedo, strict=True)
        ],
    }


class _SceneBuilder:
    """Accumulates oriented quads for the built-in scene."""

    def __init__(self) -> None:
        self.vertices: list[list[float]] = []
        self.faces: list[list[int]] = []
        self.albedo: list[float] = []

    def quad(self, corners: Sequence[Sequence[float]], towards: Sequence[float], albedo: float) -> None:
        """Add a quad whose visible side faces the direction ``towards``."""
        pts = np.asarray(corners, dtype=np.float64)
        if float(_newell_normal(pts) @ np.asarray(towards, dtype=np.float64)) < 0.0:
            pts = pts[::-1]
        start = len(self.vertices)
        self.vertices.extend(pts.tolist())
        self.faces.append(list(range(start, start + len(pts))))
        self.albedo.append(albedo)

    def box(self, lo: Sequence[float], hi: Sequence[float], albedo: float, top: bool = True) -> None:
        """An axis-aligned box resting on something (no bottom face), faces pointing out."""
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        self.quad([[x0, y0, z0], [x0, y1, z0], [x0, y1, z1], [x0, y0, z1]], (-1, 0, 0), albedo)
        self.quad([[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]], (1, 0, 0), albedo)
        self.quad([[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]], (0, -1, 0), albedo)
        self.quad([[x0, y1, z0], [x1, y1, z0], [x1, y1, z1], [x0, y1, z1]], (0, 1, 0), albedo)
        if top:
            self.quad([[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], (0, 0, 1), albedo)

    def wall_rect(
        self,
        wall: str,
        room: Sequence[float],
        a: tuple[float, float],
        z: tuple[float, float],
        albedo: float,
        inset_m: float,
    ) -> None:
        """A decal rectangle on a wall: ``a`` spans the wall's horizontal axis, ``z`` the height."""
        sx, sy, _ = room
        if wall == "south":
            x, y = (a[0], a[1]), (inset_m, inset_m)
            towards = (0, 1, 0)
        elif wall == "north":
            x, y = (a[0], a[1]), (sy - inset_m, sy - inset_m)
            towards = (0, -1, 0)
        elif wall == "west":
            x, y = (inset_m, inset_m), (a[0], a[1])
            towards = (1, 0, 0)
        else:
            x, y = (sx - inset_m, sx - inset_m), (a[0], a[1])
            towards = (-1, 0, 0)
        self.quad(
            [[x[0], y[0], z[0]], [x[1], y[1], z[0]], [x[1], y[1], z[1]], [x[0], y[0], z[1]]], towards, albedo
        )

    def window(
        self, wall: str, room: Sequence[float], a: tuple[float, float], z: tuple[float, float]
    ) -> None:
        """A bright frame with four dark panes."""
        self.wall_rect(wall, room, a, z, 0.95, 0.01)
        bar = 0.06
        am, zm = 0.5 * (a[0] + a[1]), 0.5 * (z[0] + z[1])
        for pa in ((a[0] + bar, am - bar / 2), (am + bar / 2, a[1] - bar)):
            for pz in ((z[0] + bar, zm - bar / 2), (zm + bar / 2, z[1] - bar)):
                self.wall_rect(wall, room, pa, pz, 0.2, 0.02)


#: Size of the built-in room (m): x (east), y (north), z (up).
DEFAULT_ROOM_SIZE_M: tuple[float, float, float] = (10.0, 8.0, 3.0)


def default_scene() -> SceneModel:
    """The built-in office: a 10 x 8 x 3 m room with 2 doors, 3 windows, 3 pictures and 16 furniture boxes."""
    room = DEFAULT_ROOM_SIZE_M
    sx, sy, sz = room
    b = _SceneBuilder()
    b.quad([[0, 0, 0], [sx, 0, 0], [sx, sy, 0], [0, sy, 0]], (0, 0, 1), 0.35)  # floor
    b.quad([[0, 0, sz], [sx, 0, sz], [sx, sy, sz], [0, sy, sz]], (0, 0, -1), 0.9)  # ceiling
    b.quad([[0, 0, 0], [sx, 0, 0], [sx, 0, sz], [0, 0, sz]], (0, 1, 0), 0.7)  # south wall
    b.quad([[0, sy, 0], [sx, sy, 0], [sx, sy, sz], [0, sy, sz]], (0, -1, 0), 0.62)  # north wall
    b.quad([[0, 0, 0], [0, sy, 0], [0, sy, sz], [0, 0, sz]], (1, 0, 0), 0.78)  # west wall
    b.quad([[sx, 0, 0], [sx, sy, 0], [sx, sy, sz], [sx, 0, sz]], (-1, 0, 0), 0.55)  # east wall
    # doors
    b.wall_rect("south", room, (1.2, 2.2), (0.0, 2.1), 0.25, 0.01)
    b.wall_rect("east", room, (5.5, 6.5), (0.0, 2.1), 0.3, 0.01)
    # windows
    b.window("north", room, (2.0, 3.6), (1.0, 2.3))
    b.window("north", room, (6.0, 7.6), (1.0, 2.3))
    b.window("west", room, (3.0, 4.6), (1.0, 2.3))
    # pictures
    b.wall_rect("south", room, (4.0, 5.2), (1.3, 2.1), 0.15, 0.01)
    b.wall_rect("south", room, (6.5, 7.1), (1.4, 2.2), 0.95, 0.01)
    b.wall_rect("east", room, (2.0, 3.4), (1.2, 2.0), 0.1, 0.01)
    # furniture
    b.box((0.3, 0.3, 0.0), (0.9, 2.3, 1.9), 0.45)  # shelf, south-west
    b.box((3.0, 0.25, 0.0), (3.8, 0.75, 1.1), 0.2)  # cabinet, south
    b.box((8.3, 0.3, 0.0), (9.7, 1.1, 0.75), 0.85)  # desk, south-east
    b.box((8.6, 1.3, 0.0), (9.1, 1.8, 0.45), 0.15)  # stool
    b.box((9.2, 2.4, 0.0), (9.75, 4.6, 2.2), 0.4)  # wardrobe, east
    b.box((9.3, 7.0, 0.0), (9.8, 7.7, 1.0), 0.9)  # crate, north-east
    b.box((8.2, 7.2, 0.0), (8.9, 7.75, 0.6), 0.3)  # small crate
    b.box((4.4, 7.1, 0.0), (5.6, 7.7, 0.9), 0.1)  # sideboard, north
    b.box((0.3, 6.0, 0.0), (1.3, 7.7, 0.8), 0.88)  # sofa, north-west
    b.box((0.3, 5.2, 0.0), (0.8, 5.7, 1.3), 0.2)  # plant stand
    b.box((4.2, 3.4, 0.0), (5.8, 4.4, 0.75), 0.55)  # table, centre
    b.box((3.6, 3.6, 0.0), (4.0, 4.0, 0.45), 0.12)  # chair
    b.box((6.0, 3.7, 0.0), (6.4, 4.1, 0.45), 0.92)  # chair
    b.box((2.2, 5.6, 0.0), (2.6, 6.0, sz), 0.5, top=False)  # pillar, floor to ceiling
    b.box((7.4, 2.0, 0.0), (7.8, 2.4, sz), 0.48, top=False)  # pillar
    b.box((2.0, 1.6, 0.0), (2.5, 2.1, 0.5), 0.05)  # box on the floor
    return build_scene(b.vertices, b.faces, b.albedo, name="office")
