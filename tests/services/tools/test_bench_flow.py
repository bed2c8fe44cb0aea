from __future__ import annotations

import argparse

import numpy as np

from services.tools.bench import flow


def test_the_band_limited_truth_is_the_same_texture_shifted() -> None:
    a, b = flow.band_limited_pair(3, np.array([2.0, -1.0]), size_px=64)
    assert a.dtype == np.uint8 and a.shape == (64, 64)
    # a whole-pixel shift in the Fourier domain is a periodic roll, to the 8-bit rounding
    rolled = np.roll(a, shift=(-1, 2), axis=(0, 1)).astype(int)
    assert np.max(np.abs(b.astype(int) - rolled)) <= 1
    assert np.mean(b.astype(int) == rolled) > 0.99


def test_the_flow_bench_reads_a_whole_pixel_shift_with_both_trackers_on_both_generators() -> None:
    parser = argparse.ArgumentParser()
    flow.add_arguments(parser)
    result = flow.run(parser.parse_args(["--shifts", "1.0", "0.05", "--pairs", "2"]))
    rows = {(r["tracker"], r["generator"], r["shift_px"]): r for r in result["table"]}
    assert set(rows) == {(t, g, s) for t in flow.TRACKERS for g in flow.GENERATORS for s in (1.0, 0.05)}
    for tracker in flow.TRACKERS:
        for generator in flow.GENERATORS:
            whole = rows[(tracker, generator, 1.0)]
            assert abs(whole["ratio"] - 1.0) < 0.05, whole
            assert abs(whole["across_px"]) < 0.02, whole
            assert np.isfinite(rows[(tracker, generator, 0.05)]["ratio"])
    assert len(result["json"]["pairs"]["yaw rendered"]["0.05"][0]) == 2
