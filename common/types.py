"""Array type aliases shared by the cores (one home; modules import them instead of redefining them)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

#: float64 arrays: positions, angles, covariances, measurements
FloatArray = npt.NDArray[np.float64]
#: float32 arrays: image-sized intermediate results (edges, distance transforms, spectra magnitudes)
Float32Array = npt.NDArray[np.float32]
#: booleans: masks, validity flags
BoolArray = npt.NDArray[np.bool_]
#: uint8 arrays: grey images and crops
U8Array = npt.NDArray[np.uint8]

__all__ = ["BoolArray", "Float32Array", "FloatArray", "U8Array"]
