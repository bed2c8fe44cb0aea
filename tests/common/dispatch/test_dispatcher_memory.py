"""A dispatcher's memory follows the patches it plans, not its bound of patch indices (issue 27: each of a
foreman's per-stream dispatchers, bounded at 2**16 indices, held a list of all of them: 2.4 MB a stream)."""

from __future__ import annotations

import tracemalloc

import numpy as np

from common.dispatch import Dispatcher, DispatchSettings


def test_a_dispatcher_given_the_indices_holds_no_list_of_every_index() -> None:
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        dispatcher = Dispatcher(DispatchSettings(), 1 << 16)
        dispatcher.join("w0")
        plan = dispatcher.plan(1, 0, 0.0, np.arange(256))
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert np.array_equal(plan.assignment["w0"], np.arange(256))
    assert held < 256 * 1024, held  # a list of 2**16 indices alone is 2.3 MB


def test_a_plan_of_all_patches_still_covers_every_index() -> None:
    dispatcher = Dispatcher(DispatchSettings(), 100)
    dispatcher.join("w0")
    dispatcher.join("w1")
    for seq in (1, 2):  # built once, then reused
        plan = dispatcher.plan(seq, seq - 1, 0.0)
        merged = np.sort(np.concatenate(list(plan.assignment.values())))
        assert np.array_equal(merged, np.arange(100))
