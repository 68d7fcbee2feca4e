"""Issue 13: every command is trustworthy from the command line (subprocess, ``python -m prismstereo``).

Each case asserts the exit code, the stderr lines and the exact set of files left behind: outputs
replace only regular files, appear together or not at all, failures are one line and exit 2, and
unreliable results say so.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import stat
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from prismstereo.apps.cli import cli_warning
from prismstereo.apps.demo import demo_rig
from prismstereo.io import write_image

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "examples" / "rigs" / "biprism.toml"


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "src") + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("NUMBA_CACHE_DIR", str(REPO / ".numba_cache"))
    return env


def _run(*args: str, cwd: Path | None = None, fsize: int | None = None, timeout: float = 240
         ) -> subprocess.CompletedProcess[str]:
    def limit() -> None:  # a real write failure from the OS ("disk full" for this process)
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run([sys.executable, "-m", "prismstereo", *args], capture_output=True, text=True,
                          cwd=cwd, env=_env(), timeout=timeout, preexec_fn=limit if fsize else None)


def _files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def _one_error(proc: subprocess.CompletedProcess[str], command: str, *needles: str) -> str:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"prismstereo {command}: error: "), lines[0]
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def capture(capture_folder: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The shared capture folder's files plus noise.png, an image of the capture's size that no prism made."""
    folder = tmp_path_factory.mktemp("capture")
    for name in ("capture.png", "depth_gt.pfm", "rig.toml"):
        shutil.copyfile(capture_folder / name, folder / name)
    rig = demo_rig()
    rng = np.random.default_rng(0)
    write_image(folder / "noise.png", rng.integers(0, 256, (rig.camera.height, rig.camera.width, 3), np.uint8))
    return folder


