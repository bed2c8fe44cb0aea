"""Known 3D model: planar faces, standalone lines, and the edges an image shows (paper B's "model").

JSON format (one object; units metres, any right-handed world frame)::

    {
      "name": "teabox",                       # optional
      "vertices": [[x, y, z], ...],           # required, >= 1 vertex
      "faces": [                              # optional (default none)
        {"vertices": [i, j, k, ...],          #   >= 3 distinct vertex indices, one planar polygon
         "albedo": 0.6,                       #   optional, in [0, 1] (default 0.5)
         "group": 0}                          #   optional: faces of one tessellated curved surface
      ],
      "lines": [[i, j], ...],                 # optional standalone edges (wires, markings, outlines)
      "crease_angle_deg": 30.0                # optional (default 30)
    }

A face is listed counter-clockwise when seen from its visible side (right-hand rule: the normal points at
the viewer; ViSP's ``.cao`` convention too). Its vertices must lie in one plane (1 mm); a non-convex face is
split into triangles (ear clipping), whose inner sides vanish by the coplanar rule below. ``albedo`` is the
face's brightness before shading (only the simulator and the coplanar rule use it).

Edges: every polygon side becomes an edge, sides shared by several faces are merged, and a side between two
coplanar faces of the same albedo is dropped (no contrast in an image). A side between two faces of the same
``group``, or whose normals differ by less than ``crease_angle_deg``, is *smooth*: it is scored only where it
is a silhouette (a limb: one adjacent face towards the camera, the other away), as on a tessellated
cylinder. A standalone line has no face and is never back-face culled. Every edge remembers up to two
adjacent faces (-1 for none).

Scenes also come from Wavefront OBJ and ViSP ``.cao`` files (:mod:`common.localization.cad`);
:mod:`common.localization.office` builds the built-in office.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.types import BoolArray, FloatArray

IntArray = npt.NDArray[np.int64]

#: Vertices closer than this are the same point when edges are merged (m).
_MERGE_TOLERANCE_M = 1e-6
#: A face whose vertices leave its plane by more than this is rejected (m).
_PLANARITY_TOLERANCE_M = 1e-3
#: Default angle between two faces' normals below which their common side is smooth (deg).
DEFAULT_CREASE_ANGLE_DEG = 30.0


class SceneModelError(InputError):
    """A scene description is malformed (shape, indices, non-planar face, albedo)."""


@dataclass(frozen=True)
class SceneModel:
    """Faces and edges of a static 3D scene in the world frame.

    ``faces`` holds each face's vertex indices; ``face_normals`` (F, 3) are unit normals towards the visible
    side and ``face_offsets_m`` (F,) the plane offsets (``n . x = d``). ``edges_world_m`` (E, 2, 3) are the
    edge end points; ``edge_faces`` (E, 2) the adjacent face indices (-1 for none); ``edge_smooth`` (E,)
    marks edges scored only as silhouettes (see the module docstring).
    """

    name: str
    vertices_world_m: FloatArray
    faces: tuple[tuple[int, ...], ...]
    face_albedo: FloatArray
    face_normals: FloatArray
    face_offsets_m: FloatArray
    edges_world_m: FloatArray
    edge_faces: IntArray
    edge_smooth: BoolArray

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def n_edges(self) -> int:
        return int(self.edges_world_m.shape[0])

    @property
    def size_m(self) -> float:
        """Diagonal of the bounding box of the edges (m): the model's scale."""
        points = self.edges_world_m.reshape(-1, 3)
        return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))

    @property
    def centre_world_m(self) -> FloatArray:
        """Centre of the bounding box of the edges."""
        points = self.edges_world_m.reshape(-1, 3)
        return np.asarray(0.5 * (points.max(axis=0) + points.min(axis=0)))

    def face_polygon_world_m(self, face: int) -> FloatArray:
        """Vertices (K, 3) of one face, in order."""
        return self.vertices_world_m[list(self.faces[face])]


def newell_normal(polygon: FloatArray) -> FloatArray:
    """Unnormalised polygon normal by Newell's method (robust for any planar polygon)."""
    nxt = np.roll(polygon, -1, axis=0)
    return np.array(
        [
            np.sum((polygon[:, 1] - nxt[:, 1]) * (polygon[:, 2] + nxt[:, 2])),
            np.sum((polygon[:, 2] - nxt[:, 2]) * (polygon[:, 0] + nxt[:, 0])),
            np.sum((polygon[:, 0] - nxt[:, 0]) * (polygon[:, 1] + nxt[:, 1])),
        ]
    )


