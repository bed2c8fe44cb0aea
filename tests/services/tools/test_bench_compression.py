"""``capataz bench compression`` on a short simulated run: one row per compression, every file reads back,
zstd and lz4 files are smaller than the uncompressed one, and the record command compresses with zstd
unless told otherwise. CPU figures are not asserted (a shared host)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2

from common.recordings.mcap import Compression
from common.sim.flight import hover_flight
from services.tools.bench import _runner, compression
from services.tools.cli import build_parser
from services.tools.record import RecordSettings


def test_bench_compression_measures_each_compression(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    compression.add_arguments(parser)
    args = parser.parse_args(["--frames", "8"])
    args.out = tmp_path
    result = compression.run(args)
    rows = {row["compression"]: row for row in result["table"]}
    assert set(rows) == {"none", "lz4", "zstd"}
    assert all(row["read_back"] for row in rows.values())
    assert rows["none"]["ratio"] == 1.0
    assert rows["zstd"]["bytes"] < rows["none"]["bytes"] and rows["lz4"]["bytes"] < rows["none"]["bytes"]
    assert rows["zstd"]["bytes"] == (tmp_path / "compression_zstd.mcap").stat().st_size
    assert result["settings"]["frames"] == 8


def test_record_compresses_with_zstd_by_default() -> None:
    parser = build_parser(("services.tools.record",))
    assert parser.parse_args(["record"]).compression == "zstd"
    assert parser.parse_args(["record", "--compression", "none"]).compression == "none"
    assert RecordSettings(out=Path("x.mcap")).compression is Compression.ZSTD


def test_a_real_video_is_written_beside_the_simulators_figures_with_its_metadata(tmp_path: Path) -> None:
    """``--images`` writes compression_images.json (not over compression.json), with the command, date and
    commit that ``capataz results`` prints above its table."""
    folder = tmp_path / "frames"
    folder.mkdir()
    flight = hover_flight(seed=0, n_frames=4)
    for i in range(flight.n_frames):
        cv2.imwrite(str(folder / f"{i}.png"), flight.frame(i))
    parser = argparse.ArgumentParser()
    compression.add_arguments(parser)
    args = parser.parse_args(["--frames", "4", "--images", str(folder)])
    args.out = tmp_path / "bench"
    assert _runner(compression)(args) == 0
    assert not (args.out / "compression.json").exists()
    payload = json.loads((args.out / "compression_images.json").read_text())
    assert payload["settings"]["images"] == str(folder)
    assert payload["metadata"]["command"].startswith("capataz bench ")
    assert payload["metadata"]["time_utc"].endswith("+00:00") and "git_commit" in payload["metadata"]
    assert [row["compression"] for row in payload["table"]] == ["none", "lz4", "zstd"]