# --------------------------------------------------------------------------- 1. only regular files replaced
def test_non_regular_targets_are_refused_untouched(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    folder = tmp_path / "folder"
    folder.mkdir()
    to_fifo = tmp_path / "link_to_pipe.json"
    to_fifo.symlink_to(fifo)
    before = _files(tmp_path)
    for target, needle in [(fifo, "a pipe"), (folder, "a folder"), (to_fifo, "a pipe")]:
        proc = _run("calibrate", str(RIG), "-o", str(target))
        _one_error(proc, "calibrate", str(target), needle)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and folder.is_dir() and to_fifo.is_symlink()
    assert _files(tmp_path) == before


def test_symlink_is_written_through(tmp_path: Path) -> None:
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "cams.json"
    link.symlink_to(real)
    proc = _run("calibrate", str(RIG), "-o", str(link))
    assert proc.returncode == 0, proc.stderr
    assert link.is_symlink() and json.loads(real.read_text())["method"] == "fit"
    assert _files(tmp_path) == {"real.json", "cams.json"}


# --------------------------------------------------------------------------- 3. exit codes and leftovers
def test_calibrate_output_is_a_folder_or_under_a_file(tmp_path: Path) -> None:
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    _one_error(_run("calibrate", str(RIG), "-o", str(tmp_path)), "calibrate", "a folder")
    _one_error(_run("calibrate", str(RIG), "-o", str(blocker / "cams.json")), "calibrate", "is a file")
    assert _files(tmp_path) == {"file.txt"} and blocker.read_text() == "x"


def test_disk_full_leaves_nothing(capture: Path, tmp_path: Path, tmp_path_factory: pytest.TempPathFactory) -> None:
    # the OS refuses writes past 20 kB for this process: every output stage fails for real
    out = tmp_path / "sim"
    proc = _run("simulate", str(REPO / "examples" / "biprism_demo.toml"), "-o", str(out), fsize=20_000)
    _one_error(proc, "simulate", "too large")
    out2 = tmp_path / "rect"
    proc = _run("rectify", str(capture / "rig.toml"), str(capture / "capture.png"), "-o", str(out2), fsize=20_000)
    _one_error(proc, "rectify", str(out2))
    out3 = tmp_path / "depth"
    # numba writes its cache when a kernel is first compiled: compile them first (no limit, another folder),
    # so that the limited run fails on the command's outputs and not on the cache
    warm = tmp_path_factory.mktemp("warm") / "depth"
    assert _run("depth", str(capture / "rig.toml"), str(capture / "capture.png"), "-o", str(warm), "--method", "sad",
                "--depth-range", "1200,2200").returncode == 0
    proc = _run("depth", str(capture / "rig.toml"), str(capture / "capture.png"), "-o", str(out3), "--method", "sad",
                "--depth-range", "1200,2200", fsize=20_000)
    _one_error(proc, "depth", str(out3))
    assert _files(tmp_path) == set()


def test_no_space_left_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    import errno

    from prismstereo.cli import main

    real = Path.write_bytes

    def full(self: Path, data: bytes) -> int:
        if self.name.startswith("."):  # the temporary file of a safe write
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)
    code = main(["calibrate", str(RIG), "-o", str(tmp_path / "cams.json")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "no space left" in err and "cams.json" in err
    assert _files(tmp_path) == set()


def test_match_writes_both_files_or_none(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    tex = rng.integers(0, 256, (40, 330), np.uint8)
    left, right = tex[:, 0:300], tex[:, 30:330]  # true disparity 30 px everywhere
    write_image(tmp_path / "l.png", np.repeat(left[:, :, None], 3, 2))
    write_image(tmp_path / "r.png", np.repeat(right[:, :, None], 3, 2))
    (tmp_path / "d.png").mkdir()  # the PNG beside the PFM cannot be written
    _one_error(_run("match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(tmp_path / "d.pfm"),
                    "--max-disp", "40", "--method", "sad"), "match", "a folder")
    assert _files(tmp_path) == {"l.png", "r.png", "d.png"}
    (tmp_path / "d.png").rmdir()
    proc = _run("match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(tmp_path / "d.pfm"),
                "--max-disp", "40", "--method", "sad", fsize=20_000)  # the PFM is 48 kB: "disk full"
    _one_error(proc, "match", "d.pfm")
    assert _files(tmp_path) == {"l.png", "r.png"}
    # 2. the search stops short of the scene: warnings, exit 0
    proc = _run("match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(tmp_path / "d.pfm"),
                "--max-disp", "16", "--method", "sad")
    assert proc.returncode == 0, proc.stderr
    warns = proc.stderr.splitlines()
    assert warns and all(w.startswith("prismstereo match: warning: ") for w in warns)
    assert any("largest searched disparity 16" in w and w.endswith("--min-disp/--max-disp)") for w in warns)
    assert _files(tmp_path) == {"l.png", "r.png", "d.pfm", "d.png"}
    # the right range: no warning
    proc = _run("match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(tmp_path / "d.pfm"),
                "--max-disp", "40", "--method", "sad")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


def _middlebury_like(root: Path, names: tuple[str, ...], broken: str | None = None) -> None:
    rng = np.random.default_rng(2)
    for name in names:
        d = root / name
        d.mkdir(parents=True)
        tex = rng.integers(0, 256, (40, 70), np.uint8)
        write_image(d / "left.png", tex[:, 4:64])
        write_image(d / "right.png", tex[:, 0:60])
        write_image(d / "disp_left.png", np.full((40, 60), 4 * 16, np.uint8))
        for m in ("nonocc", "all", "disc"):
            write_image(d / f"{m}.png", np.full((40, 60), 255, np.uint8))
        (d / "manifest.json").write_text(json.dumps({"ground_truth": {"scale_factor": 16},
                                                     "disparity_search_range": {"min": 0, "max": 15}}))
        if name == broken:
            (d / "left.png").write_bytes((d / "left.png").read_bytes()[:100])


def test_evaluate_all_or_nothing(tmp_path: Path) -> None:
    data = tmp_path / "data"
    _middlebury_like(data, ("tsukuba", "venus"), broken="venus")
    work = tmp_path / "work"
    work.mkdir()
    proc = _run("evaluate", "middlebury", "--data", str(data), "--method", "sad", "--scenes", "tsukuba,venus",
                "-o", str(work / "mb"))
    _one_error(proc, "evaluate", "venus")
    assert _files(work) == set()  # not tsukuba's files, not an empty mb/
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = _run("evaluate", "middlebury", "--data", str(empty), "--method", "sad", "-o", str(work / "mb"))
    _one_error(proc, "evaluate")
    assert _files(work) == set()
    blocker = work / "file"
    blocker.write_text("x")
    _one_error(_run("evaluate", "middlebury", "--data", str(data), "--method", "sad", "-o", str(blocker)),
               "evaluate", "an existing file")
    _one_error(_run("reproduce", "table5.1", "-o", str(blocker)), "reproduce", "an existing file")
    # an unknown baseline is refused before any scene is read or any file written
    _one_error(_run("evaluate", "middlebury", "--data", str(data), "--method", "sad", "--baseline", "nosuch",
                    "-o", str(work / "mb")), "evaluate", "nosuch")
    assert _files(work) == {"file"}


# --------------------------------------------------------------------------- 2. silent wrong results
def test_depth_default_range_comes_from_rig_and_images(capture: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = _run("depth", str(capture / "rig.toml"), str(capture / "capture.png"), "-o", str(out), "--gt",
                str(capture / "depth_gt.pfm"), "--method", "sad")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert "(from the rig+images" in proc.stdout
    run = json.loads((out / "run.json").read_text())
    assert run["warnings"] == [] and run["depth_range_source"] == "rig+images"
    zmin, zmax = run["depth_range_mm"]
    assert zmin < 1450 and zmax > 1800  # the tilted plane spans about 1.45–1.8 m
    assert run["accuracy"]["median_rel"] <= 0.0025


@pytest.mark.parametrize("image, extra", [("capture.png", ["--depth-range", "216,300"]), ("noise.png", [])])
def test_depth_unreliable_results_warn(capture: Path, tmp_path: Path, image: str, extra: list[str]) -> None:
    out = tmp_path / "out"
    proc = _run("depth", str(capture / "rig.toml"), str(capture / image), "-o", str(out), "--method", "sad", *extra)
    assert proc.returncode == 0, proc.stderr
    warns = proc.stderr.splitlines()
    assert warns and all(w.startswith("prismstereo depth: warning: ") for w in warns), proc.stderr
    run = json.loads((out / "run.json").read_text())
    # run.json keeps the library's words (DepthConfig.depth_range), stderr the command's (--depth-range)
    assert [f"prismstereo depth: warning: {cli_warning('depth', w)}" for w in run["warnings"]] == warns


# --------------------------------------------------------------------------- 4./5. early checks, one line
def _png(path: Path, w: int, h: int) -> None:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    rows = zlib.compress(b"".join(b"\x00" + bytes(w * 3) for _ in range(4)))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", rows) + chunk(b"IEND", b""))


def test_images_checked_from_their_header(capture: Path, tmp_path: Path) -> None:
    huge = tmp_path / "huge.png"
    _png(huge, 20000, 20000)  # a header only: decoding it would need 1.2 GB
    trunc = tmp_path / "trunc.png"
    trunc.write_bytes((capture / "capture.png").read_bytes()[:5000])
    out = tmp_path / "out"
    _one_error(_run("depth", str(capture / "rig.toml"), str(huge), "-o", str(out)), "depth", "512×384",
               "20000×20000")
    _one_error(_run("depth", str(capture / "rig.toml"), str(trunc), "-o", str(out)), "depth", "truncated")
    _one_error(_run("match", str(huge), str(huge), "-o", str(out / "d.pfm"), "--max-disp", "100"), "match",
               "fit in memory")
    assert _files(tmp_path) == {"huge.png", "trunc.png"}


def test_scene_too_large_for_memory(tmp_path: Path) -> None:
    rig = RIG.read_text().replace("width = 1024", "width = 200000").replace("height = 768", "height = 150000")
    (tmp_path / "big.toml").write_text(rig + '\n[[objects]]\ntype = "plane"\ncenter = [0.0, 0.0, 1500.0]\n'
                                       'normal = [0.0, 0.0, -1.0]\ntexture = { type = "noise", scale = 20.0 }\n')
    _one_error(_run("simulate", str(tmp_path / "big.toml"), "-o", str(tmp_path / "out")), "simulate",
               "fit in memory")
    assert _files(tmp_path) == {"big.toml"}


def test_geometry_and_argument_errors_are_one_line(capture: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(RIG.read_text().replace("corner_angle = 6.4", "corner_angle = 89.0"))
    _one_error(_run("calibrate", str(bad), "-o", str(tmp_path / "c.json")), "calibrate", "corner_angle",
               "83.3")
    rig, img, out = str(capture / "rig.toml"), str(capture / "capture.png"), str(tmp_path / "out")
    _one_error(_run("depth", rig, img, "-o", out, "--depth-range", "-100,5000"), "depth", "--depth-range", "-100")
    _one_error(_run("depth", rig, img, "-o", out, "--roi", "-5,0,10,10"), "depth", "--roi")
    assert _files(tmp_path) == {"bad.toml"}


def test_verbose_after_the_subcommand(tmp_path: Path) -> None:
    proc = _run("calibrate", str(RIG), "-o", str(tmp_path / "c.json"), "-v", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert _files(tmp_path) == {"c.json"}


def test_help_cites_docs_that_exist() -> None:
    proc = _run("--help")
    cited = {w.strip(".,():;") for w in proc.stdout.split() if w.startswith("docs/")}
    assert cited and all((REPO / c).is_file() for c in cited)
    for cmd in ("evaluate", "reproduce"):
        text = _run(cmd, "--help").stdout
        assert "vision.middlebury.edu" in text and "disp_left.png" in text


# --------------------------------------------------------------------------- 6. Ctrl-C
def test_ctrl_c_leaves_nothing(tmp_path: Path) -> None:
    import time

    out = tmp_path / "sim"
    proc = subprocess.Popen([sys.executable, "-m", "prismstereo", "simulate", str(REPO / "examples" /
                             "biprism_robot.toml"), "-o", str(out), "--supersample", "8"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                            # a suite started in the background (``make test &``) ignores SIGINT, and the child
                            # would inherit that: Python installs its Ctrl-C handler only where it is not ignored
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(4.0)  # past the imports, inside the render
    t = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    waited = time.perf_counter() - t
    assert proc.returncode == 130, err
    assert err.splitlines() == ["prismstereo simulate: interrupted"]
    assert waited < 5.0  # typically well under a second; generous for a loaded machine
    assert _files(tmp_path) == set()


def test_blank_render_warns(tmp_path: Path) -> None:
    rig = RIG.read_text().replace("width = 1024", "width = 128").replace("height = 768", "height = 96")
    rig = rig.replace("pixel_size = 0.00465", "pixel_size = 0.0372")
    (tmp_path / "behind.toml").write_text(rig + '\n[[objects]]\ntype = "plane"\ncenter = [0.0, 0.0, -1500.0]\n'
                                          'normal = [0.0, 0.0, 1.0]\ntexture = { type = "noise", scale = 20.0 }\n')
    proc = _run("simulate", str(tmp_path / "behind.toml"), "-o", str(tmp_path / "out"))
    assert proc.returncode == 0
    assert proc.stderr.splitlines() == [line for line in proc.stderr.splitlines()
                                        if line.startswith("prismstereo simulate: warning: the render is blank")]
    assert proc.stderr.count("\n") == 1


def test_ordinary_photo_warns(capture: Path, tmp_path: Path, middlebury_dir: Path) -> None:
    import cv2

    photo = cv2.resize(cv2.imread(str(middlebury_dir / "cones" / "left.png")), (512, 384))  # not a prism capture
    cv2.imwrite(str(tmp_path / "photo.png"), photo)
    out = tmp_path / "out"
    proc = _run("depth", str(capture / "rig.toml"), str(tmp_path / "photo.png"), "-o", str(out), "--method", "sad")
    assert proc.returncode == 0, proc.stderr
    warns = proc.stderr.splitlines()
    assert warns and all(w.startswith("prismstereo depth: warning: ") for w in warns), proc.stderr
    assert json.loads((out / "run.json").read_text())["warnings"]


def _run_on_terminal(*args: str) -> tuple[int, str]:
    """Run with stderr on a pseudo-terminal (120 columns); returns the exit code and what it showed."""
    import fcntl
    import pty
    import select
    import termios
    import time

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    proc = subprocess.Popen([sys.executable, "-m", "prismstereo", *args], stdin=slave, stdout=subprocess.DEVNULL,
                            stderr=slave, env=_env())
    os.close(slave)
    out, t0 = b"", time.time()
    while time.time() - t0 < 120:
        if select.select([master], [], [], 0.2)[0]:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                break
            if not chunk:
                break
            out += chunk
        elif proc.poll() is not None:
            break
    os.close(master)
    return proc.wait(), out.decode(errors="replace")


def test_progress_bar_on_a_terminal_only(tmp_path: Path) -> None:
    data = tmp_path / "data"
    _middlebury_like(data, ("tsukuba", "venus"))
    args = ("evaluate", "middlebury", "--data", str(data), "--method", "sad", "--scenes", "tsukuba,venus")
    code, shown = _run_on_terminal(*args, "-o", str(tmp_path / "a"))
    assert code == 0 and "evaluate sad" in shown and "scene" in shown
    code, shown = _run_on_terminal(*args, "-o", str(tmp_path / "b"), "--quiet")
    assert code == 0 and shown == ""
    proc = _run(*args, "-o", str(tmp_path / "c"))  # not a terminal: nothing on stderr
    assert proc.returncode == 0 and proc.stderr == ""
