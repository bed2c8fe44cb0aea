"""Reading a small text file a user names (a calibration, a model): one clear error for what it is not."""

from __future__ import annotations

from pathlib import Path

from common.errors import InputError


def read_text_file(path: Path, max_bytes: int, what: str, error: type[InputError]) -> str:
    """The UTF-8 text of the file at ``path``; a missing file, a directory, a file over ``max_bytes`` or one
    that is not UTF-8 text raises ``error`` naming ``what`` and the path."""
    if not path.is_file():
        raise error(f"{what} {path}: not a file")
    size = path.stat().st_size
    if size > max_bytes:
        raise error(f"{what} {path}: {size} bytes is larger than {max_bytes}")
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path}: not text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise error(f"{what} {path}: {exc.strerror}") from None
