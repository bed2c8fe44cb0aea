"""The distributable yaw stage as a member runs it: cached spectra per stream, subsets of patches.

A member (worker, or a master/foreman computing its own share) keeps the spectra of the patches it
computed for the newest frame of each stream. A job for frame ``seq`` measured against ``prev_seq``
brings the new crops, plus previous crops for indices the member does not hold; everything else comes
from the cache, so only the new frame travels. The arithmetic is the yaw core's own
(``patch_spectra_from_crops``, ``measure_patches``), so the results equal the in-process core bit for bit.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any, Generic, TypeVar

import numpy as np
import numpy.typing as npt

from common.errors import CapatazError
from common.yaw.correlation import PatchSpectra, measure_patches, patch_spectra_from_crops
from common.yaw.measurement import PatchMeasurement
from common.yaw.settings import YawSettings


class PatchWorkError(CapatazError):
    """A job cannot be computed (missing previous spectra, inconsistent settings or crops)."""


E = TypeVar("E")


class _StreamBudget(Generic[E]):
    """An entry per stream, least recently stored first, and the bytes the entries hold against one budget
    across streams (``max_bytes``; None: unbounded); ``evicted`` counts the streams evicted for it."""

    def __init__(self, max_bytes: int | None) -> None:
        self._streams: OrderedDict[str, E] = OrderedDict()
        #: the budget across streams (None: unbounded; a member's comes from its ``--cache-mb``)
        self.max_bytes = max_bytes
        self.nbytes = 0
        self.evicted = 0

    def __len__(self) -> int:
        return len(self._streams)

    def _entry_bytes(self, entry: E) -> int:
        raise NotImplementedError

    def _over_budget(self) -> bool:
        return self.max_bytes is not None and self.nbytes > self.max_bytes

    def _evict_oldest(self) -> None:
        _, oldest = self._streams.popitem(last=False)
        self.nbytes -= self._entry_bytes(oldest)
        self.evicted += 1


@dataclasses.dataclass
class _StreamCache:
    seq: int
    spectra: dict[int, tuple[np.ndarray, np.floating[Any]]]
    #: the last share stored whole: a lookup of exactly its indices returns it without re-stacking
    last: PatchSpectra | None = None
    stored_s: float = 0.0
    #: bytes of the spectra held (what :attr:`SpectrumCache.max_bytes` bounds)
    nbytes: int = 0


class SpectrumCache(_StreamBudget[_StreamCache]):
    """Newest-frame spectra per (stream, patch index); thread-safe; bounded in total, across streams: the
    least recently stored streams are evicted beyond ``max_streams``, beyond ``max_bytes`` of spectra, and
    when not stored to for ``max_age_s`` (a share larger than the whole budget is not kept: its next frame is
    sent its previous patches again)."""

    def __init__(
        self,
        max_streams: int = 64,
        max_age_s: float = 60.0,
        clock: Any = time.monotonic,
        max_bytes: int | None = None,
    ) -> None:
        super().__init__(max_bytes)
        self._lock = threading.Lock()
        self._max_streams = max_streams
        self._max_age_s = max_age_s
        self._clock = clock

    def _entry_bytes(self, entry: _StreamCache) -> int:
        return entry.nbytes

    def held(self, stream: str) -> tuple[int, frozenset[int]]:
        with self._lock:
            entry = self._streams.get(stream)
            return (-2, frozenset()) if entry is None else (entry.seq, frozenset(entry.spectra))

    def lookup(self, stream: str, seq: int, indices: Sequence[int]) -> tuple[PatchSpectra | None, list[int]]:
        """Cached spectra of frame ``seq`` for ``indices`` (in that order), or the list of missing ones."""
        with self._lock:
            entry = self._streams.get(stream)
            if entry is None or entry.seq != seq:
                return None, list(indices)
            last = entry.last
            if last is not None and last.indices.tolist() == list(indices):
                return last, []  # the sticky steady state: the same share as the previous frame
            missing = [i for i in indices if i not in entry.spectra]
            if missing:
                return None, missing
            rows = [entry.spectra[i] for i in indices]
        idx = np.asarray(indices, dtype=np.intp)
        if not rows:
            return PatchSpectra(idx, np.zeros((0, 0, 0), np.complex64), np.zeros((0,), np.float32)), []
        return PatchSpectra(
            indices=idx,
            spectra=np.stack([r[0] for r in rows]),
            texture_std=np.array([r[1] for r in rows], dtype=np.float32),
        ), []

    def store(self, stream: str, seq: int, spectra: PatchSpectra) -> None:
        """Remember spectra of frame ``seq`` (frames older than the cached one are ignored)."""
        now = self._clock()
        with self._lock:
            entry = self._streams.get(stream)
            # a frame far older than the cached one is a restarted stream (new epoch): it replaces it
            if entry is None or entry.seq < seq or entry.seq - seq > 2:
                if entry is not None:
                    self.nbytes -= entry.nbytes
                entry = _StreamCache(seq=seq, spectra={})
                self._streams[stream] = entry
            elif entry.seq > seq:
                return
            entry.stored_s = now
            self._streams.move_to_end(stream)
            entry.last = spectra if not entry.spectra else None
            for row, index in enumerate(spectra.indices.tolist()):
                old = entry.spectra.get(int(index))
                if old is not None:
                    entry.nbytes -= old[0].nbytes
                    self.nbytes -= old[0].nbytes
                entry.spectra[int(index)] = (spectra.spectra[row], spectra.texture_std[row])
                entry.nbytes += spectra.spectra[row].nbytes
                self.nbytes += spectra.spectra[row].nbytes
            while self._streams and (
                len(self._streams) > self._max_streams
                or self._over_budget()
                or now - next(iter(self._streams.values())).stored_s > self._max_age_s
            ):
                self._evict_oldest()


@dataclasses.dataclass
class _FrameCrops:
    """One frame's crops as they came (each add's array) and where each patch's crop is in them."""

    arrays: list[np.ndarray] = dataclasses.field(default_factory=list)
    rows: dict[int, tuple[int, int]] = dataclasses.field(default_factory=dict)
    nbytes: int = 0


