"""A folder of images as users have them: natural (numeric) order, optional per-frame stamps, a slice.

``open_image_folder`` checks everything before the first frame is published (a problem found mid-flight
would reset the yaw): the path is a folder, it holds images, every image can be read and all have one
size, the stamps file (if any) gives every selected image one stamp, strictly increasing.

Stamps file formats:

- two columns ``index,stamp`` (seconds; ``index`` = position of the image in natural order, from 0); a
  header line is allowed;
- EuRoC's ``data.csv``: ``#timestamp [ns],filename`` (nanoseconds, matched by file name).
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from common.errors import InputError
from common.estimation.measurements import FrameMeasurement

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".bmp", ".tif", ".tiff"})
#: period of frames without a stamps file when no rate is given (20 fps)
DEFAULT_PERIOD_S = 0.05


class ImageFolderError(InputError):
    """An image folder or its stamps file cannot be used (the text says which file and why)."""


def natural_key(name: str) -> tuple[int | str, ...]:
    """Sort key that orders ``img2.png`` before ``img10.png`` (digit runs compare as numbers)."""
    return tuple(int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name))


@dataclass(frozen=True)
class ImageFolder:
    """The selected images of a folder with their stamps (seconds, strictly increasing) and size."""

    path: Path
    files: tuple[Path, ...]
    stamps_s: tuple[float, ...]
    width: int
    height: int

    def __len__(self) -> int:
        return len(self.files)

    def frames(self) -> Iterator[FrameMeasurement]:
        """Grey frames in order, read lazily (one image in memory at a time)."""
        for path, stamp_s in zip(self.files, self.stamps_s, strict=True):
            yield FrameMeasurement(stamp_s, read_grey(path, (self.height, self.width)))


def read_grey(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """One image as (H, W) uint8 grey; ImageFolderError if unreadable or of another size."""
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ImageFolderError(f"{path}: cannot be read as an image")
    if image.shape != shape:
        raise ImageFolderError(f"{path}: size {image.shape[1]}x{image.shape[0]} != {shape[1]}x{shape[0]}")
    return image


def list_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` (by suffix) in natural order; ImageFolderError if none or not a folder."""
    folder = Path(folder)
    if not folder.exists():
        raise ImageFolderError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise ImageFolderError(f"{folder}: is a file, not a folder of images")
    files = sorted(
        (p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
        key=lambda p: natural_key(p.name),
    )
    if not files:
        raise ImageFolderError(f"{folder}: no images ({', '.join(sorted(IMAGE_SUFFIXES))})")
    return files


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the file header (no pixel decoding); ImageFolderError if not an image."""
    try:
        with Image.open(path) as image:
            return int(image.size[0]), int(image.size[1])
    except (UnidentifiedImageError, OSError) as exc:
        raise ImageFolderError(f"{path}: not a readable image ({exc})") from None


def check_one_size(files: list[Path]) -> tuple[int, int]:
    """The common (width, height) of ``files``; ImageFolderError naming the first of another size."""
    first = image_size(files[0])
    for path in files[1:]:
        size = image_size(path)
        if size != first:
            raise ImageFolderError(
                f"mixed image sizes: {files[0].name} is {first[0]}x{first[1]}, {path.name} is "
                f"{size[0]}x{size[1]} (one camera, one size)"
            )
    return first


def read_stamps_file(path: Path, files: list[Path]) -> list[float]:
    """Stamp (seconds) of every image of ``files``, from a ``index,stamp`` CSV or EuRoC's ``data.csv``."""
    path = Path(path)
    if not path.is_file():
        raise ImageFolderError(f"stamps file {path}: not found")
    try:
        rows = [r for r in csv.reader(path.read_text().splitlines()) if r and "".join(r).strip()]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ImageFolderError(f"stamps file {path}: cannot be read ({exc})") from None
    if not rows:
        raise ImageFolderError(f"stamps file {path}: empty")
    data = [
        (line, row)
        for line, row in enumerate(rows, start=1)
        if not row[0].lstrip().startswith("#") and not (line == 1 and not _is_number(row[0]))
    ]  # header lines skipped
    # EuRoC's data.csv names the file in its second column; the plain format has a number there
    euroc = bool(data) and len(data[0][1]) >= 2 and not _is_number(data[0][1][1])
    stamps: dict[int, float] = {}
    by_name = {p.name: i for i, p in enumerate(files)}
    for line, row in data:
        if len(row) < 2:
            raise ImageFolderError(f"stamps file {path}:{line}: expected 2 columns, got {row!r}")
        try:
            if euroc:
                name, stamp = row[1].strip(), int(row[0]) / 1e9
                if name not in by_name:
                    raise ImageFolderError(f"stamps file {path}:{line}: no image {name!r} in the folder")
                index = by_name[name]
            else:
                index, stamp = int(row[0]), float(row[1])
        except ValueError:
            raise ImageFolderError(f"stamps file {path}:{line}: not numbers: {row!r}") from None
        if not math.isfinite(stamp):
            raise ImageFolderError(f"stamps file {path}:{line}: stamp is not finite")
        if not 0 <= index < len(files):
            raise ImageFolderError(f"stamps file {path}:{line}: index {index} outside 0..{len(files) - 1}")
        if index in stamps:
            raise ImageFolderError(f"stamps file {path}:{line}: image {index} stamped twice")
        stamps[index] = stamp
    missing = [i for i in range(len(files)) if i not in stamps]
    if missing:
        raise ImageFolderError(
            f"stamps file {path}: no stamp for {len(missing)} image(s), first {files[missing[0]].name}"
        )
    return [stamps[i] for i in range(len(files))]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def open_image_folder(
    folder: Path,
    stamps_file: Path | None = None,
    start: int = 0,
    stop: int | None = None,
    step: int = 1,
    fps: float = 0.0,
) -> ImageFolder:
    """Check and open an image folder; frames ``[start:stop:step]`` of the natural order.

    Without a stamps file, image ``i`` (position in the whole folder) is stamped ``i / fps``
    (``fps = 0``: 20 fps).
    """
    if start < 0 or (stop is not None and stop < 0) or step < 1:
        raise ImageFolderError(f"need start >= 0, stop >= 0 and step >= 1, got {start}, {stop}, {step}")
    files = list_images(folder)
    if stamps_file is not None:
        stamps = read_stamps_file(stamps_file, files)
    else:
        period = 1.0 / fps if fps > 0 else DEFAULT_PERIOD_S
        stamps = [i * period for i in range(len(files))]
    chosen = range(len(files))[start:stop:step]
    if len(chosen) < 2:
        raise ImageFolderError(
            f"{folder}: {len(chosen)} image(s) selected of {len(files)} (start {start}, stop {stop}, "
            f"step {step}); a yaw needs at least 2"
        )
    selected = [files[i] for i in chosen]
    selected_stamps = [stamps[i] for i in chosen]
    bad = next((k for k in range(1, len(chosen)) if selected_stamps[k] <= selected_stamps[k - 1]), None)
    if bad is not None:
        raise ImageFolderError(
            f"stamps must increase: {selected[bad].name} ({selected_stamps[bad]!r} s) is not after "
            f"{selected[bad - 1].name} ({selected_stamps[bad - 1]!r} s)"
        )
    width, height = check_one_size(selected)
    return ImageFolder(Path(folder), tuple(selected), tuple(selected_stamps), width, height)
