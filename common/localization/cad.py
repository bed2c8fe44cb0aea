"""CAD model text -> :class:`~common.localization.model.SceneModel`: Wavefront OBJ and ViSP ``.cao``.

Pure text-to-model functions (files are read by :mod:`common.datasets.models`). Every malformed input raises
:class:`CadError` with one line naming the source and line number.

**Wavefront OBJ**: ``v x y z [w]`` vertices; ``f a b c ...`` faces (``a``, ``a/t``, ``a//n``, ``a/t/n``;
negative indices count from the end); ``l a b ...`` polylines (standalone edges); ``vt``, ``vn``, ``vp``,
``o``, ``g``, ``s``, ``usemtl``, ``mtllib`` are ignored. Faces are counter-clockwise seen from outside.
Tessellated curved surfaces show only their silhouettes (sides between faces within the crease angle are
smooth, see :mod:`~common.localization.model`).

**ViSP .cao** (version ``V1``), ``#`` starts a comment; sections in this order, each a count then rows:

- ``load("part.cao", t=[x, y, z], tu=[rx, ry, rz])`` lines right after ``V1``: a sub-part, its points
  mapped by ``X = Rodrigues(tu) X_part + t`` (metres, rad);
- 3D points ``x y z``; 3D lines ``i j`` (standalone edges);
- faces from 3D lines ``n l1 ... ln`` (the lines must close a loop); faces from 3D points ``n p1 ... pn``;
- 3D cylinders ``p1 p2 radius``: 16 lateral facets around the axis ``p1 -> p2`` (smooth: their limbs and
  the two rim polylines are edges);
- 3D circles ``radius pc p1 p2``: a 16-segment polyline of that radius about ``pc`` in the plane through
  ``pc``, ``p1``, ``p2``.

Trailing ``name=...``-style attributes on a row (ViSP's ``name=``, ``useLod=``, ``minLineLengthThreshold=``)
are accepted and ignored; missing trailing sections count as empty.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from common.localization.model import SceneModel, SceneModelError, build_scene
from common.localization.pose import rotation_matrices
from common.types import FloatArray

#: Facets of a cylinder and segments of a circle.
ROUND_SEGMENTS = 16
#: Deepest ``load()`` nesting accepted.
MAX_LOAD_DEPTH = 8


class CadError(SceneModelError):
    """A CAD model file is malformed (the message names the source and line)."""


@dataclass
class _Geometry:
    """What a CAD file contributes: vertices, faces (vertex loops), face groups, standalone lines."""

    vertices: list[FloatArray] = field(default_factory=list)
    faces: list[list[int]] = field(default_factory=list)
    groups: list[int] = field(default_factory=list)
    lines: list[tuple[int, int]] = field(default_factory=list)
    next_group: int = 0

    def add_vertex(self, point: FloatArray) -> int:
        self.vertices.append(np.asarray(point, dtype=np.float64))
        return len(self.vertices) - 1

    def merge(self, other: _Geometry, R: FloatArray, t: FloatArray) -> None:
        base = len(self.vertices)
        self.vertices.extend(R @ v + t for v in other.vertices)
        self.faces.extend([[i + base for i in f] for f in other.faces])
        self.groups.extend([g + self.next_group if g >= 0 else -1 for g in other.groups])
        self.lines.extend((a + base, b + base) for a, b in other.lines)
        self.next_group += other.next_group

    def build(self, name: str, source: str) -> SceneModel:
        if not self.vertices:
            raise CadError(f"{source}: the model has no vertices")
        try:
            return build_scene(
                np.asarray(self.vertices),
                self.faces,
                np.full(len(self.faces), 0.5),
                name=name,
                lines=self.lines,
                face_groups=self.groups,
            )
        except CadError:
            raise
        except SceneModelError as exc:
            raise CadError(f"{source}: {exc}") from None


# -- Wavefront OBJ -----------------------------------------------------------------------------------------
_OBJ_IGNORED = {"vt", "vn", "vp", "o", "g", "s", "usemtl", "mtllib"}


def scene_from_obj(text: str, name: str = "obj", source: str = "<obj>", scale: float = 1.0) -> SceneModel:
    """Scene of a Wavefront OBJ document (see the module docstring); ``scale``: its units to metres."""
    geometry = _Geometry()
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        keyword, *args = line.split()
        where = f"{source}:{number}"
        if keyword == "v":
            values = _floats(args, where, "v", (3, 4))
            geometry.add_vertex(np.asarray(values[:3]) * scale)
        elif keyword in ("f", "l"):
            ids = [_obj_index(a, len(geometry.vertices), where) for a in args]
            if keyword == "f":
                if len(ids) < 3:
                    raise CadError(f"{where}: a face needs at least 3 vertices, got {len(ids)}")
                geometry.faces.append(ids)
                geometry.groups.append(-1)
            else:
                if len(ids) < 2:
                    raise CadError(f"{where}: a line needs at least 2 vertices, got {len(ids)}")
                geometry.lines.extend(itertools.pairwise(ids))
        elif keyword not in _OBJ_IGNORED:
            raise CadError(f"{where}: unknown OBJ statement {keyword!r}")
    return geometry.build(name, source)


def _obj_index(token: str, count: int, where: str) -> int:
    head = token.split("/", 1)[0]
    try:
        index = int(head)
    except ValueError:
        raise CadError(f"{where}: {token!r} is not a vertex index") from None
    resolved = index - 1 if index > 0 else count + index
    if index == 0 or not 0 <= resolved < count:
        raise CadError(f"{where}: vertex index {index} out of range (1..{count} or -1..-{count})")
    return resolved


def _floats(args: Sequence[str], where: str, what: str, counts: tuple[int, ...]) -> list[float]:
    if len(args) not in counts:
        raise CadError(f"{where}: {what} takes {' or '.join(map(str, counts))} numbers, got {len(args)}")
    try:
        values = [float(a) for a in args]
    except ValueError:
        raise CadError(f"{where}: {what} has a value that is not a number: {' '.join(args)}") from None
    if not all(np.isfinite(values)):
        raise CadError(f"{where}: {what} has a value that is not finite")
    return values


# -- ViSP .cao ---------------------------------------------------------------------------------------------
_LOAD = re.compile(r'^load\(\s*"(?P<path>[^"]+)"\s*(?:,\s*(?P<kw>.*))?\)$')
_VECTOR = re.compile(r"(?P<key>t|tu)\s*=\s*\[(?P<values>[^\]]*)\]")


class _Rows:
    """The meaningful rows of a .cao text with their line numbers (comments and blanks removed)."""

    def __init__(self, text: str, source: str) -> None:
        self.rows: list[tuple[int, str]] = []
        for number, raw in enumerate(text.splitlines(), start=1):
            line = raw.split("#", 1)[0].strip()
            if line:
                self.rows.append((number, line))
        self.source = source
        self.position = 0

    def peek(self) -> tuple[int, str] | None:
        return self.rows[self.position] if self.position < len(self.rows) else None

    def take(self, what: str) -> tuple[int, str]:
        row = self.peek()
        if row is None:
            last = self.rows[-1][0] if self.rows else 0
            raise CadError(f"{self.source}:{last}: file ends where {what} was expected")
        self.position += 1
        return row

    def count(self, what: str) -> int:
        row = self.peek()
        if row is None:
            return 0  # missing trailing sections are empty
        number, line = self.take(f"the number of {what}")
        try:
            value = int(line.split()[0])
        except ValueError:
            raise CadError(f"{self.source}:{number}: expected the number of {what}, got {line!r}") from None
        if value < 0 or len(line.split()) != 1:
            raise CadError(f"{self.source}:{number}: expected the number of {what}, got {line!r}")
        return value

    def numbers(self, what: str) -> tuple[str, list[str]]:
        number, line = self.take(what)
        tokens = [tok for tok in line.split() if "=" not in tok]  # name=..., useLod=... ignored
        return f"{self.source}:{number}", tokens


def scene_from_cao(
    text: str,
    name: str = "cao",
    source: str = "<cao>",
    load: Callable[[str, str], tuple[str, str]] | None = None,
) -> SceneModel:
    """Scene of a ViSP ``.cao`` document; ``load(path, containing_source) -> (text, source)`` resolves
    ``load()`` sub-parts (None refuses them)."""
    return _cao_geometry(text, source, load, 0).build(name, source)


def _cao_geometry(
    text: str, source: str, load: Callable[[str, str], tuple[str, str]] | None, depth: int
) -> _Geometry:
    rows = _Rows(text, source)
    number, header = rows.take("the header V1")
    if header.split()[0] != "V1":
        raise CadError(f"{source}:{number}: a .cao file starts with 'V1', got {header!r}")
    geometry = _Geometry()
    while (row := rows.peek()) is not None and row[1].startswith("load("):
        rows.take("load()")
        geometry_part, R, t = _load_part(row, source, load, depth)
        geometry.merge(geometry_part, R, t)
    base = len(geometry.vertices)
    for _ in range(rows.count("3D points")):
        where, tokens = rows.numbers("a 3D point")
        geometry.add_vertex(np.asarray(_floats(tokens, where, "a 3D point", (3,))))
    n_points = len(geometry.vertices) - base

    def point(token: str, where: str) -> int:
        try:
            index = int(token)
        except ValueError:
            raise CadError(f"{where}: {token!r} is not a point index") from None
        if not 0 <= index < n_points:
            raise CadError(f"{where}: point index {index} out of range (0..{n_points - 1})")
        return base + index

    lines: list[tuple[int, int]] = []
    for _ in range(rows.count("3D lines")):
        where, tokens = rows.numbers("a 3D line")
        if len(tokens) != 2:
            raise CadError(f"{where}: a 3D line is 2 point indices, got {len(tokens)} values")
        lines.append((point(tokens[0], where), point(tokens[1], where)))
    geometry.lines.extend(lines)
    for _ in range(rows.count("faces from 3D lines")):
        where, tokens = rows.numbers("a face from lines")
        ids = _counted(tokens, where, "a face from lines", 3)
        loop = _chain([_line(lines, tok, where) for tok in ids], where)
        geometry.faces.append(loop)
        geometry.groups.append(-1)
    for _ in range(rows.count("faces from 3D points")):
        where, tokens = rows.numbers("a face from points")
        geometry.faces.append([point(tok, where) for tok in _counted(tokens, where, "a face from points", 3)])
        geometry.groups.append(-1)
    for _ in range(rows.count("3D cylinders")):
        where, tokens = rows.numbers("a 3D cylinder")
        if len(tokens) != 3:
            raise CadError(f"{where}: a cylinder is 2 point indices and a radius, got {len(tokens)} values")
        radius = _floats(tokens[2:], where, "a cylinder radius", (1,))[0]
        if radius <= 0.0:
            raise CadError(f"{where}: a cylinder radius must be positive, got {radius}")
        _cylinder(geometry, point(tokens[0], where), point(tokens[1], where), radius, where)
    for _ in range(rows.count("3D circles")):
        where, tokens = rows.numbers("a 3D circle")
        if len(tokens) != 4:
            raise CadError(f"{where}: a circle is a radius and 3 point indices, got {len(tokens)} values")
        radius = _floats(tokens[:1], where, "a circle radius", (1,))[0]
        if radius <= 0.0:
            raise CadError(f"{where}: a circle radius must be positive, got {radius}")
        centre, p1, p2 = (point(tok, where) for tok in tokens[1:])
        _circle(geometry, radius, centre, p1, p2, where)
    if (extra := rows.peek()) is not None:
        raise CadError(f"{source}:{extra[0]}: unexpected content after the circles: {extra[1]!r}")
    return geometry


def _load_part(
    row: tuple[int, str], source: str, load: Callable[[str, str], tuple[str, str]] | None, depth: int
) -> tuple[_Geometry, FloatArray, FloatArray]:
    number, line = row
    where = f"{source}:{number}"
    match = _LOAD.match(line.replace(" ", "") if '"' not in line else line)
    if match is None:
        raise CadError(f'{where}: expected load("file.cao", t=[x, y, z], tu=[rx, ry, rz]), got {line!r}')
    if load is None:
        raise CadError(f"{where}: load() of sub-parts is not available here")
    if depth >= MAX_LOAD_DEPTH:
        raise CadError(f"{where}: load() nested deeper than {MAX_LOAD_DEPTH} (a cycle?)")
    vectors = {"t": np.zeros(3), "tu": np.zeros(3)}
    for vec in _VECTOR.finditer(match.group("kw") or ""):
        vectors[vec.group("key")] = np.asarray(
            _floats([v for v in vec.group("values").replace(",", " ").split()], where, vec.group("key"), (3,))
        )
    try:
        text, sub_source = load(match.group("path"), source)
    except CadError:
        raise
    except Exception as exc:  # the loader's I/O error, reported on the load() line
        raise CadError(f"{where}: cannot load {match.group('path')!r}: {exc}") from None
    part = _cao_geometry(text, sub_source, load, depth + 1)
    return part, rotation_matrices(vectors["tu"][None])[0], vectors["t"]


def _counted(tokens: list[str], where: str, what: str, minimum: int) -> list[str]:
    try:
        n = int(tokens[0])
    except (IndexError, ValueError):
        raise CadError(f"{where}: {what} starts with its number of indices") from None
    if n < minimum or len(tokens) != n + 1:
        raise CadError(
            f"{where}: {what} announces {tokens[0]} indices (>= {minimum}), lists {len(tokens) - 1}"
        )
    return tokens[1:]


def _line(lines: list[tuple[int, int]], token: str, where: str) -> tuple[int, int]:
    try:
        index = int(token)
    except ValueError:
        raise CadError(f"{where}: {token!r} is not a line index") from None
    if not 0 <= index < len(lines):
        raise CadError(f"{where}: line index {index} out of range (0..{len(lines) - 1})")
    return lines[index]


def _chain(segments: list[tuple[int, int]], where: str) -> list[int]:
    """Vertex loop of lines that close a polygon (in the order given, either direction each)."""
    loop = list(segments[0])
    if segments[-1][0] in loop[:1] or segments[-1][1] in loop[:1]:
        pass
    for a, b in segments[1:]:
        if a == loop[-1]:
            loop.append(b)
        elif b == loop[-1]:
            loop.append(a)
        elif len(loop) == 2 and a == loop[0]:
            loop = [loop[1], loop[0], b]
        elif len(loop) == 2 and b == loop[0]:
            loop = [loop[1], loop[0], a]
        else:
            raise CadError(f"{where}: the face's lines do not join end to end")
    if loop[-1] != loop[0]:
        raise CadError(f"{where}: the face's lines do not close a loop")
    return loop[:-1]


def _plane_axes(normal: FloatArray) -> tuple[FloatArray, FloatArray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def _ring(geometry: _Geometry, centre: FloatArray, axis: FloatArray, radius: float) -> list[int]:
    u, v = _plane_axes(axis)
    angles = np.arange(ROUND_SEGMENTS) * (2.0 * np.pi / ROUND_SEGMENTS)
    return [geometry.add_vertex(centre + radius * (np.cos(a) * u + np.sin(a) * v)) for a in angles]


def _cylinder(geometry: _Geometry, a: int, b: int, radius: float, where: str) -> None:
    p, q = geometry.vertices[a], geometry.vertices[b]
    axis = q - p
    length = float(np.linalg.norm(axis))
    if length < 1e-9:
        raise CadError(f"{where}: a cylinder's two axis points coincide")
    axis /= length
    low = _ring(geometry, p, axis, radius)
    high = _ring(geometry, q, axis, radius)
    group = geometry.next_group
    geometry.next_group += 1
    for i in range(ROUND_SEGMENTS):
        j = (i + 1) % ROUND_SEGMENTS
        geometry.faces.append([low[i], low[j], high[j], high[i]])  # counter-clockwise from outside
        geometry.groups.append(group)


def _circle(geometry: _Geometry, radius: float, centre: int, p1: int, p2: int, where: str) -> None:
    c = geometry.vertices[centre]
    normal = np.cross(geometry.vertices[p1] - c, geometry.vertices[p2] - c)
    norm = float(np.linalg.norm(normal))
    if norm < 1e-12:
        raise CadError(f"{where}: a circle's three points are collinear (no plane)")
    ring = _ring(geometry, c, normal / norm, radius)
    geometry.lines.extend((ring[i], ring[(i + 1) % ROUND_SEGMENTS]) for i in range(ROUND_SEGMENTS))
