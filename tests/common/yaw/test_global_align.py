from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from common.yaw import (
    EstimateMethod,
    YawSettings,
    estimate_global_alignment,
    estimate_pair,
    rotation_of_homography_rad,
    scale_of_homography,
)

from .conftest import PairMaker


@pytest.mark.parametrize(("delta_yaw_deg", "altitude_ratio"), [(25.0, 1.0), (-100.0, 1.1), (160.0, 0.9)])
def test_fourier_mellin_recovers_rotation_and_scale(
    nadir_pair: PairMaker, delta_yaw_deg: float, altitude_ratio: float
) -> None:
    a, b = nadir_pair(delta_yaw_deg, (10.0, -7.0), altitude_ratio=altitude_ratio)
    alignment = estimate_global_alignment(a, b, YawSettings())
    assert (
        abs(math.degrees(math.remainder(alignment.rotation_rad - math.radians(delta_yaw_deg), 2 * math.pi)))
        < 0.5
    )
    assert alignment.scale == pytest.approx(1.0 / altitude_ratio, rel=0.02)
    assert alignment.response > 0.3


def _boat(shared_data: Path, name: str) -> np.ndarray:
    image = cv2.imread(str(shared_data / "oxford_boat" / name), cv2.IMREAD_GRAYSCALE)
    assert image is not None, name
    return np.asarray(image, dtype=np.uint8)


@pytest.mark.parametrize("pair", [2, 3])
def test_oxford_boat_rotation_within_half_a_degree(shared_data: Path, pair: int) -> None:
    """Real photographs: img1 -> img2 (-14 deg, 0.885 zoom) and img1 -> img3 (-40 deg) against H1toNp."""
    img1 = _boat(shared_data, "img1.pgm")
    img_n = _boat(shared_data, f"img{pair}.pgm")
    truth = np.loadtxt(shared_data / "oxford_boat" / f"H1to{pair}p")
    centre = ((img1.shape[1] - 1) / 2.0, (img1.shape[0] - 1) / 2.0)
    true_rotation = math.degrees(rotation_of_homography_rad(truth, centre))
    estimate = estimate_pair(img1, img_n, YawSettings())
    assert estimate.method is EstimateMethod.GLOBAL_PREALIGNED and not estimate.low_confidence
    assert abs(math.degrees(estimate.delta_yaw_rad) - true_rotation) < 0.5
    assert scale_of_homography(estimate.homography, centre) == pytest.approx(
        scale_of_homography(truth, centre), rel=0.01
    )
