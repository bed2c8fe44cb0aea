"""The one grey-image check of the cores."""

from __future__ import annotations

import numpy as np
import pytest

from common.errors import InputError
from common.images import check_grey_image


@pytest.mark.parametrize(
    ("image", "message"),
    [
        (np.zeros((0, 0), np.uint8), "empty"),
        (np.zeros((20, 20), np.float32), "uint8"),
        (np.zeros((20, 20), np.uint16), "uint8"),
        (np.zeros((20, 20, 3), np.uint8), r"grey image of shape \(H, W\)"),
        ([[1, 2], [3, 4]], "numpy array"),
        (np.zeros((7, 20), np.uint8), "at least 8x8"),
    ],
)
def test_what_is_not_a_grey_image_is_refused_with_one_clear_line(image: object, message: str) -> None:
    with pytest.raises(InputError, match=message):
        check_grey_image(image, min_side_px=8)


def test_a_grey_image_is_returned_as_is() -> None:
    image = np.zeros((8, 9), np.uint8)
    assert check_grey_image(image, min_side_px=8) is image
    assert check_grey_image(np.zeros((1, 1), np.uint8)).shape == (1, 1)
