"""The master's own share of a frame's patches (the dispatcher's ``SELF``): the level crops of the new and the
previous frame measured against each other by the yaw core (:func:`common.yaw.patchwork.measure_share`).

A :class:`OwnShare` is what a round calls for it (:attr:`services.runtime.round.FrameWork.compute_self`):
one call into this module per share, none back into the master's service."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.yaw import PatchGrid, YawSettings
from common.yaw.grid import U8Array
from common.yaw.measurement import PatchMeasurement
from common.yaw.patchwork import SpectrumCache, measure_share


@dataclass(frozen=True)
class OwnShare:
    """Frame ``seq``'s patches against frame ``prev_seq``'s, from the two frames' pyramid levels."""

    grid: PatchGrid
    level: U8Array
    prev_level: U8Array
    cache: SpectrumCache
    settings: YawSettings
    stream: str
    seq: int
    prev_seq: int

    def __call__(self, indices: np.ndarray, moved: np.ndarray) -> PatchMeasurement:
        """The shifts of patches ``indices``; the previous crops of ``moved`` (the others' spectra are
        cached)."""
        grid = self.grid
        share, moved_share = grid.crop_level(self.level, indices), grid.crop_level(self.prev_level, moved)
        return measure_share(
            self.cache,
            self.settings,
            self.stream,
            self.seq,
            self.prev_seq,
            indices,
            share,
            moved,
            moved_share,
        )
