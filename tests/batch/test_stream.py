"""Streaming depth: a synthetic video and a folder of simulated captures give their depth; bad sources fail
before any frame with one clear error."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from prismstereo.apps.cli import main
from prismstereo.apps.demo import demo_rig, plane_scene
from prismstereo.batch.stream import open_source, run_stream, source_kind
from prismstereo.depth import DepthConfig, prepare_depth, run_depth_frame
from prismstereo.depth.presets import apply_preset
from prismstereo.errors import ConfigError, ImageError
from prismstereo.evaluation.depth_metrics import evaluate_depth
from prismstereo.io import write_image

DISTANCES = (1150.0, 1300.0, 1450.0)
CONFIG = DepthConfig(method="sgm", depth_range=(1000.0, 1700.0))


@pytest.fixture(scope="module")
def captures():  # type: ignore[no-untyped-def]
    from prismstereo.simulate import render_capture

    rig = demo_rig()
    scenes = [plane_scene(z, tilt_deg=20.0, seed=40 + i) for i, z in enumerate(DISTANCES)]
    return rig, scenes, [render_capture(rig, s).image for s in scenes]


def _video(path: Path, images, fourcc: str = "FFV1") -> Path:  # type: ignore[no-untyped-def]
    h, w = images[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 5.0, (w, h))
    assert vw.isOpened()
    for img in images:
        vw.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    vw.release()
    return path


def _accurate(results, scenes) -> None:  # type: ignore[no-untyped-def]
    for res, scene in zip(results, scenes, strict=True):
        acc = evaluate_depth(res, scene=scene)
        assert acc["median_rel"] < 0.005 and acc["within_1pct"] > 0.8, acc


def test_video_stream_recovers_depth(tmp_path: Path, captures) -> None:  # type: ignore[no-untyped-def]
    rig, scenes, images = captures
    src = _video(tmp_path / "caps.avi", images)
    got: list = []
    # the fast preset's profile (what the stream command runs by default), recorded in stream.json
    fast = apply_preset(CONFIG, "fast", given=["depth_range"])
    summary = run_stream(rig, str(src), tmp_path / "out", config=fast, video=tmp_path / "depth.avi",
                         on_frame=lambda name, res: got.append((name, res)), preset="fast")
    assert summary.frames == 3 and not summary.failed and not summary.interrupted
    assert summary.frames_per_s > 0 and set(summary.stage_s) == {"read", "depth", "write"}
    assert [n for n, _ in got] == [f"caps_{i:06d}" for i in range(3)]
    _accurate([r for _, r in got], scenes)
    for name, res in got:
        png = cv2.imread(str(tmp_path / "out" / "frames" / name / "depth.png"), cv2.IMREAD_UNCHANGED)
        assert png.dtype == np.uint16
        ok = res.valid
        assert np.abs(png[ok].astype(float) - res.depth[ok]).max() <= 0.5 + 1e-6
        assert (tmp_path / "out" / "frames" / name / "disparity.pfm").is_file()
    info = json.loads((tmp_path / "out" / "stream.json").read_text())
    assert info["preset_profile"]["name"] == "fast" and info["preset_profile"]["overridden"] == []
    assert info["config"]["refine_radius"] == fast.refine_radius and info["config"]["depth_range"] == [1000, 1700]
    cap = cv2.VideoCapture(str(tmp_path / "depth.avi"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    cap.release()


def test_folder_stream_takes_new_images_and_skips_bad_ones(tmp_path: Path, captures) -> None:  # type: ignore[no-untyped-def]
    rig, scenes, images = captures
    folder = tmp_path / "in"
    folder.mkdir()
    write_image(folder / "a.png", images[0])
    write_image(folder / "b.png", images[1])
    write_image(folder / "c_small.png", images[2][:100, :100])  # wrong size: that frame fails
    (folder / "d_corrupt.png").write_bytes(b"not a png at all")
    got: list = []

    def on_frame(name: str, res: object) -> None:
        got.append((name, res))
        if name == "a":  # a frame that arrives while the stream runs, after its first listing of the folder
            write_image(folder / "e_late.png", images[2])

    # the late frame is written after frame a's depth, which the idle clock (started at the first listing)
    # must outlast on a loaded 2-core machine: the default idle timeout, not a shorter one
    summary = run_stream(rig, str(folder), tmp_path / "out", config=CONFIG, idle_timeout=10.0, poll_s=0.05,
                         on_frame=on_frame)
    assert [n for n, _ in got] == ["a", "b", "e_late"]
    assert sorted(n for n, _ in summary.failed) == ["c_small", "d_corrupt"]
    assert "512×384" in dict(summary.failed)["c_small"]
    _accurate([r for _, r in got], scenes)
    assert sorted(p.name for p in (tmp_path / "out" / "frames").iterdir()) == ["a", "b", "e_late"]


def test_folder_idle_clock_does_not_count_the_consumers_time(tmp_path: Path) -> None:
    # a consumer that holds a frame longer than the idle timeout (a full queue behind a slow first depth, a cold
    # numba cache) must not end the folder: the folder was not watched meanwhile, so a frame written then is read
    folder = tmp_path / "in"
    folder.mkdir()
    img = np.full((8, 8, 3), 100, np.uint8)
    write_image(folder / "a.png", img)
    frames = open_source(str(folder), poll_s=0.02, idle_timeout=0.3)
    first = next(frames)
    time.sleep(0.8)
    write_image(folder / "b.png", img)
    assert [first.name] + [f.name for f in frames] == ["a", "b"]


def test_bad_sources_fail_before_any_frame(tmp_path: Path, captures) -> None:  # type: ignore[no-untyped-def]
    rig, _, images = captures
    with pytest.raises(ImageError, match="camera 97"):
        open_source("97")
    bad = tmp_path / "bad.avi"
    bad.write_bytes(b"\x00" * 1000)
    with pytest.raises(ImageError, match="video"):
        open_source(str(bad))
    with pytest.raises(ConfigError, match="no such file"):
        source_kind(str(tmp_path / "missing.mp4"))
    with pytest.raises(ConfigError, match="got the file"):
        source_kind(str(tmp_path / "x.txt")) if (tmp_path / "x.txt").write_text("x") else None
    small = _video(tmp_path / "small.avi", [img[:200, :256].copy() for img in images[:1]])
    with pytest.raises(ImageError, match="camera size"):
        run_stream(rig, str(small), tmp_path / "out", config=CONFIG)
    with pytest.raises(ConfigError, match="queue_size"):
        run_stream(rig, str(small), tmp_path / "out", config=CONFIG, queue_size=0)
    with pytest.raises(ConfigError, match="neither"):
        run_stream(rig, str(small), tmp_path / "out", config=CONFIG, outputs=None)


def test_cli_bad_camera_is_one_line_and_exit_2(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    demo_rig().save(rig)
    p = subprocess.run([sys.executable, "-m", "prismstereo", "stream", str(rig), "97", "-o", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "camera 97" in lines[0], p.stderr


def test_ctrl_c_keeps_the_finished_frames(tmp_path: Path, captures) -> None:  # type: ignore[no-untyped-def]
    import signal
    import time

    rig, _, images = captures
    rig_path = tmp_path / "rig.toml"
    rig.save(rig_path)
    folder = tmp_path / "in"
    folder.mkdir()
    for i in range(6):
        write_image(folder / f"f{i}.png", images[i % 3])
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "prismstereo", "stream", str(rig_path), str(folder), "-o", str(out),
                          "--depth-range", "1000,1700", "--preset", "fast", "--idle-timeout", "600"],
                         stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not (out / "frames" / "f0" / "frame.json").is_file():
            assert p.poll() is None and time.monotonic() < deadline, p.communicate()
            time.sleep(0.1)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err
    done = sorted(x.name for x in (out / "frames").iterdir())
    assert done and all(not n.startswith(".") for n in done)
    for n in done:
        assert {f.name for f in (out / "frames" / n).iterdir()} == {"disparity.pfm", "depth.png", "frame.json"}
    assert len(done) < 6


def test_stream_narrows_the_rig_range_and_searches_again_when_the_scene_leaves_it(  # type: ignore[no-untyped-def]
        tmp_path: Path, captures) -> None:
    rig, scenes, images = captures
    # far plane first, then the near one: the first frame's band does not hold the second
    src = _video(tmp_path / "caps.avi", [images[2], images[0]])
    got: list = []
    cfg = DepthConfig(method="sgm")
    summary = run_stream(rig, str(src), tmp_path / "out", config=cfg, on_frame=lambda n, r: got.append(r))
    assert summary.frames == 2 and not summary.failed
    info = json.loads((tmp_path / "out" / "stream.json").read_text())
    assert info["depth_range_source"] == "rig+images" and info["range_searches"] == 2
    rig_lo, rig_hi = prepare_depth(rig, config=cfg).disparity_range
    first, second = (r.disparity_range for r in got)
    assert rig_hi - rig_lo > 2 * (first[1] - first[0]) and second != first
    _accurate(got, [scenes[2], scenes[0]])


def test_temporal_prior_bands_the_next_frame_and_a_scene_cut_is_matched_again(  # type: ignore[no-untyped-def]
        tmp_path: Path, captures) -> None:
    rig, scenes, images = captures
    # the near plane twice, a cut to the far plane (its disparities outside the near one's bands), the far twice
    order = [0, 0, 2, 2]
    src = _video(tmp_path / "caps.avi", [images[i] for i in order])
    fast = apply_preset(CONFIG, "fast", given=["depth_range"])
    got: list = []
    summary = run_stream(rig, str(src), tmp_path / "out", config=fast, on_frame=lambda n, r: got.append(r))
    assert summary.frames == 4 and not summary.failed
    info = json.loads((tmp_path / "out" / "stream.json").read_text())
    frames = info["temporal_prior"]["frames"]
    assert frames == {"banded": 2, "full": 2, "matched_again": 1}, frames
    kinds = [json.loads((tmp_path / "out" / "frames" / f"caps_{i:06d}" / "frame.json").read_text())["match"]
             for i in range(4)]
    assert kinds == ["full", "banded", "matched again", "banded"]
    assert got[1].match_info["temporal_band"] and got[1].match_info["band_mean"] < 20
    _accurate(got, [scenes[i] for i in order])
    # the cut frame is the per-frame (whole-range) result, not a smear of the previous scene
    setup = prepare_depth(rig, config=fast)
    alone = run_depth_frame(setup, images[2])
    np.testing.assert_array_equal(got[2].disparity, alone.disparity)
    # without the prior every frame searches the whole range (the library, and the command's option)
    off = run_stream(rig, str(src), tmp_path / "off", config=fast, temporal=None)
    assert off.frames == 4
    assert json.loads((tmp_path / "off" / "stream.json").read_text())["temporal_prior"] is None
    rig_toml = tmp_path / "rig.toml"
    rig.save(rig_toml)
    assert main(["stream", str(rig_toml), str(src), "-o", str(tmp_path / "cli"), "--depth-range", "1000,1700",
                 "--max-frames", "2", "--no-temporal-prior"]) == 0
    assert json.loads((tmp_path / "cli" / "stream.json").read_text())["temporal_prior"] is None
