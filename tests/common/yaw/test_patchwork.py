"""A member's share (cached spectra, subsets, previous crops only where needed) equals the in-process core."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pydantic import ValidationError

from common.bounds import field_bounds
from common.camera import CameraModel
from common.dispatch import Dispatcher, DispatchSettings, SpeedSource
from common.errors import InputError
from common.sim.flight import hover_flight
from common.wire.messages import LOCAL_YAW_SETTINGS, YawJobSettings
from common.yaw import FftBackend, YawError, YawSettings, YawTracker, for_frame, make_patch_grid
from common.yaw.measurement import merge_measurements
from common.yaw.patchwork import PatchWorkError, SpectrumCache, measure_share


@pytest.fixture(scope="module")
def frames() -> list[np.ndarray]:
    flight = hover_flight(seed=3, n_frames=8)
    return [flight.frame(i) for i in range(8)]


def test_settings_round_trip_and_rejects_unknown_or_wrong_types() -> None:
    settings = YawSettings(grid_cols=10, fft_backend=FftBackend.NUMPY, peak_sigma_px=1.5, pyramid_level=2)
    wire = YawJobSettings.of(settings)
    assert YawJobSettings.model_validate(wire.model_dump(mode="json")).yaw_settings == settings
    for name, value in [("colour", 1), ("grid_cols", "ten"), ("grid_cols", True), ("fft_backend", "cuda"),
                        ("peak_sigma_px", "1.5"), ("patch_size_px", 30.0)]:  # fmt: skip
        with pytest.raises(ValidationError, match=name):
            YawJobSettings.model_validate({**wire.model_dump(mode="json"), name: value})
    with pytest.raises(ValidationError, match="invalid yaw settings"):  # bounded, but not a valid YawSettings
        YawJobSettings.model_validate({**wire.model_dump(mode="json"), "patch_size_px": 9})


def test_the_job_settings_carry_every_yaw_setting_but_the_lens() -> None:
    core = {f.name for f in dataclasses.fields(YawSettings)}
    assert set(YawJobSettings.model_fields) == core - LOCAL_YAW_SETTINGS
    lens = YawSettings(camera=CameraModel.default(), pyramid_level=1)
    assert YawJobSettings.of(lens).yaw_settings == YawSettings(pyramid_level=1)


def test_a_job_states_the_pyramid_level_resolved_for_its_frames() -> None:
    """The default level follows the frame's size; the master resolves it per stream, so a job that left it
    open would leave the members to guess: refused, on both sides."""
    with pytest.raises(InputError, match="resolve"):
        YawJobSettings.of(YawSettings())
    wire = YawJobSettings.of(for_frame(YawSettings(), (720, 1280))).model_dump(mode="json")
    assert wire["pyramid_level"] == 2
    with pytest.raises(ValidationError, match="pyramid_level"):
        YawJobSettings.model_validate({**wire, "pyramid_level": None})


def test_the_job_settings_bounds_are_the_core_settings_bounds() -> None:
    """One home: the wire's limits are YawSettings' (generated), so the two refuse the same values."""
    wire = YawJobSettings.of(YawSettings(pyramid_level=1)).model_dump(mode="json")
    checked = 0
    for name, limits in field_bounds(YawSettings).items():
        integer = isinstance(wire[name], int)
        step = 1 if integer else 1e-3
        outside = {"gt": limits.gt, "lt": limits.lt}  # the open limit itself is outside
        if limits.ge is not None:
            outside["ge"] = limits.ge - step
        if limits.le is not None:
            outside["le"] = limits.le + step * (1 if integer else max(1.0, limits.le))
        for value in (v for v in outside.values() if v is not None):
            value = int(value) if integer else float(value)
            with pytest.raises(ValidationError, match=name):
                YawJobSettings.model_validate({**wire, name: value})
            with pytest.raises(InputError, match=name):
                YawSettings(**{name: value})  # type: ignore[arg-type]
            checked += 1
    assert checked > 40


@pytest.mark.parametrize("backend", list(FftBackend))
def test_sticky_shares_through_members_equal_the_in_process_tracker_bit_for_bit(
    frames: list[np.ndarray], backend: FftBackend
) -> None:
    settings = YawSettings(fft_backend=backend)
    settings = for_frame(settings, frames[0].shape)
    grid = make_patch_grid(frames[0].shape, settings)
    tracker = YawTracker(settings, grid)
    reference = tracker.initial_state(frames[0])
    cluster = tracker.initial_state(frames[0], with_spectra=False)
    dispatcher = Dispatcher(
        DispatchSettings(speed_source=SpeedSource.REPORTED, ema_alpha=1.0), grid.n_patches
    )
    caches = {name: SpectrumCache() for name in ("a", "b", "c", "self")}
    for name in ("a", "b", "c"):
        dispatcher.join(name)
    for k in range(1, len(frames)):
        if k == 4:
            dispatcher.leave("b")  # its patches move: the receivers get previous crops
        plan = dispatcher.plan(k, k - 1, 0.0)
        level, prev_level = grid.level_image(frames[k]), grid.level_image(frames[k - 1])
        parts = []
        for member, idx in plan.assignment.items():
            moved = plan.moved[member]
            parts.append(measure_share(
                caches[member], settings, "uav", k, k - 1, idx, grid.crop_level(level, idx),
                moved, grid.crop_level(prev_level, moved),
            ))  # fmt: skip
            dispatcher.record_success(member, k, idx, 0.01, reported_speed=1000.0 * (1 + len(member) + k % 2))
        measurement = merge_measurements(parts, grid.all_indices)
        reference, expected = tracker.track(reference, frames[k])
        cluster, got = tracker.conclude(cluster, frames[k], measurement)
        assert got.yaw_rad == expected.yaw_rad
        assert got.delta_yaw_rad == expected.delta_yaw_rad
        assert got.inlier_count == expected.inlier_count


def test_missing_previous_spectra_is_an_error_naming_the_patches(frames: list[np.ndarray]) -> None:
    settings = YawSettings()
    settings = for_frame(settings, frames[0].shape)
    grid = make_patch_grid(frames[0].shape, settings)
    idx = np.array([0, 1, 2])
    crops = grid.crop(frames[1], idx)
    with pytest.raises(PatchWorkError, match=r"patches \[0, 1, 2\]"):
        measure_share(SpectrumCache(), settings, "s", 1, 0, idx, crops, idx[:0], crops[:0])


def test_merge_rejects_gaps_and_overlaps(frames: list[np.ndarray]) -> None:
    settings = YawSettings()
    settings = for_frame(settings, frames[0].shape)
    grid = make_patch_grid(frames[0].shape, settings)
    cache = SpectrumCache()
    idx = np.array([0, 1])
    part = measure_share(
        cache, settings, "s", 1, 0, idx, grid.crop(frames[1], idx), idx, grid.crop(frames[0], idx)
    )
    with pytest.raises(YawError):
        merge_measurements([part], np.arange(3))
    with pytest.raises(YawError):
        merge_measurements([part, part], np.arange(2))


def test_cache_keeps_only_the_newest_frame_and_bounded_streams() -> None:
    settings = YawSettings(pyramid_level=1)
    cache = SpectrumCache(max_streams=2)
    grid = make_patch_grid((480, 752), settings)
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 255, (480, 752), dtype=np.uint8)
    idx = np.array([4, 5])
    for stream in ("x", "y", "z"):
        measure_share(cache, settings, stream, 1, 0, idx, grid.crop(frame, idx), idx, grid.crop(frame, idx))
    assert cache.held("x") == (-2, frozenset())
    assert cache.held("z") == (1, frozenset({4, 5}))


def test_cache_hands_back_the_previous_share_whole_only_for_the_same_indices(
    frames: list[np.ndarray],
) -> None:
    settings = YawSettings()
    settings = for_frame(settings, frames[0].shape)
    grid = make_patch_grid(frames[0].shape, settings)
    cache = SpectrumCache()
    share = np.array([3, 4, 5])
    crops = grid.crop(frames[0], share)
    measure_share(cache, settings, "s", 0, -1, share, crops, share, crops)
    whole, missing = cache.lookup("s", 0, [3, 4, 5])
    assert missing == [] and whole is not None
    subset, _ = cache.lookup("s", 0, [5, 3])  # another order or subset: rows stacked anew
    assert subset is not None and subset.indices.tolist() == [5, 3]
    assert np.array_equal(subset.spectra[0], whole.spectra[2]) and np.array_equal(
        subset.spectra[1], whole.spectra[0]
    )
    # a second share of the same frame (a re-dispatch) joins the cache; the three still come back right
    extra = np.array([6])
    measure_share(
        cache, settings, "s", 0, -1, extra, grid.crop(frames[0], extra), extra, grid.crop(frames[0], extra)
    )
    again, _ = cache.lookup("s", 0, [3, 4, 5])
    assert again is not None and np.array_equal(again.spectra, whole.spectra)
    four, missing = cache.lookup("s", 0, [3, 4, 5, 6])
    assert missing == [] and four is not None and four.indices.tolist() == [3, 4, 5, 6]


def test_single_part_merge_is_sorted_and_checked(frames: list[np.ndarray]) -> None:
    settings = YawSettings()
    settings = for_frame(settings, frames[0].shape)
    grid = make_patch_grid(frames[0].shape, settings)
    idx = np.array([2, 0, 1])
    part = measure_share(
        SpectrumCache(), settings, "s", 1, 0, idx, grid.crop(frames[1], idx), idx, grid.crop(frames[0], idx)
    )
    merged = merge_measurements([part], np.arange(3))
    assert merged.indices.tolist() == [0, 1, 2]
    assert np.array_equal(merged.shift_px, part.shift_px[[1, 2, 0]])
    in_order = merge_measurements([merged], np.arange(3))
    assert np.array_equal(in_order.shift_px, merged.shift_px) and in_order.indices.tolist() == [0, 1, 2]
