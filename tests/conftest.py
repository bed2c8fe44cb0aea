"""Shared fixtures: the location of ../shared/data (tests that need it skip when it is absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import zenoh
from hypothesis import HealthCheck, settings

# No wall-clock limits in tests: hypothesis's default 200 ms deadline per example and its "too slow" health
# check measure the host, not the code (test_camera's lens round trip failed so on a busy host).
settings.register_profile("calm", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("calm")

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder {SHARED_DATA} is absent (only the CI checkout has ../shared)")
    return SHARED_DATA


@pytest.fixture(autouse=True)
def _real_sessions_need_the_zenoh_marker(
    request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A test that opens a real Zenoh session in this process must be marked ``zenoh`` (it fails otherwise);
    tests that start processes which open sessions are checked by tests/test_architecture.py."""
    if request.node.get_closest_marker("zenoh") is not None:
        return

    def refuse(*_args: object, **_kwargs: object) -> None:
        raise AssertionError(f"{request.node.nodeid} opens a real Zenoh session: mark it pytest.mark.zenoh")

    monkeypatch.setattr(zenoh, "open", refuse)


#: hang guard of tests marked ``slow`` (whole flights: a 2041-frame hover took 275 s on a loaded 2-core host,
#: close to the 300 s every other test gets); a guard against hangs, not a speed claim
SLOW_TEST_TIMEOUT_S = 1800


#: tests marked ``long`` run only on request (``make test-long``): the default suite stays under 15 minutes
LONG_SKIP = pytest.mark.skip(
    reason="long run (over a minute, what shorter tests hold too); make test-long runs it"
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    long_runs = bool(os.environ.get("CAPATAZ_LONG_TESTS"))
    for item in items:
        if item.get_closest_marker("slow") is not None and item.get_closest_marker("timeout") is None:
            item.add_marker(pytest.mark.timeout(SLOW_TEST_TIMEOUT_S))
        if item.get_closest_marker("long") is not None and not long_runs:
            item.add_marker(LONG_SKIP)