def _plane_coordinates(polygon: FloatArray, normal: FloatArray) -> FloatArray:
    """2D coordinates (K, 2) of a planar polygon in its plane, counter-clockwise about ``normal``."""
    axis_u = polygon[1] - polygon[0]
    axis_u = axis_u - (axis_u @ normal) * normal
    axis_u /= np.linalg.norm(axis_u)
    axis_v = np.cross(normal, axis_u)
    rel = polygon - polygon[0]
    return np.stack([rel @ axis_u, rel @ axis_v], axis=1)


def _is_convex(xy: FloatArray) -> bool:
    """True when every corner of a counter-clockwise 2D polygon turns left (collinear corners allowed)."""
    a, b = np.roll(xy, -1, axis=0) - xy, np.roll(xy, -2, axis=0) - np.roll(xy, -1, axis=0)
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    scale = float(np.max(np.abs(xy))) ** 2 + 1e-300
    return bool(np.all(cross >= -1e-12 * scale))


def triangulate(xy: FloatArray) -> list[tuple[int, int, int]]:
    """Ear clipping of a simple counter-clockwise 2D polygon (K, 2): K - 2 triangles of corner indices.

    Raises :class:`SceneModelError` when no ear is found (a self-intersecting outline)."""
    remaining = list(range(len(xy)))
    triangles: list[tuple[int, int, int]] = []

    def cross(o: int, a: int, b: int) -> float:
        return float(
            (xy[a, 0] - xy[o, 0]) * (xy[b, 1] - xy[o, 1]) - (xy[a, 1] - xy[o, 1]) * (xy[b, 0] - xy[o, 0])
        )

    while len(remaining) > 3:
        for k in range(len(remaining)):
            i, j, m = remaining[k - 1], remaining[k], remaining[(k + 1) % len(remaining)]
            if cross(i, j, m) <= 1e-15:
                continue  # reflex or flat corner
            inside = False
            for q in remaining:
                if q in (i, j, m):
                    continue
                if cross(i, j, q) >= 0.0 and cross(j, m, q) >= 0.0 and cross(m, i, q) >= 0.0:
                    inside = True
                    break
            if not inside:
                triangles.append((i, j, m))
                remaining.pop(k)
                break
        else:
            raise SceneModelError("a face outline intersects itself (no ear to clip)")
    triangles.append((remaining[0], remaining[1], remaining[2]))
    return triangles


