"""The built-in office: a 10 x 8 x 3 m room, doors, windows, pictures and furniture boxes (about 280 edges).

Decals (doors, windows, pictures) are faces a centimetre in front of a wall with another albedo.
:class:`SceneBuilder` accumulates oriented quads and boxes; the object-scale simulator scene uses it too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from common.camera import CameraModel
from common.localization.model import SceneModel, build_scene, newell_normal

#: The office's default camera, 320x240 with a 70 deg horizontal field of view: what its simulated flight
#: renders, and what the localizer assumes when it is given no camera.
OFFICE_WIDTH_PX = 320
OFFICE_HEIGHT_PX = 240
OFFICE_HFOV_DEG = 70.0
#: The first body state (x, y, z in m; roll, pitch, yaw in rad) of the office's default flight: where the
#: localizer starts when it is given no start pose (tests/common/sim checks it against the simulated flight).
OFFICE_START_STATE: tuple[float, float, float, float, float, float] = (
    7.2, 4.0, 1.5, 0.0, math.radians(2.0), math.radians(50.0)
)  # fmt: skip


def office_camera() -> CameraModel:
    """The office's default camera: :data:`OFFICE_WIDTH_PX` x :data:`OFFICE_HEIGHT_PX` pixels,
    :data:`OFFICE_HFOV_DEG` wide."""
    return CameraModel.from_hfov(OFFICE_WIDTH_PX, OFFICE_HEIGHT_PX, OFFICE_HFOV_DEG)


class SceneBuilder:
    """Accumulates oriented quads for the built-in scene."""

    def __init__(self) -> None:
        self.vertices: list[list[float]] = []
        self.faces: list[list[int]] = []
        self.albedo: list[float] = []

    def quad(self, corners: Sequence[Sequence[float]], towards: Sequence[float], albedo: float) -> None:
        """Add a quad whose visible side faces the direction ``towards``."""
        pts = np.asarray(corners, dtype=np.float64)
        if float(newell_normal(pts) @ np.asarray(towards, dtype=np.float64)) < 0.0:
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
    b = SceneBuilder()
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
