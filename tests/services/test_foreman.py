"""The foreman's crop store: previous-frame crops stay available for a second block of the same frame."""

from __future__ import annotations

import numpy as np
import pytest

from common.dispatch.patchwork import PatchWorkError
from services.foreman.service import CropStore


def crops(value: int, n: int) -> np.ndarray:
    return np.full((n, 4, 4), value, dtype=np.uint8)


def test_a_second_block_of_a_frame_still_finds_the_previous_frame() -> None:
    store = CropStore()
    store.add("s", 4, np.array([0, 1]), crops(4, 2))
    store.add("s", 5, np.array([0, 1]), crops(5, 2))  # first block of frame 5 done
    store.add("s", 4, np.array([7]), crops(40, 1))  # re-dispatched block of frame 5 brings its frame-4 crops
    got = store.get("s", 4, np.array([7, 0]), (4, 4))
    assert got[0, 0, 0] == 40 and got[1, 0, 0] == 4
    store.add("s", 6, np.array([0]), crops(6, 1))
    with pytest.raises(PatchWorkError, match="frame 4"):
        store.get("s", 4, np.array([0]), (4, 4))
    with pytest.raises(PatchWorkError, match="patch 3"):
        store.get("s", 5, np.array([3]), (4, 4))
    assert store.get("s", 6, np.array([], dtype=np.int64), (4, 4)).shape == (0, 4, 4)
