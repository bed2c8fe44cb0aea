"""The cluster benchmark's frame folders."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from services.bench.cluster import write_frame_folder


def test_frame_folder_holds_only_this_runs_frames(tmp_path: Path) -> None:
    """Regression: a longer earlier run's frames stayed in the folder, so the camera replayed them too and
    the overhead run reported a negative number of lost frames."""
    rng = np.random.default_rng(0)
    write_frame_folder(tmp_path, [rng.integers(0, 255, (8, 8), dtype=np.uint8) for _ in range(5)])
    frames = [rng.integers(0, 255, (8, 8), dtype=np.uint8) for _ in range(3)]
    write_frame_folder(tmp_path, frames)
    files = sorted(tmp_path.glob("*.pgm"))
    assert [f.name for f in files] == ["00000.pgm", "00001.pgm", "00002.pgm"]
    for path, frame in zip(files, frames, strict=True):
        assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), frame)
