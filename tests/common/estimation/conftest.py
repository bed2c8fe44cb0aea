"""Shared fixtures of the estimation tests: one ground texture and one flight (b) per session."""

from __future__ import annotations

import pytest

from common.sim.flight import Flight, turns_flight
from common.sim.ground import GroundTexture, make_ground_texture


@pytest.fixture(scope="session")
def texture() -> GroundTexture:
    return make_ground_texture(seed=0)


@pytest.fixture(scope="session")
def flight_b(texture: GroundTexture) -> Flight:
    return turns_flight(seed=0, texture=texture)
