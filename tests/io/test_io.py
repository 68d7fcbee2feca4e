from __future__ import annotations

import numpy as np
import pytest

from prismstereo.errors import ImageError, OutputError
from prismstereo.io import output_dir, read_image, read_pfm, read_ply, write_image, write_pfm, write_ply


def test_pfm_round_trip_with_nan(tmp_path):
    a = np.random.default_rng(0).normal(size=(7, 5)).astype(np.float32)
    a[2, 3] = np.nan
    write_pfm(tmp_path / "a.pfm", a)
    raw = (tmp_path / "a.pfm").read_bytes()
    assert raw.startswith(b"Pf\n5 7\n-1.0\n")
    # Middlebury convention: rows bottom to top, so the first stored row is the last image row.
    np.testing.assert_array_equal(np.frombuffer(raw[-20:], "<f4"), a[0])
    b = read_pfm(tmp_path / "a.pfm")
    np.testing.assert_array_equal(np.isnan(b), np.isnan(a))
    np.testing.assert_array_equal(b[~np.isnan(b)], a[~np.isnan(a)])


def test_image_round_trip_keeps_rgb_order(tmp_path):
    img = np.zeros((4, 6, 3), np.uint8)
    img[..., 0] = 200  # red
    write_image(tmp_path / "x.png", img)
    back = read_image(tmp_path / "x.png")
    np.testing.assert_array_equal(back, img)
    assert read_image(tmp_path / "x.png", gray=True).shape == (4, 6)


def test_image_errors(tmp_path):
    with pytest.raises(ImageError, match="no such file"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(ImageError, match="empty"):
        read_image(tmp_path / "empty.png")
    (tmp_path / "junk.png").write_bytes(b"not an image at all")
    with pytest.raises(ImageError, match="cannot decode"):
        read_image(tmp_path / "junk.png")
    with pytest.raises(ImageError):
        write_image(tmp_path / "bad.png", np.zeros((2, 2, 5)))


def test_ply_round_trip(tmp_path):
    pts = np.random.default_rng(1).normal(size=(20, 3)).astype(np.float32)
    cols = np.random.default_rng(2).integers(0, 255, size=(20, 3)).astype(np.uint8)
    write_ply(tmp_path / "p.ply", pts, cols)
    p, c = read_ply(tmp_path / "p.ply")
    np.testing.assert_array_equal(p, pts)
    np.testing.assert_array_equal(c, cols)
    write_ply(tmp_path / "q.ply", pts, binary=False)
    assert (tmp_path / "q.ply").read_text().startswith("ply\nformat ascii")


def test_output_dir_leaves_nothing_on_failure(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError), output_dir(out) as stage:
        (stage / "a.txt").write_text("half")
        raise RuntimeError("boom")
    assert not out.exists() and list(tmp_path.iterdir()) == []  # not even the folder
    with output_dir(out) as stage:
        (stage / "a.txt").write_text("done")
    assert [p.name for p in out.iterdir()] == ["a.txt"]


def test_unwritable_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError):
        write_pfm(blocker / "sub" / "a.pfm", np.zeros((2, 2)))


def test_outputs_get_umask_permissions(tmp_path):
    import os

    mask = os.umask(0o022)
    try:
        write_pfm(tmp_path / "a.pfm", np.zeros((2, 2)))
    finally:
        os.umask(mask)
    assert (tmp_path / "a.pfm").stat().st_mode & 0o777 == 0o644
