"""The one image-coercion rule (prismstereo.io.images.as_image, docs/conventions.md) and its users agree."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from prismstereo.calibration import boards
from prismstereo.errors import ImageError
from prismstereo.io.images import as_image, to_gray
from prismstereo.matching.api import validate_pair
from prismstereo.matching.local.costs import to_gray as cost_gray

RNG = np.random.default_rng(3)
IMG8 = RNG.integers(0, 256, (12, 16, 3), dtype=np.uint8)


def test_uint8_is_kept_exactly() -> None:
    assert as_image(IMG8) is not None and np.array_equal(as_image(IMG8), IMG8)
    np.testing.assert_array_equal(as_image(IMG8, dtype=np.float32), IMG8.astype(np.float32))


def test_16_bit_and_float_scales_meet_the_8_bit_one() -> None:
    img16 = IMG8.astype(np.uint16) * 257  # 255 -> 65535
    np.testing.assert_array_equal(as_image(img16), IMG8)
    np.testing.assert_array_equal(as_image(IMG8 / 255.0), IMG8)  # scikit-image's [0, 1] floats
    np.testing.assert_array_equal(as_image(IMG8.astype(np.float64)), IMG8)  # 0..255 floats
    np.testing.assert_array_equal(as_image(IMG8.astype(np.int32)), IMG8)
    np.testing.assert_allclose(as_image(img16, dtype=np.float32), IMG8, atol=1e-4)


def test_rounding_clipping_and_channels() -> None:
    f = np.array([[-3.0, 0.4, 0.6, 254.5, 300.0]])
    np.testing.assert_array_equal(as_image(f), [[0, 0, 1, 254, 255]])
    assert as_image(IMG8[:, :, :1]).shape == (12, 16)
    rgba = np.dstack([IMG8, np.full((12, 16), 7, np.uint8)])
    np.testing.assert_array_equal(as_image(rgba), IMG8)
    gray = as_image(IMG8[:, :, 0], channels=3)
    assert gray.shape == (12, 16, 3) and np.array_equal(gray[:, :, 2], IMG8[:, :, 0])
    assert as_image(IMG8, channels=1).shape == (12, 16)


@pytest.mark.parametrize(("bad", "what"), [
    (np.zeros((4, 4), bool), "dtype"), (np.full((4, 4), np.nan), "finite"), (np.zeros((4, 4, 2)), "shape"),
    (np.zeros((0, 4)), "non-empty"), (np.zeros((4, 4), complex), "dtype"),
])
def test_bad_images_are_image_errors(bad: np.ndarray, what: str) -> None:
    with pytest.raises(ImageError, match=what):
        as_image(bad, name="left")


def test_one_gray_conversion() -> None:
    """BT.601 luminance; the matchers' and the board detection's gray are this one (rounded for the boards)."""
    def board_gray(image: np.ndarray) -> np.ndarray:
        return as_image(image, channels=1)

    assert not hasattr(boards, "to_gray")  # one public to_gray: the boards read as_image's 8-bit gray
    g = to_gray(IMG8)
    np.testing.assert_allclose(g, IMG8 @ np.array([0.299, 0.587, 0.114]), rtol=1e-5)
    assert cost_gray is to_gray
    np.testing.assert_array_equal(board_gray(IMG8), np.clip(np.rint(g), 0, 255).astype(np.uint8))
    # OpenCV's fixed-point 8-bit conversion agrees within one level
    assert int(np.abs(board_gray(IMG8).astype(int) - cv2.cvtColor(IMG8, cv2.COLOR_RGB2GRAY)).max()) <= 1
    np.testing.assert_array_equal(board_gray(IMG8.astype(np.uint16) * 257), board_gray(IMG8))


def test_a_pair_decides_its_float_scale_once() -> None:
    left = IMG8 / 255.0
    right = (IMG8 / 255.0) * 0.5
    lt, rt = validate_pair(left, right)
    np.testing.assert_allclose(lt, IMG8, atol=1e-3)
    np.testing.assert_allclose(rt, IMG8 * 0.5, atol=1e-3)
    lt16, _ = validate_pair(IMG8.astype(np.uint16) * 257, IMG8.astype(np.uint16) * 257)
    np.testing.assert_allclose(lt16, IMG8, atol=1e-4)
    l8, _ = validate_pair(IMG8, IMG8)
    assert l8.dtype == np.uint8 and np.array_equal(l8, IMG8)
