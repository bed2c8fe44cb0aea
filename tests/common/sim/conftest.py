"""Shared simulator fixtures: one small and one default texture per session (generation takes ~1 s)."""

from __future__ import annotations

import pytest

from common.sim.ground import GroundTexture, make_ground_texture


@pytest.fixture(scope="session")
def texture() -> GroundTexture:
    return make_ground_texture(seed=0)


@pytest.fixture(scope="session")
def small_texture() -> GroundTexture:
    return make_ground_texture(seed=3, size_px=512, texel_m=0.01)
