"""The whole system under the secure profile (mutual TLS + access control on every participant) gives the
results of the open profile, in the same run: the yaw cluster, the estimator (uav0) and the localizer (uav1,
office flight).

Yaw: every frame, equal to the in-process tracker in both profiles (so equal to each other); estimator:
attitude within 2 deg of the truth in roll and pitch, pose/vo published; localizer: ``pose/pf`` within 10 cm
of the truth at the end. Every participant holds only its own role's certificate.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from services.tools.bench.secure_system import compare, run_system

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

FRAMES = 80


def test_cluster_estimator_and_localizer_give_the_same_results_open_and_secure(tmp_path: Path) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (needed to make the development certificates)")
    runs = {profile: run_system(profile, tmp_path, FRAMES) for profile in ("open", "secure")}
    report = compare(runs)
    for profile in ("open", "secure"):
        assert report[profile]["failed_bounds"] == [], (profile, report[profile])
    both = report["secure_vs_open"]
    assert both["yaw_frames_compared"] == FRAMES
    assert both["yaw_max_difference_rad"] < 1e-9
    assert both["same_results"]
