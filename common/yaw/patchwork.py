"""The distributable yaw stage as a member runs it: cached spectra per stream, subsets of patches.

A member (worker, or a master/foreman computing its own share) keeps the spectra of the patches it
computed for the newest frame of each stream. A job for frame ``seq`` measured against ``prev_seq``
brings the new crops, plus previous crops for indices the member does not hold; everything else comes
from the cache, so only the new frame travels. The arithmetic is the yaw core's own
(``patch_spectra_from_crops``, ``measure_patches``), so the results equal the in-process core bit for bit.
"""

from __future__ import annotations

import dataclasses
import enum
import threading
import time
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from common.errors import CapatazError
from common.yaw.correlation import PatchMeasurement, PatchSpectra, measure_patches, patch_spectra_from_crops
from common.yaw.settings import YawSettings


class PatchWorkError(CapatazError):
    """A job cannot be computed (missing previous spectra, inconsistent settings or crops)."""


#: Settings only the central stage uses (the lens model): never sent to members.
LOCAL_SETTINGS = frozenset({"camera"})


def settings_to_wire(settings: YawSettings) -> dict[str, Any]:
    """Yaw settings as a flat msgpack-able dict (enums by value), without :data:`LOCAL_SETTINGS`."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(settings):
        if f.name in LOCAL_SETTINGS:
            continue
        value = getattr(settings, f.name)
        out[f.name] = value.value if isinstance(value, enum.Enum) else value
    return out


#: Bounds of the yaw settings a job may carry (a member allocates windows and spectra of these sizes):
#: checked at the wire, before any allocation. The largest values in use are far below.
WIRE_SETTING_BOUNDS: dict[str, tuple[float, float]] = {
    "patch_size_px": (8, 256),
    "grid_cols": (1, 64),
    "grid_rows": (1, 64),
    "margin_px": (0, 4096),
    "pyramid_level": (0, 4),
    "ransac_max_iters": (1, 10_000),
    "min_inliers": (3, 4096),
    "global_size_px": (64, 1024),
    "global_angle_bins": (90, 4096),
    "peak_sigma_px": (1e-3, 64.0),
    "ransac_threshold_px": (1e-3, 1e3),
    "max_residual_px": (1e-3, 1e3),
    "overlap_correction": (0.0, 8.0),
    "min_texture_std": (0.0, 255.0),
    "min_peak_ratio": (0.0, 1e3),
}


def settings_from_wire(values: dict[str, Any]) -> YawSettings:
    """Inverse of :func:`settings_to_wire`; unknown, out-of-bounds (:data:`WIRE_SETTING_BOUNDS`) or invalid
    fields raise :class:`PatchWorkError`."""
    defaults = YawSettings()
    known = {f.name for f in dataclasses.fields(YawSettings)} - LOCAL_SETTINGS
    unknown = set(values) - known
    if unknown:
        raise PatchWorkError(f"unknown yaw settings {sorted(unknown)}")
    kwargs: dict[str, Any] = {}
    for name, value in values.items():
        default = getattr(defaults, name)
        try:
            if isinstance(default, enum.Enum):
                kwargs[name] = type(default)(value)
            elif isinstance(default, float):
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise ValueError(f"expected a number, got {value!r}")
                kwargs[name] = float(value)
            elif isinstance(default, int) and not isinstance(default, bool):
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ValueError(f"expected an integer, got {value!r}")
                kwargs[name] = value
            else:
                kwargs[name] = value
        except ValueError as exc:
            raise PatchWorkError(f"yaw setting {name}: {exc}") from None
        bounds = WIRE_SETTING_BOUNDS.get(name)
        if bounds is not None and not bounds[0] <= kwargs[name] <= bounds[1]:
            raise PatchWorkError(f"yaw setting {name} = {kwargs[name]!r} outside {bounds[0]}..{bounds[1]}")
    try:
        return YawSettings(**kwargs)
    except (ValueError, TypeError) as exc:
        raise PatchWorkError(f"invalid yaw settings: {exc}") from None


class SettingsCache:
    """Parsed yaw settings by their wire form: every job carries them, and parsing each time costs more than
    a lookup. Bounded: a handful of distinct settings at most are in use at once."""

    def __init__(self, max_entries: int = 8) -> None:
        self._parsed: dict[tuple[tuple[str, Any], ...], YawSettings] = {}
        self._max_entries = max_entries

    def parsed(self, values: dict[str, Any]) -> YawSettings:
        """``settings_from_wire(values)``, cached; invalid settings raise :class:`PatchWorkError`."""
        key = tuple(sorted(values.items()))
        settings = self._parsed.get(key)
        if settings is None:
            settings = settings_from_wire(values)
            if len(self._parsed) > self._max_entries:
                self._parsed.clear()
            self._parsed[key] = settings
        return settings


@dataclasses.dataclass
class _StreamCache:
    seq: int
    spectra: dict[int, tuple[np.ndarray, np.floating[Any]]]
    #: the last share stored whole: a lookup of exactly its indices returns it without re-stacking
    last: PatchSpectra | None = None
    stored_s: float = 0.0


class SpectrumCache:
    """Newest-frame spectra per (stream, patch index); thread-safe; bounded number of streams (the least
    recently stored beyond ``max_streams`` and any not stored to for ``max_age_s`` are evicted)."""

    def __init__(self, max_streams: int = 64, max_age_s: float = 60.0, clock: Any = time.monotonic) -> None:
        self._streams: OrderedDict[str, _StreamCache] = OrderedDict()
        self._lock = threading.Lock()
        self._max_streams = max_streams
        self._max_age_s = max_age_s
        self._clock = clock

    def __len__(self) -> int:
        return len(self._streams)

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
                entry = _StreamCache(seq=seq, spectra={})
                self._streams[stream] = entry
            elif entry.seq > seq:
                return
            entry.stored_s = now
            self._streams.move_to_end(stream)
            entry.last = spectra if not entry.spectra else None
            for row, index in enumerate(spectra.indices.tolist()):
                entry.spectra[int(index)] = (spectra.spectra[row], spectra.texture_std[row])
            while len(self._streams) > self._max_streams:
                self._streams.popitem(last=False)
            while self._streams and now - next(iter(self._streams.values())).stored_s > self._max_age_s:
                self._streams.popitem(last=False)


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
    cache.store(stream, seq, current)
    if idx.size == 0:
        return measure_patches(current, current, settings)
    if cached is not None and not prev_idx.size and np.array_equal(cached.indices, idx):
        return measure_patches(cached, current, settings)  # all previous spectra held, in order
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
    return measure_patches(previous, current, settings)


def merge_measurements(parts: Sequence[PatchMeasurement], expected: npt.ArrayLike) -> PatchMeasurement:
    """One measurement in ascending index order from disjoint parts that cover ``expected`` exactly."""
    want = np.sort(np.asarray(expected, dtype=np.intp))
    if len(parts) == 1 and np.array_equal(np.asarray(parts[0].indices, dtype=np.intp), want):
        only = parts[0]  # one member computed everything, in order (the usual case): no concatenation
        return PatchMeasurement(
            indices=want,
            shift_px=np.asarray(only.shift_px, dtype=np.float64).reshape(-1, 2),
            confidence=np.asarray(only.confidence, dtype=np.float64),
            peak=np.asarray(only.peak, dtype=np.float64),
            valid=np.asarray(only.valid, dtype=np.bool_),
        )
    indices = (
        np.concatenate([np.asarray(p.indices, dtype=np.intp) for p in parts])
        if parts
        else np.zeros(0, np.intp)
    )
    order = np.argsort(indices, kind="stable")
    if not np.array_equal(indices[order], want):
        raise PatchWorkError(f"parts cover {indices.size} indices, expected each of {want.size} exactly once")
    return PatchMeasurement(
        indices=indices[order],
        shift_px=np.concatenate([np.asarray(p.shift_px, dtype=np.float64).reshape(-1, 2) for p in parts])[
            order
        ],
        confidence=np.concatenate([np.asarray(p.confidence, dtype=np.float64) for p in parts])[order],
        peak=np.concatenate([np.asarray(p.peak, dtype=np.float64) for p in parts])[order],
        valid=np.concatenate([np.asarray(p.valid, dtype=np.bool_) for p in parts])[order],
    )
