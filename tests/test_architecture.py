"""The house rules, pinned: the rings (docs/architecture.md), pure cores, no service reaching into another's
package, small modules, and every test that starts Zenoh processes marked ``zenoh``. Known exceptions are
listed here and tracked: a listed one that no longer breaks the rule fails the test until it is removed, so
the lists can only shrink.

The rings, innermost first; a module imports only modules of its own ring or of rings inside it:

0. cores: ``common/`` (pure: arrays in, value objects out)
1. file readers: ``common/datasets/``
2. wire: ``common/wire/`` (schema, messages, codec, keys)
3. simulation and recordings: ``common/sim/``, ``common/recordings/``
4. services: ``services/runtime/`` and one package per Zenoh service
5. tools: ``services/tools/`` (command line, benchmarks, load test, demos, up/compose/secure, record/view)
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 400

#: cores that still import the simulator (the estimator and localizer work removes them)
SIM_IMPORT_EXCEPTIONS: set[str] = set()
#: modules over MAX_LINES today (split them, then remove them here)
LONG_MODULE_EXCEPTIONS: set[str] = set()


def python_files(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (ROOT / folder).rglob("*.py"))


def rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute names; relative imports resolved against its package)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = rel(path).removesuffix(".py").replace("/", ".").rsplit(".", 1)[0]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join([*parts[: len(parts) - node.level + 1], base]).strip(".")
            names.add(base)
            names |= {f"{base}.{alias.name}" for alias in node.names}
    return names


def imports_any(path: Path, prefixes: tuple[str, ...]) -> set[str]:
    return {m for m in imported_modules(path) if any(m == p or m.startswith(p + ".") for p in prefixes)}


#: (ring, module prefix), most specific prefixes first; the first that matches a module names its ring
RINGS: tuple[tuple[int, str], ...] = (
    (1, "common.datasets"),
    (2, "common.wire"),
    (3, "common.sim"),
    (3, "common.recordings"),
    (0, "common"),
    (5, "services.tools"),
    (4, "services"),
)
RING_NAMES = ("cores", "file readers", "wire", "simulation and recordings", "services", "tools")
#: packages directly under services/ that are not services: the runtime they share, the tools above them
NOT_SERVICES = {"runtime", "tools"}
#: the Zenoh services: every other package directly under services/ (found from the folders, so a new one
#: is covered)
SERVICES = tuple(
    sorted(
        p.parent.name for p in (ROOT / "services").glob("*/__init__.py") if p.parent.name not in NOT_SERVICES
    )
)


def module_name(path: Path) -> str:
    return rel(path).removesuffix(".py").removesuffix("/__init__").replace("/", ".")


def ring_of(module: str) -> int | None:
    return next((ring for ring, prefix in RINGS if module == prefix or module.startswith(prefix + ".")), None)


def test_every_module_has_a_ring() -> None:
    assert [rel(p) for p in python_files("common", "services") if ring_of(module_name(p)) is None] == []


def test_each_ring_imports_only_its_own_ring_and_the_rings_inside_it() -> None:
    offenders = []
    for path in python_files("common", "services"):
        ring = ring_of(module_name(path))
        assert ring is not None
        for imported in imports_any(path, ("common", "services")):
            other = ring_of(imported)
            if other is not None and other > ring:
                offenders.append(f"{rel(path)} ({RING_NAMES[ring]}) imports {imported} ({RING_NAMES[other]})")
    assert offenders == []


def test_no_service_imports_another_service() -> None:
    assert {"camera", "master", "foreman", "worker", "estimator", "localizer", "router", "ros2"} <= set(
        SERVICES
    )
    offenders = []
    for service in SERVICES:
        others = tuple(f"services.{s}" for s in SERVICES if s != service)
        for path in python_files(f"services/{service}"):
            offenders += [f"{rel(path)} imports {m}" for m in sorted(imports_any(path, others))]
    assert offenders == []


def test_only_the_camera_and_the_tools_import_the_simulation() -> None:
    allowed = ("services/camera/", "services/tools/", "common/sim/")
    offenders = [
        f"{rel(p)} imports {sorted(imports_any(p, ('common.sim',)))}"
        for p in python_files("common", "services")
        if not rel(p).startswith(allowed) and imports_any(p, ("common.sim",))
    ]
    assert offenders == []


def test_the_rings_diagram_matches_the_folders() -> None:
    """docs/architecture.md lists every package of common/ and services/ under its ring."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    packages = {
        rel(p.parent)
        for p in python_files("common", "services")
        if p.name == "__init__.py" and p.parent != ROOT
    }
    missing = sorted(p for p in packages if f"{p}/" not in text)
    assert missing == [], "packages missing from docs/architecture.md's rings"


