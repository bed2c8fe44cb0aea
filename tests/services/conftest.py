"""Fixtures of the service tests: development certificates of the secure profile (made once per session)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from services.tools.secure import make_certs


@pytest.fixture(scope="session")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (needed to make the development certificates)")
    out = tmp_path_factory.mktemp("certs")
    make_certs(out, ("uav0",))
    return out
