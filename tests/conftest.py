"""Shared fixtures: the location of ../shared/data (tests that need it skip when it is absent)."""

from __future__ import annotations

from pathlib import Path

import pytest
import zenoh

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
