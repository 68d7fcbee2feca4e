"""Batch depth on Dask: same results as ``depth``, faults recorded, resume, video, interrupt, CLI exit codes.

Everything runs on a quarter-resolution thesis bi-prism rig (256×192) with the ``sad`` matcher, and on an
in-process Dask cluster with one worker, so that the whole file takes seconds.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from prismstereo.apps.demo import plane_scene, scaled_rig
from prismstereo.batch import (
    Frame,
    list_frames,
    parse_outputs,
    read_frame,
    run_batch,
)
from prismstereo.cli import main
from prismstereo.config import thesis_biprism
from prismstereo.depth import DepthConfig, run_depth
from prismstereo.depth.outputs import write_depth_outputs
from prismstereo.depth.pipeline import prepare_depth, run_depth_frame
from prismstereo.errors import ConfigError
from prismstereo.io import read_image, read_pfm, write_image

distributed = pytest.importorskip("distributed")

# a given range: without one, depth narrows it per capture from the images while a batch keeps the rig range
CONFIG = DepthConfig(method="sad", depth_range=(800.0, 5000.0))
DEPTHS = (1100.0, 1300.0, 1500.0)
NO_REPORT = "disparity.pfm,disparity.png,depth.pfm,points.ply,run.json"  # depth's files but the slow report


@pytest.fixture(scope="module")
def rig():
    return scaled_rig(thesis_biprism(), 4)


@pytest.fixture(scope="module")
def captures(rig):
    """Three rendered captures of a tilted textured plane at 1.1, 1.3 and 1.5 m."""
    from prismstereo.simulate import render_capture

    return [render_capture(rig, plane_scene(z, tilt_deg=20.0)).image for z in DEPTHS]


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory, rig, captures):
    """f0..f2.png, a corrupt file and a capture of the wrong size."""
    d = tmp_path_factory.mktemp("captures")
    for i, img in enumerate(captures):
        write_image(d / f"f{i}.png", img)
    (d / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n not really a png")
    write_image(d / "small.png", captures[0][:100, :120])
    return d


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as c, \
            distributed.Client(c) as cl:
        yield cl


def test_prepared_frames_equal_run_depth(rig, captures):
    setup = prepare_depth(rig, config=CONFIG)
    for img in captures[:2]:
        a = run_depth(rig, img, config=CONFIG)
        b = run_depth_frame(setup, img)
        assert a.disparity_range == b.disparity_range
        np.testing.assert_array_equal(a.disparity, b.disparity)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.points, b.points)


def test_batch_matches_depth_and_records_bad_frames(tmp_path, rig, frames_dir, client):
    out = tmp_path / "out"
    rows_seen = []
    s = run_batch(rig, [frames_dir, tmp_path / "missing.png"], out, config=CONFIG, client=client,
                  on_frame=rows_seen.append, outputs=NO_REPORT)
    by = {r["name"]: r for r in s.rows}
    assert [r["name"] for r in s.rows] == ["corrupt", "f0", "f1", "f2", "small", "missing"]
    assert s.exit_code == 3 and len(rows_seen) == 6
    assert {n for n, r in by.items() if r["status"] == "ok"} == {"f0", "f1", "f2"}
    assert "damaged" in by["corrupt"]["error"]
    assert "expected a 256×192 capture" in by["small"]["error"]
    assert "no such file" in by["missing"]["error"]
    assert all("\n" not in r["error"] for r in s.rows)
    # only finished frames have folders, with depth's files; no staging leftovers
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["f0", "f1", "f2"]
    # bit-identical to a plain depth run of the same capture
    ref = tmp_path / "ref"
    res = run_depth(rig, read_image(frames_dir / "f1.png"), config=CONFIG)
    write_depth_outputs(res, ref, report=False)
    for name in ("disparity.pfm", "depth.pfm", "points.ply", "disparity.png"):
        assert (out / "frames" / "f1" / name).read_bytes() == (ref / name).read_bytes(), name
    assert by["f1"]["points"] == res.counts()["points"] > 1000
    assert 0.5 < by["f1"]["coverage"] <= 1.0
    # the depth is right: the plane's centre is at 1.3 m
    z = read_pfm(out / "frames" / "f1" / "depth.pfm")
    assert abs(float(np.nanmedian(z[np.isfinite(z)])) - 1300.0) < 40.0
    # summary files and run.json
    csv_lines = (out / "summary.csv").read_text().splitlines()
    assert len(csv_lines) == 7 and csv_lines[0].startswith("name,source,index,status")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["totals"]["failed"] == 3 and len(summary["frames"]) == 6
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["method"] == "sad" and run["frames"] == 6 and run["scheduler"]["kind"] == "client"


def test_resume_skips_finished_frames_and_redoes_failed(tmp_path, rig, frames_dir, client):
    out = tmp_path / "out"
    inputs = [frames_dir / "f0.png", frames_dir / "f1.png", frames_dir / "corrupt.png"]
    first = run_batch(rig, inputs, out, config=CONFIG, client=client, outputs="depth.pfm,points.ply")
    assert first.exit_code == 3
    stamp = {p.name: p.stat().st_mtime_ns for p in (out / "frames" / "f0").iterdir()}
    redone = []
    second = run_batch(rig, inputs, out, config=CONFIG, client=client, outputs="depth.pfm,points.ply",
                       on_frame=redone.append)
    assert [r["name"] for r in redone] == ["corrupt"]  # finished frames were not resubmitted
    assert [r["resumed"] for r in second.rows] == [True, True, False]
    assert second.rows[0]["points"] == first.rows[0]["points"]
    assert {p.name: p.stat().st_mtime_ns for p in (out / "frames" / "f0").iterdir()} == stamp
    # a frame whose folder lacks a requested file is redone
    third = run_batch(rig, inputs[:2], out, config=CONFIG, client=client, outputs="depth.pfm,points.ply,depth.png")
    assert [r["resumed"] for r in third.rows] == [False, False] and third.exit_code == 0
    assert (out / "frames" / "f0" / "depth.png").is_file()
    # another configuration cannot be mixed into the same folder
    with pytest.raises(ConfigError, match="method"):
        run_batch(rig, inputs, out, config=DepthConfig(method="ssd"), client=client)


def test_video_frames_decoded_by_index(tmp_path, rig, captures, client):
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (rig.camera.width, rig.camera.height))
    assert writer.isOpened()
    for img in captures:
        writer.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    writer.release()
    frames = list_frames([video])
    assert [f.name for f in frames] == ["clip_000000", "clip_000001", "clip_000002"]
    # a frame read alone by index is the frame a sequential decode gives
    cap = cv2.VideoCapture(str(video))
    seq = [cap.read()[1] for _ in range(3)]
    cap.release()
    np.testing.assert_array_equal(read_frame(frames[2]), cv2.cvtColor(seq[2], cv2.COLOR_BGR2RGB))
    out = tmp_path / "out"
    s = run_batch(rig, [video], out, config=CONFIG, client=client, outputs="depth.png,points.ply")
    assert s.exit_code == 0 and [r["index"] for r in s.rows] == [0, 1, 2]
    for f, z_true in zip(frames, DEPTHS, strict=True):
        folder = out / "frames" / f.name
        assert sorted(p.name for p in folder.iterdir()) == ["depth.png", "frame.json", "points.ply"]
        mm = cv2.imread(str(folder / "depth.png"), cv2.IMREAD_UNCHANGED)
        assert mm.dtype == np.uint16
        # same as depth on the decoded frame, rounded to whole mm
        res = run_depth(rig, read_frame(f), config=CONFIG)
        np.testing.assert_array_equal(mm, np.where(np.isfinite(res.depth), np.rint(res.depth), 0).astype(np.uint16))
        assert abs(float(np.median(mm[mm > 0])) - z_true) < 0.05 * z_true


def test_a_long_video_keeps_only_a_window_of_frames_in_flight(tmp_path, rig, captures, client):
    """Frames are decoded on the workers by index and submitted a window at a time: however long the video,
    the scheduler knows only a few frame tasks (2 per worker thread + 2), each returning only its row."""
    video = tmp_path / "long.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (rig.camera.width, rig.camera.height))
    for i in range(10):
        writer.write(cv2.cvtColor(captures[i % len(captures)], cv2.COLOR_RGB2BGR))
    writer.release()

    def frame_tasks(dask_scheduler):
        return sum(str(k).startswith("prismstereo-frame") for k in dask_scheduler.tasks)

    in_flight = []
    s = run_batch(rig, [video], tmp_path / "out", config=CONFIG, client=client, outputs="depth.pfm",
                  on_frame=lambda row: in_flight.append(client.run_on_scheduler(frame_tasks)))
    assert s.exit_code == 0 and len(s.rows) == 10
    window = 2 * sum(client.nthreads().values()) + 2
    assert len(in_flight) == 10 and 1 <= max(in_flight) <= window < 10
    assert all(isinstance(v, int | float | str | bool) for r in s.rows for v in r.values() if v is not None
               and not isinstance(v, dict))  # rows only: no arrays come back to the client


def test_dashboard_notice_without_a_dashboard(tmp_path, rig, frames_dir, client):
    lines = []
    run_batch(rig, [frames_dir / "f0.png"], tmp_path / "out", config=CONFIG, client=client, outputs="depth.pfm",
              echo=lines.append)
    sched = json.loads((tmp_path / "out" / "run.json").read_text())["scheduler"]
    assert sched["dashboard"] is None and "dashboard_note" in sched
    assert [line for line in lines if line.startswith("dask dashboard: none (")]


def test_dashboard_link_printed_and_recorded(tmp_path, rig, frames_dir):
    pytest.importorskip("bokeh")
    import urllib.request

    lines = []
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as c, \
            distributed.Client(c) as cl:
        run_batch(rig, [frames_dir / "f0.png"], tmp_path / "out", config=CONFIG, client=cl, outputs="depth.pfm",
                  echo=lines.append)
        link = json.loads((tmp_path / "out" / "run.json").read_text())["scheduler"]["dashboard"]
        assert link.startswith("http://") and link.endswith("/status")
        assert f"dask dashboard: {link}" in lines
        with urllib.request.urlopen(link, timeout=30) as page:  # the page is served (no browser opened)
            assert page.status == 200 and b"<html" in page.read().lower()


def test_interrupt_leaves_only_complete_frames(tmp_path, rig, frames_dir):
    out = tmp_path / "out"

    def stop(row):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch(rig, [frames_dir / f"f{i}.png" for i in range(3)], out, config=CONFIG, workers=1,
                  processes=False, on_frame=stop, outputs="depth.pfm")
    names = sorted(p.name for p in (out / "frames").iterdir())
    assert names and all(not n.startswith(".") for n in names)
    for n in names:
        assert {p.name for p in (out / "frames" / n).iterdir()} == {"depth.pfm", "frame.json"}
    rows = json.loads((out / "summary.json").read_text())["frames"]
    assert len(rows) == 3 and rows[0]["status"] in ("ok", "interrupted")
    assert json.loads((out / "run.json").read_text())["totals"]["interrupted"] is True


def test_frames_of_a_killed_worker_are_rerun(tmp_path, rig, frames_dir):
    psutil = pytest.importorskip("psutil")
    out = tmp_path / "out"
    killed = []

    def kill_worker(row):
        if not killed:  # the first frame is back: kill its worker process while the others wait or run there
            pid = int(row["worker"].rsplit(":", 1)[1])
            psutil.Process(pid).kill()
            killed.append(pid)

    s = run_batch(rig, [frames_dir / f"f{i}.png" for i in range(3)], out, config=CONFIG, workers=1, processes=True,
                  on_frame=kill_worker, outputs="depth.pfm")
    assert s.exit_code == 0 and [r["status"] for r in s.rows] == ["ok"] * 3
    assert any(int(r["worker"].rsplit(":", 1)[1]) != killed[0] for r in s.rows)  # rerun on the new worker
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["f0", "f1", "f2"]


def test_list_frames_and_outputs(tmp_path, frames_dir):
    frames = list_frames([str(frames_dir / "f*.png"), frames_dir / "f0.png", tmp_path / "gone.png"])
    assert [f.name for f in frames] == ["f0", "f1", "f2", "f0_2", "gone"]
    assert frames[-1] == Frame("gone", str(tmp_path / "gone.png"), None)
    with pytest.raises(ConfigError, match="no match"):
        list_frames([str(frames_dir / "nothing*.png")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="none inside"):
        list_frames([tmp_path / "empty"])
    with pytest.raises(ConfigError, match="at least one"):
        list_frames([])
    assert parse_outputs("points.ply, depth.pfm") == ("depth.pfm", "points.ply")
    with pytest.raises(ConfigError, match="^outputs: "):
        parse_outputs("depth.exr")


def test_cli_exit_codes(tmp_path, rig, frames_dir, capsys):
    rig_path = tmp_path / "rig.toml"
    rig.save(rig_path)
    out = tmp_path / "out"
    args = ["batch", str(rig_path), str(frames_dir / "f0.png"), str(frames_dir / "corrupt.png"), "-o", str(out),
            "--method", "sad", "--outputs", "depth.pfm", "--in-process", "--workers", "1"]
    assert main(args) == 3
    text = capsys.readouterr()
    assert "1 failed" in text.out and "corrupt: failed: ImageError" in text.out
    assert main(args[:3] + args[4:]) == 0  # without the corrupt frame: f0 is finished, nothing to do
    assert "1 of 1 frames already finished" in capsys.readouterr().err
    # bad arguments: exit 2, one line, nothing written
    for bad in (["--outputs", "depth.exr"], ["--workers", "0"], ["--method", "nope"], ["--depth-range", "100,50"],
                ["--scheduler", "localhost"]):
        out2 = tmp_path / "bad"
        assert main(["batch", str(rig_path), str(frames_dir / "f0.png"), "-o", str(out2), *bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("prismstereo batch: error:"), err
        assert not out2.exists()
    assert main(["batch", str(tmp_path / "norig.toml"), str(frames_dir / "f0.png"), "-o", str(out)]) == 2


def test_cli_preset_and_min_confidence(tmp_path, rig, frames_dir, capsys):
    import json

    rig_path = tmp_path / "rig.toml"
    rig.save(rig_path)
    out = tmp_path / "out"
    args = ["batch", str(rig_path), str(frames_dir / "f0.png"), "-o", str(out), "--preset", "fast",
            "--min-confidence", "0.3", "--depth-range", "800,5000", "--outputs", "depth.pfm", "--in-process",
            "--workers", "1"]
    assert main(args) == 0
    run = json.loads((out / "run.json").read_text())
    config = run["config"]
    assert config["method"] == "sgm" and config["min_confidence"] == 0.3
    # the fast profile's refinement, the option given winning (recorded)
    from prismstereo.depth.presets import PROFILES

    assert all(config[k] == v for k, v in PROFILES["fast"].settings if k != "min_confidence")
    assert run["preset_profile"]["overridden"] == ["min_confidence"]
    capsys.readouterr()
    for bad in (["--preset", "fast", "--method", "sad"], ["--preset", "quick"], ["--min-confidence", "2"]):
        out2 = tmp_path / "bad"
        assert main(["batch", str(rig_path), str(frames_dir / "f0.png"), "-o", str(out2), *bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("prismstereo batch: error:"), err
        assert not out2.exists()
