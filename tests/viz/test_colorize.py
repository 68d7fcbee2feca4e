from __future__ import annotations

import numpy as np
import pytest

from prismstereo.errors import ImageError
from prismstereo.viz.colorize import colorbar, colorize_depth, colorize_disparity


def test_colorize_disparity_nan_black_and_range() -> None:
    d = np.array([[0.0, 5.0, np.nan], [10.0, 2.0, 20.0]], np.float32)
    rgb = colorize_disparity(d, vmin=0, vmax=10)
    assert rgb.shape == (2, 3, 3) and rgb.dtype == np.uint8
    assert np.all(rgb[0, 2] == 0)
    assert np.array_equal(rgb[1, 0], rgb[1, 2])  # clipped at vmax
    assert not np.array_equal(rgb[0, 0], rgb[1, 0])


def test_colorize_depth_and_bar() -> None:
    z = np.array([[500.0, np.inf], [1000.0, 2000.0]])
    rgb = colorize_depth(z)
    assert np.all(rgb[0, 1] == 0)
    bar = colorbar(vmin=0, vmax=10, height=16, width=4)
    assert bar.shape == (16, 4, 3)
    with pytest.raises(ImageError):
        colorize_disparity(np.zeros((2, 2, 2)))
