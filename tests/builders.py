"""Messages as tests build them: a small valid patch job (default yaw settings) and a yaw estimate."""

from __future__ import annotations

from typing import Any, TypeVar

import numpy as np

from common.wire.messages import PatchJob, YawEstimate, YawJobSettings
from common.yaw import YawSettings, for_frame

#: the default yaw settings as every job of a 320x240 stream carries them
JOB_SETTINGS = YawJobSettings.of(for_frame(YawSettings(), (240, 320)))

J = TypeVar("J", bound=PatchJob)


def patch_job(
    n: int = 2,
    side: int = 8,
    *,
    cls: type[J] = PatchJob,  # type: ignore[assignment]
    validate: bool = True,
    **fields: Any,
) -> J:
    """A job for patches ``0..n-1`` with blank ``side`` x ``side`` crops and no previous crops; ``fields``
    override any field. ``validate=False`` builds it unchecked (to send what a hostile sender would)."""
    values: dict[str, Any] = {
        "stream": "s",
        "seq": 1,
        "prev_seq": 0,
        "settings": JOB_SETTINGS,
        "indices": np.arange(n, dtype=np.int32),
        "crops": np.zeros((n, side, side), np.uint8),
        "prev_indices": np.zeros(0, np.int32),
        "prev_crops": np.zeros((0, side, side), np.uint8),
        "budget_s": 1.0,
    }
    values.update(fields)
    return cls(**values) if validate else cls.model_construct(**values)


def yaw_estimate(**fields: Any) -> YawEstimate:
    """A measured yaw of frame 0 of ``u`` (40 patches, all inliers); ``fields`` override any field."""
    values: dict[str, Any] = {
        "uav": "u",
        "seq": 0,
        "stamp_s": 0.0,
        "delta_yaw_rad": 0.0,
        "yaw_rad": 0.0,
        "inlier_count": 40,
        "patch_count": 40,
        "confidence": 1.0,
        "low_confidence": False,
        "method": "patch",
    }
    return YawEstimate(**{**values, **fields})


def small_cluster_file(hosts: int) -> str:
    """The cluster file (YAML) of a small ``capataz up`` for ``uav0``: router, camera, master, and a foreman
    and a worker on each of the hosts ``h1`` ... ``h<hosts>``."""
    lines = ["name: small", "topology: master-foreman-worker", "balance: time", "uav: uav0", "hosts:"]
    lines += [f"  - {{name: h{i}, workers: 1}}" for i in range(1, hosts + 1)]
    return "\n".join(lines) + "\n"
