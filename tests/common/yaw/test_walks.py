"""A frame's walk through the in-process yaw core (``YawTracker.track``): no module entered more than twice,
the frame checked once (measured with :func:`tests.walks.walk`)."""

from __future__ import annotations

from common.geometry import matrix_from_euler
from common.sim.flight import hover_flight
from common.yaw import YawSettings, YawTracker, for_frame, make_patch_grid
from tests.walks import entries_per_module, walk


def test_a_tracked_frame_enters_no_module_more_than_twice_and_is_checked_once() -> None:
    flight = hover_flight(seed=0, n_frames=3)
    settings = YawSettings()
    settings = for_frame(settings, flight.frame(0).shape)
    tracker = YawTracker(settings, make_patch_grid(flight.frame(0).shape, settings))
    state = tracker.initial_state(flight.frame(0), stamp_s=0.0)
    state, _ = tracker.track(state, flight.frame(1), stamp_s=0.05)  # the steady state: spectra cached
    frame = flight.frame(2)
    entries = walk(lambda: tracker.track(state, frame, stamp_s=0.1))
    counts = entries_per_module(entries)
    assert counts["common/yaw/tracker.py"] >= 1 and counts["common/yaw/fit.py"] >= 1, entries  # it measured
    assert max(counts.values()) <= 2, counts
    assert counts["common/images.py"] == 1, entries
    assert counts["common/yaw/grid.py"] == 1, entries


def test_the_walk_counts_entries_from_another_module_not_calls_within_one() -> None:
    """The measure itself: consecutive calls within one module are one entry, a return to a module is none,
    every call into it after a call into another module is one."""
    settings = YawSettings()
    grid = make_patch_grid((480, 752), settings)
    assert walk(lambda: (grid.n_patches, grid.all_indices, grid.n_patches)) == ["common/yaw/grid.py"]
    fresh = YawSettings(pyramid_level=1)  # its scale not computed yet
    entries = walk(lambda: (grid.n_patches, fresh.scale, grid.n_patches))
    assert entries == ["common/yaw/grid.py", "common/yaw/settings.py", "common/yaw/grid.py"]
    assert entries_per_module(entries) == {"common/yaw/grid.py": 2, "common/yaw/settings.py": 1}
    assert walk(lambda: sorted([3, 1, 2])) == []  # outside the project: no entry


def test_a_levelled_frame_of_a_calibrated_camera_enters_no_module_more_than_twice() -> None:
    """The same walk with the lens's intrinsics and each frame's tilt (:mod:`common.yaw.level`)."""
    flight = hover_flight(seed=0, n_frames=3)
    settings = for_frame(YawSettings(camera=flight.camera), flight.frame(0).shape)
    tracker = YawTracker(settings, make_patch_grid(flight.frame(0).shape, settings))
    tilt = matrix_from_euler(0.05, -0.03, 0.0)
    state = tracker.initial_state(flight.frame(0), stamp_s=0.0, R_level_body=tilt)
    state, _ = tracker.track(state, flight.frame(1), stamp_s=0.05, R_level_body=tilt)
    frame = flight.frame(2)
    entries = walk(lambda: tracker.track(state, frame, stamp_s=0.1, R_level_body=tilt))
    counts = entries_per_module(entries)
    assert counts["common/yaw/level.py"] == 1, entries  # it levelled
    assert max(counts.values()) <= 2, counts
