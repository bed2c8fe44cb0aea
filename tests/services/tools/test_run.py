"""``capataz run``: ``--only`` merges into out/summary.json, which carries metadata."""

from __future__ import annotations

import argparse
import json
import sys
import types
from pathlib import Path

import pytest

from services.tools import run as run_command


def fake_demo(name: str, result: dict[str, float]) -> str:
    module = types.ModuleType(f"tests_fake_{name}")
    module.run_demo = lambda out_dir: dict(result)  # type: ignore[attr-defined]
    sys.modules[module.__name__] = module
    return module.__name__


def test_only_merges_into_the_summary_and_metadata_is_recorded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    a, b = fake_demo("demo_a", {"x": 1.0}), fake_demo("demo_b", {"y": 2.0})
    monkeypatch.setattr(run_command, "DEMO_MODULES", (a, b))
    assert run_command.run(argparse.Namespace(out=tmp_path, only=None)) == 0
    first = json.loads((tmp_path / "summary.json").read_text())
    assert first[a.rsplit(".", 1)[-1]] == {"x": 1.0} and first[b.rsplit(".", 1)[-1]] == {"y": 2.0}
    meta = first["metadata"]
    assert (
        meta["version"]
        and meta["time_utc"].endswith("+00:00")
        and meta["parts_run"] == ["tests_fake_demo_a", "tests_fake_demo_b"]
    )
    assert "git_commit" in meta and "seeds" in meta and meta["settings"]["only"] is None

    monkeypatch.setattr(run_command, "DEMO_MODULES", (a, fake_demo("demo_b", {"y": 3.0})))
    assert run_command.run(argparse.Namespace(out=tmp_path, only="tests_fake_demo_b")) == 0
    merged = json.loads((tmp_path / "summary.json").read_text())
    assert merged["tests_fake_demo_a"] == {"x": 1.0}  # kept
    assert merged["tests_fake_demo_b"] == {"y": 3.0}  # replaced
    assert merged["metadata"]["parts_run"] == ["tests_fake_demo_b"]
    assert set(merged["metadata"]["durations_s"]) == {"tests_fake_demo_a", "tests_fake_demo_b"}


class Work:
    def __init__(self, log: list[str]) -> None:
        self.log = log

    def cancel(self) -> None:
        self.log.append("cancel")


def _prestarted_demos(log: list[str], fail: bool = False) -> tuple[str, str]:
    first, second = types.ModuleType("tests_fake_first"), types.ModuleType("tests_fake_second")

    def run_first(out_dir: Path) -> dict[str, float]:
        log.append("first")
        if fail:
            raise RuntimeError("the part ahead failed")
        return {"a": 1.0}

    def start_second(out_dir: Path) -> Work:
        log.append("start second")
        return Work(log)

    def run_second(out_dir: Path, started: Work | None = None) -> dict[str, float]:
        log.append(f"second ({'prestarted' if started is not None else 'cold'})")
        return {"b": 2.0}

    first.run_demo, second.start, second.run_demo = run_first, start_second, run_second  # type: ignore[attr-defined]
    for module in (first, second):
        sys.modules[module.__name__] = module
    return first.__name__, second.__name__


def test_a_part_is_started_before_the_one_ahead_of_it_and_handed_its_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log: list[str] = []
    first, second = _prestarted_demos(log)
    monkeypatch.setattr(run_command, "DEMO_MODULES", (first, second))
    monkeypatch.setattr(run_command, "PRESTART", {first: second})
    assert run_command.run(argparse.Namespace(out=tmp_path, only=None)) == 0
    assert log == ["start second", "first", "second (prestarted)"]
    log.clear()  # alone, the part starts its own work
    assert run_command.run(argparse.Namespace(out=tmp_path, only="tests_fake_second")) == 0
    assert log == ["second (cold)"]


def test_work_started_ahead_is_cancelled_when_the_part_before_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log: list[str] = []
    first, second = _prestarted_demos(log, fail=True)
    monkeypatch.setattr(run_command, "DEMO_MODULES", (first, second))
    monkeypatch.setattr(run_command, "PRESTART", {first: second})
    with pytest.raises(RuntimeError):
        run_command.run(argparse.Namespace(out=tmp_path, only=None))
    assert log == ["start second", "first", "cancel"]


def test_an_unreadable_summary_is_replaced(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "summary.json").write_text("{not json")
    monkeypatch.setattr(run_command, "DEMO_MODULES", (fake_demo("demo_c", {"z": 1.0}),))
    assert run_command.run(argparse.Namespace(out=tmp_path, only="tests_fake_demo_c")) == 0
    assert json.loads((tmp_path / "summary.json").read_text())["tests_fake_demo_c"] == {"z": 1.0}


def test_progress_bars_are_quiet_under_ci_and_with_quiet(monkeypatch: pytest.MonkeyPatch) -> None:
    from services.runtime import progress

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    monkeypatch.delenv("CI", raising=False)
    progress.configure(quiet=False)
    assert progress.enabled()
    monkeypatch.setenv("CI", "true")
    assert not progress.enabled()
    monkeypatch.delenv("CI")
    progress.configure(quiet=True)
    try:
        assert not progress.enabled()
        with progress.bar(total=3, desc="x") as bar:
            bar.update()
            assert not bar.shown
            assert list(bar.track([1, 2])) == [1, 2]
    finally:
        progress.configure(quiet=False)
