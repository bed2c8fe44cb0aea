"""No service imports another service (issue 24): a service package (every package directly under
``services/`` but the runtime the services share and the tools above them) never imports another one (its
own package, the runtime and the rings inside are its to use); what two services share lives below them
(e.g. a sample's wire message,
``common/wire/measurements.py``). The packages are found from the folders, so a new service is covered."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: packages directly under services/ that are not services: the runtime they share, the tools above them
NOT_SERVICES = {"runtime", "tools"}


def service_packages() -> set[str]:
    """Dotted names of the service packages: ``services/<name>/__init__.py`` exists, name not excluded."""
    found = (ROOT / "services").glob("*/__init__.py")
    return {f"services.{p.parent.name}" for p in found if p.parent.name not in NOT_SERVICES}


def imported_modules(source: str, package: str) -> set[str]:
    """Absolute names of every module ``source`` imports, at any depth (relative imports resolved against
    ``package``, the dotted package of the file)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join([*parts[: len(parts) - node.level + 1], base]).strip(".")
            names |= {base} | {f"{base}.{alias.name}" for alias in node.names}
    return names


def other_services(source: str, package: str, own: str, services: set[str]) -> set[str]:
    """The modules of services other than ``own`` that ``source`` imports."""
    return {
        m
        for m in imported_modules(source, package)
        for other in services - {own}
        if m == other or m.startswith(other + ".")
    }


def test_the_services_are_found() -> None:
    expected = {"services.camera", "services.estimator", "services.master", "services.worker"}
    assert expected <= service_packages()
    assert not {"services.runtime", "services.tools"} & service_packages()


def test_no_service_imports_another_service() -> None:
    services = service_packages()
    offenders = {}
    for own in sorted(services):
        for path in sorted((ROOT / own.replace(".", "/")).rglob("*.py")):
            package = path.relative_to(ROOT).parent.as_posix().replace("/", ".")
            if found := other_services(path.read_text(), package, own, services):
                offenders[path.relative_to(ROOT).as_posix()] = sorted(found)
    assert offenders == {}


@pytest.mark.parametrize(
    "source",
    [
        "from services.estimator.sim_publisher import message_of\n",
        "import services.estimator\n",
        "from ..estimator import service\n",
        "from services import estimator\n",
        "def f():\n    from services.estimator import service\n",
    ],
)
def test_the_rule_sees_every_kind_of_import_of_another_service(source: str) -> None:
    services = {"services.camera", "services.estimator"}
    assert other_services(source, "services.camera", "services.camera", services)


def test_the_rule_allows_the_own_package_the_runtime_and_the_rings_below() -> None:
    services = {"services.camera", "services.estimator"}
    source = (
        "from services.camera.sources import CameraSource\nfrom . import flights\n"
        "from services.runtime.service import ConfiguredService\n"
        "from common.wire.measurements import message_of\n"
    )
    assert other_services(source, "services.camera", "services.camera", services) == set()
