"""The pinned versions (``deploy/constraints.txt``) cover every dependency ``pyproject.toml`` names, within
its ranges, and are what the tests run on: ``make`` and the image install with them as constraints, so a
fresh clone tests what was tested, not the registry's newest release of the day."""

from __future__ import annotations

import re
import tomllib
from importlib import metadata
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
PINS = ROOT / "deploy" / "constraints.txt"


def pins() -> dict[str, Version]:
    """``name -> version`` of every ``name==version`` line (comments and blank lines skipped)."""
    out: dict[str, Version] = {}
    for line in PINS.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        match = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;]+)", line)
        assert match, f"not a pin: {line!r}"
        name = canonicalize_name(match.group(1))
        assert name not in out, f"{name} pinned twice"
        out[name] = Version(match.group(2))
    return out


def named_requirements() -> list[Requirement]:
    """The runtime dependencies and every extra's, as ``pyproject.toml`` names them."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = list(project["dependencies"])
    for extra in project.get("optional-dependencies", {}).values():
        names.extend(extra)
    return [Requirement(text) for text in names]


def test_every_named_dependency_is_pinned_within_its_range() -> None:
    pinned = pins()
    for requirement in named_requirements():
        name = canonicalize_name(requirement.name)
        assert name in pinned, f"{requirement} has no pin in {PINS.name} (make lock)"
        assert requirement.specifier.contains(pinned[name], prereleases=True), (
            f"{name}=={pinned[name]} is outside pyproject's {requirement.specifier} (make lock)"
        )


def test_the_tests_run_on_the_pinned_versions() -> None:
    """Each named dependency that is installed has its pinned version (an extra left out, such as ros2 whose
    tests then skip, is not a mismatch)."""
    pinned = pins()
    for requirement in named_requirements():
        name = canonicalize_name(requirement.name)
        try:
            installed = Version(metadata.version(name))
        except metadata.PackageNotFoundError:
            continue
        assert installed == pinned[name], (
            f"{name} {installed} is installed, {pinned[name]} is pinned: `make test` installs the pins "
            f"(uv pip install -c {PINS.relative_to(ROOT)})"
        )


def test_make_and_the_image_install_with_the_pins() -> None:
    makefile = (ROOT / "Makefile").read_text()
    assert re.search(r"^PINS\s*:= deploy/constraints.txt$", makefile, re.M)
    assert re.search(r"^UV\s*:= .*--constraints \$\(PINS\)$", makefile, re.M)
    dockerfile = (ROOT / "deploy" / "Dockerfile").read_text()
    assert "COPY deploy/constraints.txt /tmp/constraints.txt" in dockerfile
    assert "-r /tmp/requirements.txt -c /tmp/constraints.txt" in dockerfile
