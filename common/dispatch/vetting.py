"""Which member's patches agree with a frame's robust fit (pure glue of the yaw fit and the trust core).

The dispatcher of a frame (the master) fits the merged measurement once more with the yaw core's own
robust fit (paper A's RANSAC, :func:`common.yaw.fit.fit_correspondences`) and counts, per member, the valid
patches that are outliers of it: :func:`round_outcomes` feeds :class:`~common.dispatch.trust.TrustMonitor`.
A frame whose patch fit is poor (too few inliers) judges nobody.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from common.dispatch.trust import MemberOutcome, outcomes_of_fit
from common.yaw.fit import fit_correspondences
from common.yaw.measurement import PatchMeasurement
from common.yaw.settings import YawSettings


def round_outcomes(
    owners: Sequence[str],
    parts: Sequence[PatchMeasurement],
    merged: PatchMeasurement,
    centres_px: npt.NDArray[np.float64],
    settings: YawSettings,
) -> list[MemberOutcome]:
    """Per-member outcomes of one frame, or [] when fewer than two members took part or the fit is poor.

    ``owners[k]`` computed ``parts[k]``; ``merged`` is the frame's merged measurement (ascending indices);
    ``centres_px`` the grid's patch centres (full-resolution pixels).
    """
    if len(set(owners)) < 2:
        return []
    valid = np.asarray(merged.valid, dtype=bool)
    src = np.asarray(centres_px, dtype=np.float64)[np.asarray(merged.indices)[valid]]
    fit = fit_correspondences(src, src + np.asarray(merged.shift_px)[valid], settings)
    if not fit.ok or fit.inlier_count < settings.min_inlier_fraction * merged.indices.size:
        return []
    return outcomes_of_fit(owners, [p.indices for p in parts], merged.indices, valid, fit.inliers)
