"""``capataz bench compression`` on a short simulated run: one row per compression, every file reads back,
zstd and lz4 files are smaller than the uncompressed one, and the record command compresses with zstd
unless told otherwise. CPU figures are not asserted (a shared host)."""

from __future__ import annotations

import argparse
from pathlib import Path

from common.recordings.mcap import Compression
from services.tools.bench import compression
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