class CropStore(_StreamBudget[dict[int, _FrameCrops]]):
    """Crops of the two newest frames of each stream, by patch index (a foreman's: a share moved to another
    worker, or re-dispatched after a failure, needs the previous frame's crops); bounded in total, across
    streams: beyond ``max_bytes`` of crops the least recently stored streams are evicted (never the one just
    stored). Each add's crops are held as one array, copied when it is a view (a decoded message's arrays
    view its whole payload), so what is held is what is counted.

    Two frames are kept because a second block of frame k (re-dispatched by the master) still refers to frame
    k-1 after the first block of frame k was stored. Not thread-safe: one thread serves a foreman's blocks.
    """

    def __init__(self, max_bytes: int | None = None, frames: int = 2) -> None:
        super().__init__(max_bytes)
        self._keep = frames

    def _entry_bytes(self, entry: dict[int, _FrameCrops]) -> int:
        return sum(crops.nbytes for crops in entry.values())

    def add(self, stream: str, seq: int, indices: np.ndarray, crops: np.ndarray) -> None:
        frames = self._streams.setdefault(stream, {})
        self._streams.move_to_end(stream)
        if frames and seq + self._keep < min(frames):
            self._drop(frames, list(frames))  # the stream restarted (a new camera run counts from 0 again)
        elif frames and seq < min(frames) and len(frames) >= self._keep:
            return  # older than everything kept
        held = crops if crops.base is None and crops.flags.c_contiguous else np.array(crops, copy=True)
        entry = frames.setdefault(seq, _FrameCrops())
        chunk = len(entry.arrays)
        entry.arrays.append(held)
        entry.rows.update((index, (chunk, row)) for row, index in enumerate(indices.tolist()))
        entry.nbytes += held.nbytes
        self.nbytes += held.nbytes
        self._drop(frames, sorted(frames)[: -self._keep])
        while self._over_budget() and len(self._streams) > 1:
            self._evict_oldest()

    def get(self, stream: str, seq: int, indices: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        if indices.size == 0:
            return np.zeros((0, *shape), dtype=np.uint8)
        entry = self._streams.get(stream, {}).get(seq)
        if entry is None:
            raise PatchWorkError(f"no crops of frame {seq} of {stream}")
        try:
            where = [entry.rows[int(i)] for i in indices]
        except KeyError as exc:
            raise PatchWorkError(f"no crop of patch {exc} in frame {seq} of {stream}") from None
        return np.stack([entry.arrays[chunk][row] for chunk, row in where])

    def _drop(self, frames: dict[int, _FrameCrops], seqs: list[int]) -> None:
        for seq in seqs:
            self.nbytes -= frames.pop(seq).nbytes


def measure_share(
    cache: SpectrumCache,
    settings: YawSettings,
    stream: str,
    seq: int,
    prev_seq: int,
    indices: npt.ArrayLike,
    crops_u8: np.ndarray,
    prev_indices: npt.ArrayLike,
    prev_crops_u8: np.ndarray,
) -> PatchMeasurement:
    """Shifts of patches ``indices`` of frame ``seq`` vs ``prev_seq``; caches the new spectra.

    Previous spectra come from ``prev_crops_u8`` where given, else from the cache; a missing one raises
    :class:`PatchWorkError` (the dispatcher then sends the previous patches).
    """
    idx = np.asarray(indices, dtype=np.intp)
    prev_idx = np.asarray(prev_indices, dtype=np.intp)
    given = set(prev_idx.tolist())
    from_cache = [int(i) for i in idx if int(i) not in given]
    cached, missing = cache.lookup(stream, prev_seq, from_cache) if from_cache else (None, [])
    if missing:
        raise PatchWorkError(
            f"no spectra of frame {prev_seq} for patches {missing[:10]} (send previous crops)"
        )
    current = patch_spectra_from_crops(crops_u8, idx, settings)
    if idx.size == 0:
        previous = current
    elif cached is not None and not prev_idx.size and np.array_equal(cached.indices, idx):
        previous = cached  # all previous spectra held, in order
    else:
        sent = patch_spectra_from_crops(prev_crops_u8, prev_idx, settings) if prev_idx.size else None
        rows: dict[int, tuple[np.ndarray, np.floating[Any]]] = {}
        for part in (cached, sent):
            if part is not None:
                for row, index in enumerate(part.indices.tolist()):
                    rows[int(index)] = (part.spectra[row], part.texture_std[row])
        previous = PatchSpectra(
            indices=idx,
            spectra=np.stack([rows[int(i)][0] for i in idx]),
            texture_std=np.array([rows[int(i)][1] for i in idx], dtype=np.float32),
        )
    measurement = measure_patches(previous, current, settings)
    cache.store(
        stream, seq, current
    )  # once measured: a share that fails to measure leaves the cache as it was
    return measurement


def measure_crops(
    settings: YawSettings, indices: npt.ArrayLike, crops_u8: np.ndarray, prev_crops_u8: np.ndarray
) -> PatchMeasurement:
    """Shifts of the crops ``crops_u8`` against ``prev_crops_u8`` (both (n, s, s), patches ``indices``), with
    nothing cached: a turning pair's refinement (a transient :class:`~common.wire.jobs.PatchJob`), whose
    crops are frame k turned back and must not replace frame k's spectra."""
    idx = np.asarray(indices, dtype=np.intp)
    if crops_u8.shape != prev_crops_u8.shape or crops_u8.shape[0] != idx.size:
        raise PatchWorkError(
            f"{idx.size} indices, crops {crops_u8.shape} and previous crops {prev_crops_u8.shape} differ"
        )
    previous = patch_spectra_from_crops(prev_crops_u8, idx, settings)
    return measure_patches(previous, patch_spectra_from_crops(crops_u8, idx, settings), settings)