def test_common_imports_no_zenoh() -> None:
    offenders = {rel(p): imports_any(p, ("zenoh",)) for p in python_files("common")}
    assert {k: v for k, v in offenders.items() if v} == {}


def test_common_imports_the_simulator_only_inside_common_sim() -> None:
    offenders = {
        rel(p)
        for p in python_files("common")
        if not rel(p).startswith("common/sim/") and imports_any(p, ("common.sim",))
    }
    assert offenders - SIM_IMPORT_EXCEPTIONS == set(), "a core imports the simulator"
    assert SIM_IMPORT_EXCEPTIONS - offenders == set(), "fixed: remove it from SIM_IMPORT_EXCEPTIONS"


def test_tests_of_the_cores_import_no_service() -> None:
    """tests/common mirrors common/: a test that needs a service lives under tests/services."""
    offenders = {rel(p): imports_any(p, ("services",)) for p in python_files("tests/common")}
    assert {k: v for k, v in offenders.items() if v} == {}


@pytest.mark.parametrize("package", ["services/worker", "services/foreman", "services/runtime"])
def test_worker_foreman_and_runtime_import_nothing_from_the_master(package: str) -> None:
    offenders = {rel(p): imports_any(p, ("services.master",)) for p in python_files(package)}
    assert {k: v for k, v in offenders.items() if v} == {}


def test_no_module_over_400_lines_outside_common_sim() -> None:
    long = {
        rel(p)
        for p in python_files("common", "services", "tests")
        if not rel(p).startswith("common/sim/") and len(p.read_text().splitlines()) > MAX_LINES
    }
    assert long - LONG_MODULE_EXCEPTIONS == set(), f"over {MAX_LINES} lines: split it"
    assert LONG_MODULE_EXCEPTIONS - long == set(), "now short enough: remove it from LONG_MODULE_EXCEPTIONS"


#: what a test file does when it starts processes that open Zenoh sessions
_PROCESS_PATTERNS = re.compile(r"LocalCluster\(|\"services\.cli\"|capataz_command\(")


def test_tests_that_start_zenoh_processes_are_marked_zenoh() -> None:
    """In-process sessions are caught at run time (tests/conftest.py); processes are caught here: a test
    that starts them (itself or through a function of its module) carries the marker."""
    unmarked = []
    for path in python_files("tests"):
        text = path.read_text()
        if not path.name.startswith("test_") or re.search(r"^pytestmark = .*mark\.zenoh", text, re.M):
            continue
        functions = [n for n in ast.parse(text).body if isinstance(n, ast.FunctionDef)]
        source = {f.name: ast.get_source_segment(text, f) or "" for f in functions}
        starters = {  # a test that replaces LocalCluster.spawn starts nothing
            name
            for name, body in source.items()
            if _PROCESS_PATTERNS.search(body) and not re.search(r"setattr\([^)]*\"spawn\"", body)
        }
        for function in functions:
            if not function.name.startswith("test_"):
                continue
            calls = {n.id for n in ast.walk(function) if isinstance(n, ast.Name)}
            decorators = " ".join(ast.get_source_segment(text, d) or "" for d in function.decorator_list)
            if (function.name in starters or calls & starters) and "mark.zenoh" not in decorators:
                unmarked.append(f"{rel(path)}::{function.name}")
    assert unmarked == []
