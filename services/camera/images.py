"""The camera's image folders (``capataz camera --images``): the folder check as a usage error."""

from __future__ import annotations

from pathlib import Path

from common.datasets.images import ImageFolderError, list_images
from services.runtime.usage import UsageError


def image_files(folder: Path) -> list[Path]:
    """The images of ``--images`` (:func:`common.datasets.images.list_images`: natural order, the reader's
    suffixes); UsageError (one line, exit 2) for a missing folder, a file, or a folder without images: the
    camera checks this before its service starts."""
    try:
        return list_images(folder)
    except ImageFolderError as exc:
        raise UsageError(f"--images {exc}") from None
