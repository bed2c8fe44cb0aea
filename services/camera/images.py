"""The camera's image folders (``capataz camera --images``)."""

from __future__ import annotations

from pathlib import Path

from services.runtime.usage import UsageError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".bmp")


def image_files(folder: Path) -> list[Path]:
    """The images of ``--images`` in name order; UsageError (one line, exit 2) for a missing folder, a file,
    or a folder without images: the camera checks this before its service starts."""
    if not folder.is_dir():
        raise UsageError(f"--images {folder}: {'not a folder' if folder.exists() else 'no such folder'}")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise UsageError(f"--images {folder}: no {'/'.join(IMAGE_SUFFIXES)} files in the folder")
    return files
