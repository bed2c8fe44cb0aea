"""Image folders as users have them (issue 10 section 4): natural order, stamps files, a slice, and one
clear refusal (exit code 1, no traceback) for an empty folder, mixed sizes or a file path."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.datasets.images import ImageFolderError, natural_key, open_image_folder
from common.sim.flight import hover_flight


def _folder(tmp_path: Path, names: list[str], shape: tuple[int, int] = (48, 64)) -> Path:
    folder = tmp_path / "images"
    folder.mkdir()
    for k, name in enumerate(names):
        cv2.imwrite(str(folder / name), np.full(shape, k * 10, np.uint8))
    return folder


def test_natural_order_puts_frame_2_before_frame_10(tmp_path: Path) -> None:
    folder = _folder(tmp_path, ["frame10.png", "frame2.png", "frame1.png"])
    opened = open_image_folder(folder)
    assert [p.name for p in opened.files] == ["frame1.png", "frame2.png", "frame10.png"]
    # each frame is the image of that file (the value written for it), not of the string order
    values = [int(f.image[0, 0]) for f in opened.frames()]
    assert values == [20, 10, 0]


@given(st.lists(st.integers(0, 10**6), min_size=2, max_size=30, unique=True))
def test_natural_key_orders_numbered_names_by_number(numbers: list[int]) -> None:
    names = [f"img_{n}.png" for n in numbers]
    assert sorted(names, key=natural_key) == [f"img_{n}.png" for n in sorted(numbers)]


def test_real_frames_keep_their_pixels(tmp_path: Path) -> None:
    flight = hover_flight(seed=0, n_frames=3)
    folder = tmp_path / "flight"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"), flight.frame(i))
    frames = list(open_image_folder(folder, fps=20.0).frames())
    assert [f.stamp_s for f in frames] == [0.0, 0.05, 0.1]
    for i, f in enumerate(frames):
        assert np.array_equal(f.image, flight.frame(i))


def test_index_stamp_csv_gives_each_image_its_stamp(tmp_path: Path) -> None:
    folder = _folder(tmp_path, ["a1.png", "a2.png", "a10.png"])
    stamps = tmp_path / "stamps.csv"
    stamps.write_text("index,stamp\n2,0.31\n0,0.10\n1,0.20\n")
    opened = open_image_folder(folder, stamps)
    assert opened.stamps_s == (0.10, 0.20, 0.31)


def test_euroc_data_csv_stamps_by_file_name(tmp_path: Path) -> None:
    folder = _folder(tmp_path, ["1403636579763555584.png", "1403636579813555456.png"])
    stamps = tmp_path / "data.csv"
    stamps.write_text(
        "#timestamp [ns],filename\n1403636579763555584,1403636579763555584.png\n"
        "1403636579813555456,1403636579813555456.png\n"
    )
    opened = open_image_folder(folder, stamps)
    assert opened.stamps_s == (1403636579763555584 / 1e9, 1403636579813555456 / 1e9)


def test_start_stop_step_select_frames_with_their_original_stamps(tmp_path: Path) -> None:
    folder = _folder(tmp_path, [f"{i}.png" for i in range(10)])
    opened = open_image_folder(folder, start=2, stop=9, step=3, fps=10.0)
    assert [p.name for p in opened.files] == ["2.png", "5.png", "8.png"]
    assert opened.stamps_s == pytest.approx((0.2, 0.5, 0.8))


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        ("empty", "no images"),
        ("file", "is a file, not a folder"),
        ("mixed", "mixed image sizes"),
        ("missing_stamp", "no stamp for 1 image"),
        ("decreasing", "stamps must increase"),
        ("corrupt", "not a readable image"),
        ("one_selected", "a yaw needs at least 2"),
    ],
)
def test_bad_folders_are_refused_with_one_clear_error(tmp_path: Path, setup: str, message: str) -> None:
    folder = _folder(tmp_path, ["0.png", "1.png", "2.png"])
    kwargs: dict[str, object] = {}
    if setup == "empty":
        folder = tmp_path / "empty"
        folder.mkdir()
    elif setup == "file":
        folder = folder / "0.png"
    elif setup == "mixed":
        cv2.imwrite(str(folder / "3.png"), np.zeros((40, 64), np.uint8))
    elif setup in ("missing_stamp", "decreasing"):
        stamps = tmp_path / "s.csv"
        rows = "0,0.0\n1,0.1\n" if setup == "missing_stamp" else "0,0.0\n1,0.2\n2,0.1\n"
        stamps.write_text(rows)
        kwargs["stamps_file"] = stamps
    elif setup == "corrupt":
        (folder / "5.png").write_bytes(b"not a png at all")
    elif setup == "one_selected":
        kwargs["start"] = 2
    with pytest.raises(ImageFolderError, match=message):
        open_image_folder(folder, **kwargs)  # type: ignore[arg-type]
