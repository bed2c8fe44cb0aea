from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.sim.ground import GroundTexture, homography_between_views, nadir_camera_pose, render_ground_view
from common.yaw import (
    FftBackend,
    PatchMeasurement,
    YawError,
    YawSettings,
    correlation,
    for_frame,
    make_patch_grid,
    measure_patches,
    merge_measurements,
    patch_spectra,
    patch_spectra_from_crops,
)
from common.yaw.fit import transfer_error_px

from .conftest import ALTITUDE_M


def _measure(
    a: np.ndarray, b: np.ndarray, settings: YawSettings, indices: list[int] | None = None
) -> PatchMeasurement:
    settings = for_frame(settings, a.shape)
    grid = make_patch_grid(a.shape, settings)
    return measure_patches(
        patch_spectra(a, grid, indices, settings), patch_spectra(b, grid, indices, settings), settings
    )


def _translated_pair(
    texture: GroundTexture, camera: CameraModel, move_m: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pose_a = nadir_camera_pose(0.1, 0.2, ALTITUDE_M, 0.3)
    pose_b = nadir_camera_pose(0.1 + move_m[0], 0.2 + move_m[1], ALTITUDE_M, 0.3)
    a = render_ground_view(texture, camera, *pose_a)
    b = render_ground_view(texture, camera, *pose_b)
    return a, b, homography_between_views(camera, *pose_a, *pose_b)


@pytest.mark.parametrize("backend", list(FftBackend))
def test_shifts_match_the_true_motion_at_every_patch(
    texture: GroundTexture, camera: CameraModel, backend: FftBackend
) -> None:
    a, b, H_b_a = _translated_pair(texture, camera, (0.0123, -0.0087))  # about 3 and 2 px
    settings = YawSettings(fft_backend=backend, pyramid_level=1)
    grid = make_patch_grid(a.shape, settings)
    m = _measure(a, b, settings)
    assert m.valid.all()
    expected_error = transfer_error_px(H_b_a, grid.centres_px, grid.centres_px + m.shift_px)
    assert np.max(expected_error) < 0.15, expected_error  # full-resolution px, measured at level 1
    assert np.mean(expected_error) < 0.05
    assert np.all(m.confidence > 3.0)


def test_crops_give_the_same_spectra_bit_for_bit_for_any_subset(
    texture: GroundTexture, camera: CameraModel
) -> None:
    a, b, _ = _translated_pair(texture, camera, (0.01, 0.004))
    settings = YawSettings()
    settings = for_frame(settings, a.shape)
    grid = make_patch_grid(a.shape, settings)
    full_a = patch_spectra(a, grid, None, settings)
    full_b = patch_spectra(b, grid, None, settings)
    full = measure_patches(full_a, full_b, settings)
    subsets = [np.array([5, 1, 30]), np.arange(10, 20), np.array([39])]
    parts = []
    for idx in subsets:
        from_crops = patch_spectra_from_crops(grid.crop(a, idx), idx, settings)
        assert np.array_equal(from_crops.spectra, full_a.spectra[idx])
        assert np.array_equal(from_crops.texture_std, full_a.texture_std[idx])
        part = measure_patches(from_crops, patch_spectra(b, grid, idx, settings), settings)
        assert np.array_equal(part.shift_px, full.shift_px[idx])
        parts.append(part)
    merged = merge_measurements(parts[::-1])
    assert np.array_equal(merged.indices, np.sort(np.concatenate(subsets)))
    assert np.array_equal(merged.shift_px, full.shift_px[merged.indices])


def test_textureless_patches_are_rejected(texture: GroundTexture, camera: CameraModel) -> None:
    a, b, _ = _translated_pair(texture, camera, (0.01, 0.0))
    a, b = a.copy(), b.copy()
    a[:, :200] = 128  # a flat strip: the left columns of patches see nothing
    b[:, :200] = 128
    settings = YawSettings()
    settings = for_frame(settings, a.shape)
    grid = make_patch_grid(a.shape, settings)
    m = _measure(a, b, settings)
    inside_flat = grid.centres_px[:, 0] + settings.patch_size_px * settings.scale / 2 < 200
    assert inside_flat.sum() >= 5
    assert not m.valid[inside_flat].any()
    assert np.all(m.confidence[inside_flat] == 0.0)
    assert m.valid[grid.centres_px[:, 0] > 260].all()


def test_backends_agree(texture: GroundTexture, camera: CameraModel) -> None:
    a, b, _ = _translated_pair(texture, camera, (-0.007, 0.011))
    shifts = []
    for backend in FftBackend:
        settings = YawSettings(fft_backend=backend)
        settings = for_frame(settings, a.shape)
        grid = make_patch_grid(a.shape, settings)
        sa, sb = patch_spectra(a, grid, None, settings), patch_spectra(b, grid, None, settings)
        shifts.append(measure_patches(sa, sb, settings).shift_px)
    for other in shifts[1:]:
        assert np.max(np.abs(other - shifts[0])) < 1e-3


def test_mismatched_spectra_raise_yaw_error(texture: GroundTexture, camera: CameraModel) -> None:
    a, b, _ = _translated_pair(texture, camera, (0.0, 0.0))
    settings = YawSettings()
    settings = for_frame(settings, a.shape)
    grid = make_patch_grid(a.shape, settings)
    with pytest.raises(YawError, match="same patch indices"):
        measure_patches(
            patch_spectra(a, grid, [0, 1], settings), patch_spectra(b, grid, [0, 2], settings), settings
        )
    other = YawSettings(fft_backend=FftBackend.OPENCV)  # full spectra where the settings expect half ones
    with pytest.raises(YawError):
        measure_patches(
            patch_spectra(a, grid, [0, 1], other), patch_spectra(b, grid, [0, 1], other), settings
        )
    part = _measure(a, b, settings, [0])
    with pytest.raises(YawError, match="overlap"):
        merge_measurements([part, part])


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(1, 13),
    size=st.sampled_from([8, 16, 32]),
    run_pixels=st.sampled_from([1, 256, 1024, 4096, 1 << 17]),
    seed=st.integers(0, 2**16),
    backend=st.sampled_from(list(FftBackend)),
)
def test_patches_in_runs_give_the_bits_of_one_batch(
    n: int, size: int, run_pixels: int, seed: int, backend: FftBackend
) -> None:
    """The core windows, transforms and correlates a frame's patches in runs of FFT_RUN_PIXELS (faster for
    large patches, capataz bench fft); each patch's spectrum and shift must not depend on the run it falls
    in."""
    rng = np.random.default_rng(seed)
    crops = rng.integers(0, 256, (2, n, size, size), dtype=np.uint8)
    yaw_settings = YawSettings(patch_size_px=size, fft_backend=backend, pyramid_level=1)
    indices = np.arange(n)

    def spectra_and_shifts() -> tuple[np.ndarray, np.ndarray]:
        previous, current = (patch_spectra_from_crops(c, indices, yaw_settings) for c in crops)
        return current.spectra, measure_patches(previous, current, yaw_settings).shift_px

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(correlation, "FFT_RUN_PIXELS", 1 << 30)  # one run: the whole batch
        batch = spectra_and_shifts()
        patch.setattr(correlation, "FFT_RUN_PIXELS", run_pixels)
        run = max(1, run_pixels // (size * size))
        expected = [(i, min(i + run, n)) for i in range(0, n, run)]
        assert [(p.start, p.stop) for p in correlation.run_slices(n, size)] == expected
        runs = spectra_and_shifts()
    np.testing.assert_array_equal(runs[0], batch[0])
    np.testing.assert_array_equal(runs[1], batch[1])
