"""``capataz run``: ``--only`` merges into out/summary.json, which carries metadata."""

from __future__ import annotations

import argparse
import json
import sys
import types
from pathlib import Path

import pytest

from services import run as run_command


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
