"""Mean-shift segmentation (thesis §5.1)."""

from __future__ import annotations

import numpy as np

from prismstereo.matching.segments.segmentation import SegmentationParams, mean_shift_segment, segment_adjacency


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
