"""Regression: after a camera restart (its frames count from 0 again) the foreman kept the old run's
higher frame numbers and silently refused every new frame's crops, so each moved share failed with
"no crops of frame N" and the master suspended honest foremen (seen in the hostile-participant suite,
where those suspensions also handed work to the attackers)."""

from __future__ import annotations

import numpy as np

from common.yaw.patchwork import CropStore


def test_crop_store_after_a_camera_restart_regression() -> None:
    store = CropStore()
    for seq in (198, 199):  # the end of the previous run
        store.add("uav0", seq, np.array([0, 1]), np.full((2, 4, 4), seq % 256, dtype=np.uint8))
    store.add("uav0", 0, np.array([0, 1]), np.full((2, 4, 4), 7, dtype=np.uint8))  # the new run
    store.add("uav0", 1, np.array([0, 1]), np.full((2, 4, 4), 8, dtype=np.uint8))
    assert store.get("uav0", 0, np.array([1]), (4, 4))[0, 0, 0] == 7
    assert store.get("uav0", 1, np.array([0]), (4, 4))[0, 0, 0] == 8
