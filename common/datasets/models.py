"""3D model files -> :class:`~common.localization.model.SceneModel`: JSON, Wavefront OBJ, ViSP ``.cao``.

The format is chosen by the suffix (``.json``, ``.obj``, ``.cao``); the parsers are the pure text functions
of :mod:`common.localization.model` and :mod:`common.localization.cad`. ``load()`` lines of a ``.cao`` file
resolve relative to the file that contains them. Every problem is one :class:`ModelFileError` (a
:class:`~common.localization.model.SceneModelError`) naming the file (and line, where the parser knows it).
"""

from __future__ import annotations

import os
from pathlib import Path

from common.datasets.files import read_text_file
from common.localization.cad import CadError, scene_from_cao, scene_from_obj
from common.localization.model import SceneModel, SceneModelError, scene_from_json

#: the largest model file read (a CAD model for edge tracking has at most some thousands of faces).
MAX_MODEL_BYTES = 64 << 20
SUFFIXES = (".json", ".obj", ".cao")


class ModelFileError(SceneModelError):
    """A model file could not be read as a scene."""


def _read_text(path: Path) -> str:
    return read_text_file(path, MAX_MODEL_BYTES, "model file", ModelFileError)


def load_model(path: str | os.PathLike[str], scale: float = 1.0) -> SceneModel:
    """The scene of a model file; ``scale`` converts an OBJ's units to metres (JSON and .cao are metres)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise ModelFileError(
            f"model file {p}: unknown format {suffix!r} (expected one of {', '.join(SUFFIXES)})"
        )
    text = _read_text(p)
    try:
        if suffix == ".obj":
            return scene_from_obj(text, name=p.stem, source=str(p), scale=scale)
        if suffix == ".cao":

            def load(relative: str, containing: str) -> tuple[str, str]:
                target = (Path(containing).parent / relative).resolve()
                return _read_text(target), str(target)

            return scene_from_cao(text, name=p.stem, source=str(p), load=load)
        return scene_from_json(text)
    except CadError:
        raise
    except ModelFileError:
        raise
    except SceneModelError as exc:
        raise ModelFileError(f"model file {p}: {exc}") from None
