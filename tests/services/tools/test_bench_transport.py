"""``capataz bench transport`` on a short run: one row per codec, lossless codecs give mono8's yaw exactly and
decode bit-identical, JPEG sends fewer bytes the lower its quality, the JSON holds the table and every
flight. CPU figures are not asserted (a shared host)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from common.errors import CapatazError
from services.tools.bench import _runner, transport
from services.tools.cli import build_parser


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    transport.add_arguments(parser)
    return parser.parse_args(list(argv))


def test_every_codec_is_measured_and_lossless_ones_keep_mono8s_yaw(tmp_path: Path) -> None:
    args = _args(
        "--seeds", "1", "--frames", "8", "--scenarios", "tiles", "--timing-frames", "2", "--repeats", "1"
    )  # fmt: skip
    args.out = tmp_path
    assert _runner(transport)(args) == 0
    payload = json.loads((tmp_path / "transport.json").read_text())
    rows = {row["codec"]: row for row in payload["table"]}
    assert list(rows) == [label for label, _, _ in transport.VARIANTS]
    mono8 = rows["mono8"]
    assert mono8["bytes_per_frame"] == 752 * 480 and mono8["ratio"] == 1.0
    assert mono8["Mbit_s_at_20fps"] == pytest.approx(752 * 480 * 8 * 20 / 1e6)
    for label in ("png", "zstd"):
        row = rows[label]
        assert row["lossless"] and row["bit_identical"]
        assert row["max_diff_to_mono8_deg"] == 0.0 and row["yaw_rms_deg"] == mono8["yaw_rms_deg"]
        assert row["bytes_per_frame"] < mono8["bytes_per_frame"]
    q95, q90, q75 = (rows[f"jpeg q{q}"] for q in (95, 90, 75))
    assert not q90["lossless"] and not q90["bit_identical"] and q90["quality"] == 90
    assert mono8["bytes_per_frame"] > q95["bytes_per_frame"] > q90["bytes_per_frame"] > q75["bytes_per_frame"]
    assert q95["field_ratio"] > q75["field_ratio"]
    assert all(row["encode_ms"] >= 0.0 and row["decode_ms_p95"] >= row["decode_ms"] for row in rows.values())
    assert list(payload["flights"]) == ["tiles/0"]
    assert set(payload["flights"]["tiles/0"]) == set(rows)


@pytest.mark.parametrize(
    ("argv", "match"),
    [(["--scenarios", "moon"], "unknown field scenario"), (["--seeds", "0"], "must be >= 1")],
)
def test_bad_options_are_one_error(argv: list[str], match: str) -> None:
    with pytest.raises(CapatazError, match=match):
        transport.run(_args(*argv))


def test_the_bench_is_a_capataz_bench_command() -> None:
    args = build_parser().parse_args(["bench", "transport", "--seeds", "3"])
    assert args.seeds == 3 and args.frames == 150 and args.repeats == 5
