"""TUM trajectories: one pose per line, ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, unit
quaternion with the scalar LAST, as the TUM RGB-D benchmark and evo's ``file_interface`` expect).

capataz keeps quaternions scalar first (``q_world_body = [w, x, y, z]``); the reader and writer convert.
Values are written with ``repr`` precision, so a file reads back to the same floats.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import quaternion_from_euler
from common.types import FloatArray


class TumError(InputError):
    """A TUM file or trajectory is malformed (wrong column count, non-finite value, non-unit quaternion)."""


@dataclass(frozen=True)
class Trajectory:
    """Stamped poses of the body in the world: stamps (N,) s, positions (N, 3) m, quaternions (N, 4) wxyz."""

    stamps_s: FloatArray
    p_world_body_m: FloatArray
    q_world_body: FloatArray

    def __post_init__(self) -> None:
        n = self.stamps_s.shape[0] if self.stamps_s.ndim == 1 else -1
        if n < 0 or self.p_world_body_m.shape != (n, 3) or self.q_world_body.shape != (n, 4):
            raise TumError(
                f"trajectory needs stamps (N,), positions (N, 3), quaternions (N, 4); got "
                f"{self.stamps_s.shape}, {self.p_world_body_m.shape}, {self.q_world_body.shape}"
            )
        for name in ("stamps_s", "p_world_body_m", "q_world_body"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise TumError(f"trajectory {name} has NaN or inf")
        if n and not np.allclose(np.linalg.norm(self.q_world_body, axis=1), 1.0, atol=1e-6):
            raise TumError("trajectory quaternions must be unit quaternions")

    def __len__(self) -> int:
        return int(self.stamps_s.shape[0])

    @classmethod
    def from_yaw(cls, stamps_s: npt.ArrayLike, yaw_rad: npt.ArrayLike) -> Trajectory:
        """A rotation-only trajectory (position 0) of yaw angles about the world z axis."""
        yaw = np.asarray(yaw_rad, dtype=np.float64)
        zeros = np.zeros_like(yaw)
        return cls(
            np.asarray(stamps_s, dtype=np.float64),
            np.zeros((yaw.size, 3)),
            np.atleast_2d(quaternion_from_euler(zeros, zeros, yaw)).reshape(-1, 4),
        )


def format_pose(stamp_s: float, p_m: npt.ArrayLike, q_wxyz: npt.ArrayLike) -> str:
    """One TUM line (``repr`` precision)."""
    p = np.asarray(p_m, dtype=np.float64)
    q = np.asarray(q_wxyz, dtype=np.float64)
    values = (stamp_s, p[0], p[1], p[2], q[1], q[2], q[3], q[0])
    return " ".join(repr(float(v)) for v in values)


def write_tum(path: Path, trajectory: Trajectory) -> Path:
    """Write ``trajectory`` to ``path`` (parents created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [
        format_pose(float(t), p, q)
        for t, p, q in zip(
            trajectory.stamps_s, trajectory.p_world_body_m, trajectory.q_world_body, strict=True
        )
    ]
    path.write_text("# timestamp tx ty tz qx qy qz qw\n" + "".join(line + "\n" for line in lines))
    return path


def read_tum(path: Path) -> Trajectory:
    """Read a TUM file (``#`` comments and blank lines skipped); TumError naming the bad line."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise TumError(f"{path}: cannot be read ({exc})") from None
    rows: list[list[float]] = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 8:
            raise TumError(
                f"{path}:{line_no}: expected 8 columns (timestamp tx ty tz qx qy qz qw), got {len(parts)}"
            )
        try:
            rows.append([float(v) for v in parts])
        except ValueError:
            raise TumError(f"{path}:{line_no}: not numbers") from None
    data = np.array(rows, dtype=np.float64).reshape(-1, 8)
    return Trajectory(data[:, 0].copy(), data[:, 1:4].copy(), data[:, [7, 4, 5, 6]].copy())


class TumWriter:
    """Appends one pose per line as estimates arrive (a service's ``--trajectory FILE``); flushed per line,
    so a file read while the service runs (or after a kill) holds every complete pose."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._file: IO[str] | None = self.path.open("w")
        except OSError as exc:
            raise TumError(f"--trajectory {self.path}: cannot be written ({exc})") from None
        self._file.write("# timestamp tx ty tz qx qy qz qw\n")
        self.count = 0
        self._lock = threading.Lock()

    def write(self, stamp_s: float, p_m: npt.ArrayLike, q_wxyz: npt.ArrayLike) -> None:
        line = format_pose(stamp_s, p_m, q_wxyz) + "\n"
        with self._lock:
            if self._file is None:
                return
            self._file.write(line)
            self._file.flush()
            self.count += 1

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None
