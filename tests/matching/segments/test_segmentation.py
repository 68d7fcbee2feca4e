"""Mean-shift segmentation (thesis §5.1)."""

from __future__ import annotations

import cv2
import numpy as np

from prismstereo.matching.segments.segmentation import (
    SegmentationParams,
    _mean_shift_filter,
    mean_shift_segment,
    segment_adjacency,
)


def _two_regions(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.zeros((40, 60, 3), np.float64)
    img[:, :30] = (200, 40, 40)
    img[:, 30:] = (40, 60, 200)
    img += rng.normal(0, 1.5, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_two_flat_regions_are_separated() -> None:
    lab = mean_shift_segment(_two_regions(), params=SegmentationParams(hs=5, hr=6, min_region=20))
    assert lab.shape == (40, 60) and lab.dtype == np.int32
    assert len(np.unique(lab[:, :30])) == 1 and len(np.unique(lab[:, 30:])) == 1
    assert lab[0, 0] != lab[0, -1]


def test_min_region_merges_small_blobs() -> None:
    img = _two_regions(1)
    img[10:13, 5:8] = (250, 250, 250)  # a 9-pixel blob
    small = mean_shift_segment(img, params=SegmentationParams(hs=5, hr=6, min_region=5))
    big = mean_shift_segment(img, params=SegmentationParams(hs=5, hr=6, min_region=20))
    assert small.max() + 1 == 3
    assert big.max() + 1 == 2
    assert np.bincount(big.ravel()).min() >= 20


def test_adjacency_pairs_and_lengths() -> None:
    lab = np.zeros((4, 6), np.int32)
    lab[:, 3:] = 1
    lab[3, :] = 2
    pairs, length, _ = segment_adjacency(lab)
    got = {tuple(p): n for p, n in zip(pairs.tolist(), length.tolist(), strict=True)}
    assert got == {(0, 1): 3.0, (0, 2): 3.0, (1, 2): 3.0}


def test_mean_shift_filter_is_opencvs_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    # smooth gradients with noise and hard edges: pixels converge after 1 to 5 iterations, some at windows
    # clipped by the image border
    yy, xx = np.mgrid[0:37, 0:53]
    img = np.stack([3 * xx, 4 * yy, 2 * (xx + yy)], axis=2) + rng.normal(0, 3, (37, 53, 3))
    img[10:25, 20:40] += 60
    img = np.clip(img, 0, 255).astype(np.uint8)
    for sp, sr in ((5, 4.0), (5, 3.0), (3, 7.5), (2.5, 4.5), (1, 12.0)):
        ref = cv2.pyrMeanShiftFiltering(img, sp=float(sp), sr=float(sr), maxLevel=0)
        assert np.array_equal(_mean_shift_filter(img, float(sp), float(sr)), ref), (sp, sr)
    noise = rng.integers(0, 256, (9, 4, 3)).astype(np.uint8)
    assert np.array_equal(_mean_shift_filter(noise, 5.0, 40.0), cv2.pyrMeanShiftFiltering(noise, 5.0, 40.0, maxLevel=0))
    # the comparison tells filters apart: another range radius changes the result
    assert not np.array_equal(_mean_shift_filter(img, 5.0, 9.0), cv2.pyrMeanShiftFiltering(img, 5.0, 4.0, maxLevel=0))
