"""The state of a master's yaw stream: what one epoch of one UAV's frames is measured with and where it is."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from common.dispatch import Dispatcher
from common.wire.messages import YawJobSettings
from common.yaw import PatchGrid, TrackerState, YawSettings, YawTracker
from common.yaw.grid import U8Array
from common.yaw.patchwork import SpectrumCache
from services.master.refine import RefineChooser


@dataclass
class YawStream:
    #: the master's yaw settings with the pyramid level resolved for the stream's frames, and their wire form
    settings: YawSettings
    wire_settings: YawJobSettings
    grid: PatchGrid
    tracker: YawTracker
    state: TrackerState
    prev_seq: int
    prev_level: U8Array
    dispatcher: Dispatcher
    epoch: int = 0
    cache: SpectrumCache = field(default_factory=SpectrumCache)
    #: every patch index of the grid (the round's expected cover)
    all_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.intp))
    #: the id of the stream's rig the stream was started with (None: the master's own options)
    rig_id: str | None = None
    #: where its turning frames' second pass has cost less (the members or the master)
    refine_chooser: RefineChooser = field(default_factory=RefineChooser)
