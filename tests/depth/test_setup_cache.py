"""The on-disk cache of a rig's cameras and rectification gives the set-up it stored, or nothing."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from prismstereo.apps.demo import demo_rig
from prismstereo.depth import DepthConfig
from prismstereo.depth import pipeline as pl
from prismstereo.depth.setup_cache import cache_folder, load_setup, save_setup, setup_key


@pytest.fixture()
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("PRISMSTEREO_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.delenv("PRISMSTEREO_CACHE", raising=False)
    return tmp_path / "c"


@pytest.fixture(scope="module")
def computed():
    rig = demo_rig()
    cfg = pl.validate_config(rig, DepthConfig(method="sad"))
    views = pl.virtual_cameras(rig, cfg)
    pair = pl.rectify_geometry(rig, views, cfg)
    return rig, cfg, views, pair, pl.epipolar_curves(pair)


def _same(a, b) -> None:
    for name in ("K", "R", "C_left", "C_right", "map_left", "map_right", "valid_left", "valid_right"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert (a.left_face, a.right_face, a.size, a.disparity_offset, a.remap, a.method) == \
           (b.left_face, b.right_face, b.size, b.disparity_offset, b.remap, b.method)
    for va, vb in ((a.view_left, b.view_left), (a.view_right, b.view_right)):
        assert (va.face, va.name, va.method, va.rms_px, va.max_px) == (vb.face, vb.name, vb.method, vb.rms_px,
                                                                        vb.max_px)
        for f in ("K", "R", "C", "dist"):
            assert np.array_equal(getattr(va.camera, f), getattr(vb.camera, f))


def test_round_trip_and_run_depth_uses_it(cache: Path, computed) -> None:
    rig, cfg, views, pair, epi = computed
    assert load_setup(rig, cfg.views, cfg.calibration) is None
    path = save_setup(rig, cfg.views, cfg.calibration, views, pair, epi)
    assert path is not None and path.parent == cache and not list(cache.glob(".setup-*"))
    got = load_setup(rig, cfg.views, cfg.calibration)
    assert got is not None
    _same(got[1], pair)
    assert np.array_equal(got[2].offsets, epi.offsets)
    assert (got[2].step, got[2].d_start, got[2].d_step) == (epi.step, epi.d_start, epi.d_step)
    # another model or pair of faces is another entry
    assert setup_key(rig, cfg.views, "thesis") != setup_key(rig, cfg.views, cfg.calibration)
    assert setup_key(rig, (0, 1), cfg.calibration) != setup_key(rig, cfg.views, cfg.calibration)
    setup = pl.prepare_depth(rig, config=DepthConfig(method="sad"))
    _same(setup.pair, pair)


def test_corrupt_entry_is_computed_again(cache: Path, computed) -> None:
    rig, cfg, views, pair, epi = computed
    path = save_setup(rig, cfg.views, cfg.calibration, views, pair, epi)
    assert path is not None
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])  # truncated (a crash of another writer, a full disk)
    assert load_setup(rig, cfg.views, cfg.calibration) is None
    setup = pl.prepare_depth(rig, config=DepthConfig(method="sad"))
    _same(setup.pair, pair)
    assert load_setup(rig, cfg.views, cfg.calibration) is not None  # rewritten whole


def test_disabled_or_unwritable_cache_costs_only_the_saving(cache: Path, computed, tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    rig, cfg, views, pair, epi = computed
    monkeypatch.setenv("PRISMSTEREO_CACHE", "0")
    assert cache_folder() is None
    assert save_setup(rig, cfg.views, cfg.calibration, views, pair, epi) is None
    pl.prepare_depth(rig, config=DepthConfig(method="sad"))
    assert not cache.exists()
    monkeypatch.delenv("PRISMSTEREO_CACHE")
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    monkeypatch.setenv("PRISMSTEREO_CACHE_DIR", str(blocker / "c"))  # a folder inside a file
    assert save_setup(rig, cfg.views, cfg.calibration, views, pair, epi) is None
    _same(pl.prepare_depth(rig, config=DepthConfig(method="sad")).pair, pair)


def test_concurrent_writers_leave_one_whole_entry(cache: Path, computed) -> None:
    rig, cfg, views, pair, epi = computed
    threads = [threading.Thread(target=save_setup, args=(rig, cfg.views, cfg.calibration, views, pair, epi))
               for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(list(cache.iterdir())) == 1
    got = load_setup(rig, cfg.views, cfg.calibration)
    assert got is not None
    _same(got[1], pair)


def test_old_entries_are_pruned(cache: Path, computed, monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    from prismstereo.depth import setup_cache

    rig, cfg, views, pair, epi = computed
    monkeypatch.setattr(setup_cache, "MAX_ENTRIES", 2)
    cache.mkdir(parents=True)
    for i in range(3):  # entries of other rigs or older code, oldest first
        f = cache / f"setup-old{i}.npz"
        f.write_bytes(b"x")
        os.utime(f, (1000.0 + i, 1000.0 + i))
    path = save_setup(rig, cfg.views, cfg.calibration, views, pair, epi)
    assert path is not None
    assert sorted(p.name for p in cache.iterdir()) == sorted([path.name, "setup-old2.npz"])


def test_ray_table_round_trip_and_bad_entries(cache: Path, computed) -> None:
    from prismstereo.depth.setup_cache import load_rays, save_rays
    from prismstereo.depth.triangulation import ray_table

    rig, cfg, views, pair, epi = computed
    shape = (pair.size[1], pair.size[0])
    table = ray_table(rig, pair)
    assert load_rays(rig, cfg.views, cfg.calibration, shape=shape) is None
    path = save_rays(rig, cfg.views, cfg.calibration, table)
    assert path is not None and path.name.startswith("rays-")
    got = load_rays(rig, cfg.views, cfg.calibration, shape=shape)
    assert got is not None
    for a, b in zip(got.to_arrays().values(), table.to_arrays().values(), strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    assert load_rays(rig, cfg.views, cfg.calibration, shape=(shape[0] + 1, shape[1])) is None  # another size
    path.write_bytes(path.read_bytes()[:1000])  # truncated: missing, not an error
    assert load_rays(rig, cfg.views, cfg.calibration, shape=shape) is None
    np.save(path, np.zeros((3, *shape, 3)))  # another layout: missing
    assert load_rays(rig, cfg.views, cfg.calibration, shape=shape) is None
    np.save(path, np.zeros((4, *shape, 3), dtype=np.float32))
    assert load_rays(rig, cfg.views, cfg.calibration, shape=shape) is None


def test_the_ray_table_maps_its_file_copy_on_write(cache: Path, computed) -> None:
    """The loaded table's arrays are views of the mapped entry (no read of the whole file); writing to them
    leaves the file as it was."""
    from prismstereo.depth.setup_cache import load_rays, save_rays
    from prismstereo.depth.triangulation import ray_table

    rig, cfg, views, pair, epi = computed
    shape = (pair.size[1], pair.size[0])
    path = save_rays(rig, cfg.views, cfg.calibration, ray_table(rig, pair))
    assert path is not None and path.suffix == ".npy"
    before = path.read_bytes()
    got = load_rays(rig, cfg.views, cfg.calibration, shape=shape)
    assert got is not None
    assert isinstance(got.left_origins.base, np.memmap) and got.left_origins.flags.writeable
    got.right_directions[0, 0, 0] = 12345.0
    assert path.read_bytes() == before


def test_run_depth_caches_the_ray_table(cache: Path) -> None:
    rig = demo_rig()
    s1 = pl.prepare_depth(rig, config=DepthConfig(method="sad"))
    assert s1.rays is not None and list(cache.glob("rays-*.npy"))
    s2 = pl.prepare_depth(rig, config=DepthConfig(method="sad"))
    assert s2.rays is not None and np.array_equal(s2.rays.right_directions, s1.rays.right_directions,
                                                  equal_nan=True)
    s3 = pl.prepare_depth(rig, config=DepthConfig(method="sad", triangulation="midpoint"))
    assert s3.rays is None


def test_rig_range_round_trip_and_same_region(cache: Path, computed) -> None:
    from prismstereo.depth.search_range import rig_range
    from prismstereo.depth.setup_cache import load_range, save_range

    rig, cfg, views, pair, epi = computed
    shape = (pair.size[1], pair.size[0])
    found = rig_range(pair, rig.prism.back_distance)
    assert load_range(rig, cfg.views, cfg.calibration, shape=shape) is None
    path = save_range(rig, cfg.views, cfg.calibration, found)
    assert path is not None and path.name.startswith("range-")
    got = load_range(rig, cfg.views, cfg.calibration, shape=shape)
    assert got is not None and got.depth_mm == found.depth_mm and got.disparity_px == found.disparity_px
    assert np.array_equal(got.region, found.region) and np.array_equal(got.disparity, found.disparity, equal_nan=True)
    assert load_range(rig, cfg.views, cfg.calibration, shape=(1, 1)) is None
    path.write_bytes(b"PK\x03\x04 truncated")
    assert load_range(rig, cfg.views, cfg.calibration, shape=shape) is None
    # the region a run searches is the same with the cached rig range as without
    with_known = pl.search_region(rig, pair, cfg, known=found)
    without = pl.search_region(rig, pair, cfg)
    assert np.array_equal(with_known.mask, without.mask)
    assert with_known.disparity_range == without.disparity_range and with_known.depth_range == without.depth_range


def test_common_view_round_trip_and_other_depths_miss(cache: Path, computed) -> None:
    from prismstereo.depth.setup_cache import load_view, save_view
    from prismstereo.rectify import common_view

    rig, cfg, views, pair, epi = computed
    shape = (pair.size[1], pair.size[0])
    region, disp = common_view(pair, 300.0, 900.0)
    assert load_view(rig, cfg.views, cfg.calibration, depth_mm=(300.0, 900.0), shape=shape) is None
    path = save_view(rig, cfg.views, cfg.calibration, depth_mm=(300.0, 900.0), region=region, disparity_px=disp)
    assert path is not None and path.name.startswith("view-")
    got = load_view(rig, cfg.views, cfg.calibration, depth_mm=(300.0, 900.0), shape=shape)
    assert got is not None and np.array_equal(got[0], region) and got[1] == disp
    assert load_view(rig, cfg.views, cfg.calibration, depth_mm=(300.0, 901.0), shape=shape) is None
    assert load_view(rig, cfg.views, cfg.calibration, depth_mm=(300.0, 900.0), shape=(1, 1)) is None
    path.write_bytes(b"PK\x03\x04 truncated")
    assert load_view(rig, cfg.views, cfg.calibration, depth_mm=(300.0, 900.0), shape=shape) is None


def test_search_region_reads_the_cached_view_with_the_same_region(cache: Path, computed, monkeypatch) -> None:
    rig, _, views, pair, epi = computed
    cfg = pl.validate_config(rig, DepthConfig(method="sad", depth_range=(300.0, 900.0)))
    plain = pl.search_region(rig, pair, cfg)
    first = pl.search_region(rig, pair, cfg, cached=True)
    assert len(list(cache.glob("view-*.npz"))) == 1

    def fail(*a, **k):
        raise AssertionError("common_view computed again")

    monkeypatch.setattr(pl, "common_view", fail)
    second = pl.search_region(rig, pair, cfg, cached=True)
    for got in (first, second):
        assert np.array_equal(got.mask, plain.mask)
        assert got.disparity_range == plain.disparity_range and got.depth_range == plain.depth_range
    other = pl.validate_config(rig, DepthConfig(method="sad", depth_range=(300.0, 950.0)))
    with pytest.raises(AssertionError, match="computed again"):
        pl.search_region(rig, pair, other, cached=True)
