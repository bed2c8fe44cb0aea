"""Every value a sender chooses is bounded at the wire: a refusal, never an exit or unbounded memory."""

from __future__ import annotations

import numpy as np
import pytest

from common.streams import StreamTable
from common.wire.codec import decode, encode
from common.wire.messages import PatchJob
from common.wire.schema import MAX_BUDGET_S, MAX_JOB_PATCHES, WireError
from common.yaw import YawSettings, for_frame
from common.yaw.correlation import patch_spectra_from_crops
from common.yaw.patchwork import SpectrumCache
from tests.builders import JOB_SETTINGS, patch_job


@pytest.mark.parametrize(
    ("name", "value"),
    [("patch_size_px", 100_000), ("patch_size_px", 1024), ("grid_cols", 10_000), ("global_size_px", 6144),
     ("ransac_max_iters", 10**9), ("global_angle_bins", 10**7)],
)  # fmt: skip
def test_oversized_yaw_settings_in_a_job_are_refused_before_any_allocation(name: str, value: int) -> None:
    settings = {**JOB_SETTINGS.model_dump(mode="json"), name: value}
    payload, header = encode(patch_job(validate=False, settings=settings))
    with pytest.raises(WireError, match=f"settings.{name}"):
        decode(payload, header, PatchJob)
    default = for_frame(YawSettings(), (240, 320))
    assert decode(*encode(patch_job()), PatchJob).settings.yaw_settings == default


def _job(n: int, side: int = 32, stream: str = "uav0") -> PatchJob:
    return patch_job(n, side, validate=False, stream=stream)


@pytest.mark.parametrize(
    ("job", "match"),
    [(_job(MAX_JOB_PATCHES + 1, 8), "patches"), (_job(1, 1024), "square"),
     (_job(40, stream="x" * 65), "stream"), (_job(400, 256), "pixels"),
     (patch_job(40, validate=False, budget_s=MAX_BUDGET_S * 100), "budget_s")],
)  # fmt: skip
def test_oversized_jobs_are_refused_at_decode(job: PatchJob, match: str) -> None:
    payload, header = encode(job)
    with pytest.raises(WireError, match=match):
        decode(payload, header, PatchJob)
    payload, header = encode(_job(40))
    assert decode(payload, header, PatchJob).indices.size == 40


def test_thousands_of_stream_names_keep_the_per_stream_state_bounded() -> None:
    table: StreamTable[list[int]] = StreamTable(max_streams=64, max_age_s=60.0)
    for k in range(5000):
        table.get(f"s{k}", now_s=k * 0.001, create=list)
    assert len(table) == 64 and table.evicted == 5000 - 64
    table.get("late", now_s=1000.0, create=list)  # every other stream is older than the age bound
    assert len(table) == 1
    cache = SpectrumCache(max_streams=8, max_age_s=60.0)
    spectra = patch_spectra_from_crops(np.zeros((2, 32, 32), np.uint8), [0, 1], YawSettings())
    for k in range(1000):
        cache.store(f"s{k}", 1, spectra)
    assert len(cache) == 8


def test_a_restarted_stream_replaces_its_cached_spectra_instead_of_being_ignored() -> None:
    """Regression (a seq of 2**53 or a camera restart left a member ignoring the stream's real frames)."""
    cache = SpectrumCache()
    spectra = patch_spectra_from_crops(np.zeros((2, 32, 32), np.uint8), [0, 1], YawSettings())
    cache.store("uav0", 2**53, spectra)
    cache.store("uav0", 5, spectra)
    assert cache.held("uav0") == (5, frozenset({0, 1}))