def build_scene(
    vertices_world_m: npt.ArrayLike,
    faces: Sequence[Sequence[int]],
    face_albedo: npt.ArrayLike,
    name: str = "scene",
    lines: Sequence[Sequence[int]] = (),
    face_groups: Sequence[int] | None = None,
    crease_angle_deg: float = DEFAULT_CREASE_ANGLE_DEG,
) -> SceneModel:
    """Validate faces (non-convex ones are triangulated) and lines, derive normals and edges; raises
    :class:`SceneModelError` naming the offending face or line."""
    vertices = np.asarray(vertices_world_m, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.shape[0] < 2:
        raise SceneModelError(f"vertices must have shape (V >= 2, 3), got {vertices.shape}")
    if not np.all(np.isfinite(vertices)):
        raise SceneModelError("vertices must be finite")
    albedo_in = np.asarray(face_albedo, dtype=np.float64).reshape(-1)
    if albedo_in.shape != (len(faces),):
        raise SceneModelError(f"face_albedo must have shape ({len(faces)},), got {albedo_in.shape}")
    if not np.all((albedo_in >= 0.0) & (albedo_in <= 1.0)):
        raise SceneModelError("face albedo must lie in [0, 1]")
    groups_in = [-1] * len(faces) if face_groups is None else [int(g) for g in face_groups]
    if len(groups_in) != len(faces):
        raise SceneModelError(f"face_groups must have {len(faces)} entries, got {len(groups_in)}")
    if not 0.0 <= crease_angle_deg < 90.0:
        raise SceneModelError(f"crease_angle_deg must lie in [0, 90), got {crease_angle_deg}")
    if len(faces) == 0 and len(lines) == 0:
        raise SceneModelError("a scene needs at least one face or line")
    face_tuples: list[tuple[int, ...]] = []
    normals: list[FloatArray] = []
    offsets: list[float] = []
    albedo: list[float] = []
    groups: list[int] = []
    for f, face in enumerate(faces):
        ids = tuple(int(i) for i in face)
        if len(ids) < 3 or min(ids) < 0 or max(ids) >= len(vertices) or len(set(ids)) != len(ids):
            raise SceneModelError(f"face {f} must list >= 3 distinct vertex indices in [0, {len(vertices)})")
        polygon = vertices[list(ids)]
        normal = newell_normal(polygon)
        norm = float(np.linalg.norm(normal))
        if norm < 1e-12:
            raise SceneModelError(f"face {f} is degenerate (zero area)")
        normal /= norm
        offset = float(normal @ polygon.mean(axis=0))
        if np.max(np.abs(polygon @ normal - offset)) > _PLANARITY_TOLERANCE_M:
            raise SceneModelError(f"face {f} is not planar (a vertex leaves its plane by more than 1 mm)")
        pieces: list[tuple[int, ...]] = [ids]
        if len(ids) > 3:
            xy = _plane_coordinates(polygon, normal)
            if not _is_convex(xy):
                try:
                    pieces = [tuple(ids[k] for k in tri) for tri in triangulate(xy)]
                except SceneModelError as exc:
                    raise SceneModelError(f"face {f}: {exc}") from None
        for piece in pieces:
            face_tuples.append(piece)
            normals.append(normal)
            offsets.append(offset)
            albedo.append(float(albedo_in[f]))
            groups.append(groups_in[f])
    line_pairs: list[tuple[int, int]] = []
    for n, line in enumerate(lines):
        ids = tuple(int(i) for i in line)
        if len(ids) != 2 or min(ids) < 0 or max(ids) >= len(vertices) or ids[0] == ids[1]:
            raise SceneModelError(f"line {n} must join 2 distinct vertex indices in [0, {len(vertices)})")
        if np.linalg.norm(vertices[ids[0]] - vertices[ids[1]]) < _MERGE_TOLERANCE_M:
            raise SceneModelError(f"line {n} has zero length")
        line_pairs.append((ids[0], ids[1]))
    normal_array = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    albedo_array = np.asarray(albedo, dtype=np.float64)
    edges, edge_faces, smooth = _derive_edges(
        vertices, face_tuples, normal_array, albedo_array, groups, line_pairs, crease_angle_deg
    )
    if edges.shape[0] == 0:
        raise SceneModelError("the scene has no edge an image could show")
    return SceneModel(
        name=name,
        vertices_world_m=vertices,
        faces=tuple(face_tuples),
        face_albedo=albedo_array,
        face_normals=normal_array,
        face_offsets_m=np.asarray(offsets, dtype=np.float64),
        edges_world_m=edges,
        edge_faces=edge_faces,
        edge_smooth=smooth,
    )


def _derive_edges(
    vertices: FloatArray,
    faces: list[tuple[int, ...]],
    normals: FloatArray,
    albedo: FloatArray,
    groups: list[int],
    lines: list[tuple[int, int]],
    crease_angle_deg: float,
) -> tuple[FloatArray, IntArray, BoolArray]:
    """Polygon sides merged by end-point coordinates; contrast-free sides between coplanar faces dropped;
    smooth sides flagged; standalone lines appended unless they repeat a side."""
    keys = np.round(vertices / _MERGE_TOLERANCE_M).astype(np.int64)
    sides: dict[tuple[tuple[int, ...], tuple[int, ...]], list[int]] = {}
    ends: dict[tuple[tuple[int, ...], tuple[int, ...]], tuple[int, int]] = {}
    for f, ids in enumerate(faces):
        for a, b in zip(ids, ids[1:] + ids[:1], strict=True):
            ka, kb = tuple(keys[a].tolist()), tuple(keys[b].tolist())
            key = (ka, kb) if ka <= kb else (kb, ka)
            sides.setdefault(key, []).append(f)
            ends.setdefault(key, (a, b))
    cos_crease = float(np.cos(np.radians(crease_angle_deg)))
    edge_list: list[FloatArray] = []
    face_pairs: list[tuple[int, int]] = []
    smooth: list[bool] = []
    for key, adjacent in sides.items():
        first = adjacent[0]
        second = adjacent[1] if len(adjacent) > 1 else -1
        is_smooth = False
        if second >= 0:
            cos_angle = float(normals[first] @ normals[second])
            if cos_angle > 1.0 - 1e-9 and abs(albedo[first] - albedo[second]) < 1e-9:
                continue
            same_group = groups[first] >= 0 and groups[first] == groups[second]
            is_smooth = same_group or (cos_angle > cos_crease and abs(albedo[first] - albedo[second]) < 1e-9)
        a, b = ends[key]
        edge_list.append(vertices[[a, b]])
        face_pairs.append((first, second))
        smooth.append(is_smooth)
    for a, b in lines:
        ka, kb = tuple(keys[a].tolist()), tuple(keys[b].tolist())
        key = (ka, kb) if ka <= kb else (kb, ka)
        if key in sides:
            continue
        sides[key] = []
        edge_list.append(vertices[[a, b]])
        face_pairs.append((-1, -1))
        smooth.append(False)
    return (
        np.asarray(edge_list, dtype=np.float64).reshape(-1, 2, 3),
        np.asarray(face_pairs, dtype=np.int64).reshape(-1, 2),
        np.asarray(smooth, dtype=bool),
    )


def scene_from_dict(description: Mapping[str, Any]) -> SceneModel:
    """Scene of a parsed JSON description (see the module docstring); raises :class:`SceneModelError`."""
    if not isinstance(description, Mapping):
        raise SceneModelError("a scene description must be a JSON object")
    unknown = set(description) - {"name", "vertices", "faces", "lines", "crease_angle_deg"}
    if unknown:
        raise SceneModelError(f"unknown key(s) in the scene description: {sorted(unknown)}")
    if "vertices" not in description:
        raise SceneModelError("scene description lacks the key 'vertices'")
    faces_raw = description.get("faces", [])
    lines_raw = description.get("lines", [])
    if not isinstance(faces_raw, list) or not isinstance(lines_raw, list):
        raise SceneModelError("'faces' and 'lines' must be lists")
    faces: list[list[int]] = []
    albedo: list[float] = []
    groups: list[int] = []
    try:
        for i, face in enumerate(faces_raw):
            if not isinstance(face, Mapping) or "vertices" not in face:
                raise SceneModelError(
                    f"face {i} must be an object with 'vertices' (optional 'albedo', 'group')"
                )
            faces.append([int(v) for v in face["vertices"]])
            albedo.append(float(face.get("albedo", 0.5)))
            groups.append(int(face.get("group", -1)))
        lines = [[int(v) for v in line] for line in lines_raw]
        vertex_array = np.asarray(description["vertices"], dtype=np.float64)
        crease = float(description.get("crease_angle_deg", DEFAULT_CREASE_ANGLE_DEG))
    except (TypeError, ValueError) as exc:
        if isinstance(exc, SceneModelError):
            raise
        raise SceneModelError(f"scene description has a value of the wrong type: {exc}") from None
    return build_scene(
        vertex_array,
        faces,
        albedo,
        name=str(description.get("name", "scene")),
        lines=lines,
        face_groups=groups,
        crease_angle_deg=crease,
    )


def scene_from_json(text: str) -> SceneModel:
    """Scene of a JSON document (see the module docstring); raises :class:`SceneModelError`."""
    try:
        description = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SceneModelError(f"scene file is not valid JSON: line {exc.lineno}: {exc.msg}") from None
    return scene_from_dict(description)


def scene_to_dict(scene: SceneModel) -> dict[str, Any]:
    """The JSON description of a scene (faces as stored, i.e. after triangulation; standalone lines)."""
    lines = [
        [int(np.argmin(np.linalg.norm(scene.vertices_world_m - p, axis=1))) for p in edge]
        for edge, pair in zip(scene.edges_world_m, scene.edge_faces, strict=True)
        if pair[0] < 0
    ]
    description: dict[str, Any] = {
        "name": scene.name,
        "vertices": scene.vertices_world_m.tolist(),
        "faces": [
            {"vertices": list(face), "albedo": float(a)}
            for face, a in zip(scene.faces, scene.face_albedo, strict=True)
        ],
    }
    if lines:
        description["lines"] = lines
    return description
