"""How the master sends a share's new-frame pixels (:func:`services.runtime.round.job_band`): a band of the
level image where it is fewer pixels than the crops; otherwise the crops as they are (``mono8``) or side by
side, compressed (``zstd``). The member's crops are the sender's bit for bit either way."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from common.wire.codec import decode, encode
from common.wire.messages import BlockJob, YawJobSettings
from common.yaw import YawSettings, make_patch_grid
from services.runtime.round import job_band
from tests.builders import patch_job
from tests.common.test_job_band import HEAVY, _level


@settings(max_examples=20, deadline=None)
@given(
    picks=st.sets(st.integers(0, 191), min_size=1, max_size=60), encoding=st.sampled_from(["mono8", "zstd"])
)
def test_a_scattered_share_travels_as_crops_or_as_a_compressed_mosaic(picks: set[int], encoding: str) -> None:
    """Where a share's band would be more pixels than its crops: mono8 sends the crops as they are; zstd
    compresses them side by side (a scattered share crosses a thin link compressed too). Either way the
    member's crops are the sender's bit for bit."""
    grid = make_patch_grid((1080, 1920), HEAVY)
    level = np.asarray(np.add.outer(np.arange(1080), np.arange(1920)) // 7 % 256, np.uint8)
    indices = np.array(sorted(picks))
    got = job_band(grid, level, encoding, indices)
    if grid.band_level(level, indices) is not None:
        assert got is not None and got.encoding == encoding
    elif encoding == "mono8":
        assert got is None
        return
    assert got is not None
    side = grid.patch_size_px
    job = patch_job(
        int(indices.size), side, cls=BlockJob, validate=False, indices=indices.astype(np.int32),
        crops=np.zeros((0, side, side), np.uint8), band=got.data, band_shape=got.shape,
        band_encoding=got.encoding, corners=got.corners.astype(np.int32), settings=YawJobSettings.of(HEAVY),
    )  # fmt: skip
    decoded = decode(*encode(job), BlockJob)
    assert np.array_equal(decoded.crops, grid.crop_level(level, indices))
    if encoding == "zstd":  # smooth pixels: compressed, fewer bytes than the raw crops
        assert got.data.size < indices.size * side * side


def test_patches_apart_send_crops_in_mono8_without_cutting_a_band() -> None:
    apart = make_patch_grid((480, 752), YawSettings(pyramid_level=1))
    level = _level(apart, 3)
    assert job_band(apart, level, "mono8", apart.all_indices) is None
    mosaic = job_band(apart, level, "zstd", apart.all_indices)
    assert mosaic is not None and mosaic.corners.shape == (apart.n_patches, 2)


def test_a_lower_jpeg_quality_sends_fewer_bytes_and_the_same_corners() -> None:
    """``--job-quality``: the master's JPEG quality reaches the share's band (75: fewer bytes than the
    default 90), cut the same way."""
    grid = make_patch_grid((1080, 1920), HEAVY)
    level = np.asarray(np.add.outer(np.arange(1080), np.arange(1920)) * 37 // 5 % 251, np.uint8)
    indices = np.arange(40, 88)
    default = job_band(grid, level, "jpeg", indices)
    lower = job_band(grid, level, "jpeg", indices, quality=75)
    assert default is not None and lower is not None
    assert lower.data.size < default.data.size
    assert np.array_equal(lower.corners, default.corners) and lower.shape == default.shape
