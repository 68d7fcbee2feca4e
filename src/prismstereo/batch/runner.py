"""Depth for many frames on Dask: one set-up per rig, one task per frame.

:func:`run_batch` prepares the per-rig part of the depth pipeline once (virtual cameras, rectification maps,
common view, disparity range: :func:`prismstereo.depth.pipeline.prepare_depth`), ships it to the cluster
once (one task whose result every worker fetches once) and submits one task per frame. A task reads its frame
(a video frame is decoded on the worker, by index), runs :func:`~prismstereo.depth.pipeline.run_depth_frame`
and writes the frame's folder all-or-nothing; it returns only its summary row, so a worker holds about
one frame per thread and the client only rows. At most a few tasks per worker thread are submitted at a
time, so even a very long video keeps the scheduler's queue short.

Faults: an error of a frame (missing, corrupt or wrong-size capture, a failure of the pipeline) is caught
in its task and becomes a ``failed`` row with a one-line error; the batch goes on. A worker that dies has
its tasks rerun elsewhere (``retries`` of ``Client.submit``). Ctrl-C cancels the tasks, removes the
unfinished frames' staging folders and writes the summary of what finished. Resume: a second run on the
same output folder skips every finished frame folder and redoes the others.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from prismstereo import __version__
from prismstereo.batch.frames import Frame, list_frames, read_frame
from prismstereo.batch.outputs import (
    finished_row,
    parse_outputs,
    remove_partial,
    write_frame_folder,
    write_summary,
)
from prismstereo.config import Rig, load_rig
from prismstereo.depth.pipeline import DepthConfig, DepthSetup, prepare_depth, run_depth_frame
from prismstereo.depth.presets import preset_record
from prismstereo.errors import ConfigError
from prismstereo.io import to_jsonable, write_json
from prismstereo.io.atomic import check_output_dir
from prismstereo.io.jsonio import library_versions
from prismstereo.matching import get_matcher
from prismstereo.numba_cache import tolerate_cache_write_errors

log = logging.getLogger(__name__)

__all__ = ["EXIT_OK", "EXIT_SOME_FAILED", "BatchSummary", "local_cluster", "machine_cores", "process_frame",
           "run_batch"]

EXIT_OK = 0
#: exit code of ``prismstereo batch`` when some frames failed (the others are written)
EXIT_SOME_FAILED = 3


@dataclass
class BatchSummary:
    """What a batch did: one row per frame, in input order (the content of ``summary.json``).

    Attributes
    ----------
    out_dir : Path
    rows : list of dict
        Keys of :data:`~prismstereo.batch.outputs.SUMMARY_FIELDS`; ``status`` is ``ok``, ``failed`` or
        ``interrupted``; ``resumed`` is true for frames finished by an earlier run (not redone).
    run : dict
        The content of ``OUT/run.json`` (resolved configuration, scheduler, totals).
    """

    out_dir: Path
    rows: list[dict[str, Any]]
    run: dict[str, Any] = field(default_factory=dict)

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.rows)

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["status"] != "ok"]

    @property
    def exit_code(self) -> int:
        """0 when every frame is done, :data:`EXIT_SOME_FAILED` (3) otherwise."""
        return EXIT_OK if not self.failed else EXIT_SOME_FAILED

    def text(self) -> str:
        """A few lines for the terminal: counts, throughput, and each failed frame's error."""
        t = self.run.get("totals", {})
        resumed = sum(bool(r.get("resumed")) for r in self.rows)
        lines = [f"batch: {len(self.rows)} frames, {self.count('ok')} ok ({resumed} finished before), "
                 f"{len(self.failed)} failed; {t.get('computed', 0)} computed in {t.get('wall_s', 0.0):.1f} s "
                 f"({t.get('frames_per_s', 0.0):.2f} frames/s)"]
        lines += [f"  {r['name']}: {r['status']}: {r['error']}" for r in self.failed]
        lines.append(f"wrote {self.out_dir / 'frames'}/<name>/, summary.csv, summary.json, run.json")
        return "\n".join(lines)


def machine_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


# --------------------------------------------------------------------------- the task
class _FrameLog(logging.Handler):
    """Collects the prismstereo warnings logged by one thread (the task's) while it runs a frame."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.thread = threading.get_ident()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.lines.append(record.getMessage().splitlines()[0] if record.getMessage() else record.levelname)


def _limit_threads(host_threads: dict[str, int], client_pid: int, numba_threads: int | None) -> int:
    """Give this task's numba (and OpenCV) a share of the cores: cores // worker threads on this host."""
    import numba

    tolerate_cache_write_errors()
    on_host = 1
    try:
        from distributed import get_worker

        worker = get_worker()
        on_host = host_threads.get(worker.address, worker.state.nthreads)
    except (ImportError, ValueError):  # not on a Dask worker (called directly)
        pass
    want = numba_threads if numba_threads is not None else machine_cores() // max(on_host, 1)
    n = max(1, min(want, int(numba.config.NUMBA_NUM_THREADS)))  # type: ignore[attr-defined]
    numba.set_num_threads(n)  # thread-local in numba: set in the thread that runs the frame
    if os.getpid() != client_pid:  # OpenCV's setting is process-wide: leave the user's own process alone
        import cv2

        cv2.setNumThreads(n)
    return n


def _error_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _rss_mb() -> float:
    try:
        import psutil

        return float(psutil.Process().memory_info().rss) / 2**20
    except ImportError:  # pragma: no cover - psutil comes with distributed
        return float("nan")


def _base_row(frame: Frame) -> dict[str, Any]:
    return {"name": frame.name, "source": frame.source, "index": frame.index, "status": "failed", "resumed": False,
            "points": 0, "coverage": float("nan"), "t_read_s": float("nan"), "t_depth_s": float("nan"),
            "t_write_s": float("nan"), "t_total_s": float("nan"), "rss_mb": float("nan"), "worker": "",
            "warnings": "", "error": ""}


def process_frame(setup: DepthSetup, frame: Frame, frames_dir: str, outputs: Sequence[str], *,
                  host_threads: dict[str, int] | None = None, client_pid: int = -1,
                  numba_threads: int | None = None, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Depth of one frame with a prepared set-up, written to ``frames_dir/<name>/``; returns its summary row.

    Errors of the frame (bad capture, pipeline failure) are returned in the row (``status`` ``failed``,
    ``error`` one line), never raised, so that Dask's retries are spent only on lost workers.
    """
    t0, cpu0 = time.perf_counter(), time.process_time()
    row = _base_row(frame)
    row["worker"] = f"{os.uname().nodename}:{os.getpid()}"
    row["numba_threads"] = _limit_threads(host_threads or {}, client_pid, numba_threads)
    handler = _FrameLog()
    pkg_log = logging.getLogger("prismstereo")
    pkg_log.addHandler(handler)
    try:
        img = read_frame(frame)
        t1 = time.perf_counter()
        res = run_depth_frame(setup, img)
        t2 = time.perf_counter()
        c = res.counts()
        cov = res.coverage.share if res.coverage is not None else c["points"] / max(c["region_pixels"], 1)
        row.update(status="ok", points=c["points"], coverage=cov,
                   t_read_s=t1 - t0, t_depth_s=t2 - t1, stages_s={k: round(v, 4) for k, v in res.timings.items()})
        info = {"inputs": {"image": frame.source, "index": frame.index}, **(extra or {})}
        row["rss_mb"] = _rss_mb()
        row["warnings"] = " | ".join(handler.lines)
        row["t_total_s"] = time.perf_counter() - t0  # frame.json: read + depth (+ the write, added below)
        write_frame_folder(res, Path(frames_dir), frame.name, outputs, row=row, extra=info)
    except Exception as exc:  # noqa: BLE001 - any failure of one frame is that frame's, the batch goes on
        row.update(status="failed", error=_error_line(exc))
        log.debug("frame %s failed", frame.label, exc_info=True)
    finally:
        pkg_log.removeHandler(handler)
    row["warnings"] = " | ".join(handler.lines)
    row["rss_mb"] = _rss_mb()
    row["t_total_s"] = time.perf_counter() - t0
    # CPU seconds of the worker process while the frame ran (all its threads: numba's and OpenCV's too)
    row["cpu_s"] = time.process_time() - cpu0
    return row


# --------------------------------------------------------------------------- the client
def local_cluster(workers: int | None = None, *, threads_per_worker: int = 1, processes: bool = True,
                  retries: int = 2, dashboard_address: str | None = ":0") -> Any:
    """A ``distributed.LocalCluster`` set up for depth frames (what ``run_batch`` makes when given no client).

    Parameters
    ----------
    workers : int, optional
        Worker processes (threads with ``processes=False``); default: cores // ``threads_per_worker``.
    threads_per_worker : int
    processes : bool
        Workers in their own processes (default; the numba kernels hold the GIL) or as threads here.
    retries : int
        Times a frame is rerun when its worker dies (the scheduler's ``allowed-failures``).
    dashboard_address : str or None
        Where the dashboard listens (``:0`` = a free port; it needs ``bokeh``); None for no dashboard.

    Notes
    -----
    Dask starts worker processes with ``MALLOC_TRIM_THRESHOLD_=65536``, which turns off glibc's adaptive
    mmap threshold: every large temporary array of the pipeline is then mapped and page-faulted afresh,
    about 40 % more CPU per frame (docs/EXPERIMENTS.md). These workers keep glibc's default.
    """
    import dask
    from distributed import LocalCluster

    n = workers if workers is not None else max(1, machine_cores() // threads_per_worker)
    settings = {"distributed.scheduler.allowed-failures": retries,
                "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
    # an earlier cluster's nanny may have left Dask's value in this process's environment: not inherited
    inherited = os.environ.pop("MALLOC_TRIM_THRESHOLD_", None) if processes else None
    try:
        with dask.config.set(settings):
            return LocalCluster(n_workers=n, threads_per_worker=threads_per_worker, processes=processes,
                                dashboard_address=dashboard_address, silence_logs=logging.ERROR)
    finally:
        if inherited is not None:
            os.environ["MALLOC_TRIM_THRESHOLD_"] = inherited


@contextlib.contextmanager
def _dask_client(client: Any, scheduler: str | None, workers: int | None, threads_per_worker: int,
                 processes: bool, retries: int) -> Iterator[tuple[Any, dict[str, Any]]]:
    """The client to use and a description of it; clients and clusters made here are closed on exit."""
    if client is not None:
        yield client, {"kind": "client", "address": str(client.scheduler.address)}
        return
    from distributed import Client

    if scheduler:
        try:
            own = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"scheduler: expected a reachable Dask scheduler like tcp://HOST:8786, got "
                              f"{scheduler!r} ({_error_line(exc)})") from None
        try:
            yield own, {"kind": "scheduler", "address": scheduler}
        finally:
            own.close()
        return
    n = workers if workers is not None else max(1, machine_cores() // threads_per_worker)
    cluster = local_cluster(n, threads_per_worker=threads_per_worker, processes=processes, retries=retries)
    own = Client(cluster)
    try:
        yield own, {"kind": "local", "workers": n, "threads_per_worker": threads_per_worker, "processes": processes}
    finally:
        own.close()
        cluster.close()


def _serves_dashboard(dask_scheduler: Any) -> bool | None:
    """On the scheduler: whether its web server serves the bokeh dashboard (None when it cannot tell).

    The scheduler always runs a web server and lists it as its ``dashboard`` service; without bokeh, or
    when started without a dashboard, ``/status`` is only a notice. The dashboard is a bokeh application
    added to that server.
    """
    apps = getattr(getattr(dask_scheduler, "http_application", None), "applications", None)
    return None if apps is None else any("Bokeh" in type(a).__name__ for a in apps)


def _dashboard(client: Any) -> tuple[str | None, str]:
    """(link of the scheduler's Dask dashboard or None, a one-line notice for the user)."""
    try:
        services = client.scheduler_info().get("services", {})
        serves = client.run_on_scheduler(_serves_dashboard) if "dashboard" in services else False
    except Exception:  # noqa: BLE001 - the link is a convenience (run_on_scheduler may be refused)
        services, serves = {}, None
    if "dashboard" in services and serves is not False:
        link = str(client.dashboard_link)
        return link, f"dask dashboard: {link}"
    try:
        import bokeh  # noqa: F401 - only whether the dashboard could run here
    except ImportError:
        return None, "dask dashboard: none (it needs bokeh>=3.1: pip install 'bokeh>=3.1')"
    return None, "dask dashboard: none (the scheduler runs without one)"


def _host_threads(client: Any) -> dict[str, int]:
    """Worker address -> threads of all workers on the same host (they share its cores)."""
    workers = client.scheduler_info(n_workers=-1)["workers"] if _accepts_n_workers(client) else \
        client.scheduler_info()["workers"]
    per_host: dict[str, int] = {}
    for info in workers.values():
        per_host[info.get("host", "")] = per_host.get(info.get("host", ""), 0) + int(info.get("nthreads", 1))
    return {addr: per_host[info.get("host", "")] for addr, info in workers.items()}


def _accepts_n_workers(client: Any) -> bool:
    import inspect

    return "n_workers" in inspect.signature(client.scheduler_info).parameters


def _progress_bar(total: int, initial: int, progress: bool | None) -> Any:
    if progress is False or (progress is None and not sys.stderr.isatty()):
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="batch", unit="frame")


def _check_resume(out_dir: Path, run: dict[str, Any]) -> None:
    """Refuse to mix frames of another rig or configuration into an existing output folder."""
    import json

    prev_path = out_dir / "run.json"
    if not prev_path.is_file():
        return
    try:
        prev = json.loads(prev_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    now = json.loads(json.dumps(to_jsonable({"rig": run["rig"], "config": run["config"]})))
    if prev.get("command") != "batch":
        return
    for key in ("rig", "config"):
        old, new = prev.get(key) or {}, now[key]
        if old != new:
            diff = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
            raise ConfigError(f"-o: expected the {key} of the earlier batch in {str(out_dir)!r} to resume it, got "
                              f"a different {key} ({', '.join(diff)}; use a new output folder)")


# --------------------------------------------------------------------------- run_batch
def run_batch(rig: Rig | str | os.PathLike[str], inputs: Sequence[str | os.PathLike[str]],
              out: str | os.PathLike[str], *, config: DepthConfig | None = None,
              outputs: str | Sequence[str] | None = None, client: Any = None, scheduler: str | None = None,
              workers: int | None = None, threads_per_worker: int = 1, processes: bool = True, retries: int = 2,
              numba_threads: int | None = None, progress: bool | None = None,
              echo: Callable[[str], None] | None = None,
              on_frame: Callable[[dict[str, Any]], None] | None = None,
              preset: str | None = None) -> BatchSummary:
    """Depth of every frame of ``inputs`` into ``out/frames/<name>/``, on Dask.

    Parameters
    ----------
    rig : Rig or path of a rig TOML
    inputs : image files, folders, globs or video files (see :func:`~prismstereo.batch.frames.list_frames`)
    out : output folder: ``frames/<name>/``, ``summary.csv``, ``summary.json``, ``run.json``
    config : DepthConfig, optional
        As for ``prismstereo depth`` (method, triangulation, views, depth range …).
    outputs : names or comma-separated text, optional
        Files per frame among :data:`~prismstereo.batch.outputs.OUTPUT_CHOICES`; default: ``depth``'s files.
    client : distributed.Client, optional
        Run on this client (e.g. a notebook's); it is left open.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://HOST:PORT``); ignored when ``client`` is given.
    workers, threads_per_worker, processes :
        The local cluster made when neither ``client`` nor ``scheduler`` is given: by default one
        single-threaded worker process per core.
    retries : int
        Times a frame is rerun when its worker dies (the local cluster's ``allowed-failures``; with
        ``client`` or ``scheduler``, that scheduler's own setting applies) or its task fails outside the
        frame's own error handling (``Client.submit(retries=...)``).
    numba_threads : int, optional
        Numba (and OpenCV) threads per task; default: the host's cores // its worker threads.
    progress : bool, optional
        Progress bar over frames; default: when stderr is a terminal.
    echo : callable, optional
        Receives one-line notices (cluster, dashboard link).
    on_frame : callable, optional
        Called with each frame's row as it completes (in completion order).
    preset : str, optional
        The preset ``config`` was resolved from (:func:`~prismstereo.depth.presets.apply_preset`), recorded in
        ``run.json`` with its settings as resolved (``preset_profile``).

    Returns
    -------
    BatchSummary
        ``exit_code`` is 0 when every frame is done, 3 when some failed.

    Raises
    ------
    ConfigError, GeometryError, OutputError
        Bad arguments, found before any frame is processed.
    KeyboardInterrupt
        After cancelling the tasks and writing the summary of the finished frames.
    """

    t_start = time.perf_counter()
    say = echo or (lambda line: log.info("%s", line))
    rig_obj = rig if isinstance(rig, Rig) else load_rig(rig)
    chosen = parse_outputs(outputs)
    if workers is not None and workers < 1:
        raise ConfigError(f"workers: expected a positive number, got {workers}")
    if threads_per_worker < 1:
        raise ConfigError(f"threads_per_worker: expected a positive number, got {threads_per_worker}")
    if retries < 0:
        raise ConfigError(f"retries: expected 0 or more, got {retries}")
    if numba_threads is not None and numba_threads < 1:
        raise ConfigError(f"numba_threads: expected a positive number, got {numba_threads}")
    if scheduler is not None and client is None and "://" not in scheduler:
        raise ConfigError(f"scheduler: expected an address like tcp://HOST:8786, got {scheduler!r}")
    out_dir = Path(out)
    check_output_dir(out_dir)
    frames = list_frames(inputs)
    t = time.perf_counter()
    setup = prepare_depth(rig_obj, config=config)
    t_setup = time.perf_counter() - t
    get_matcher(setup.config.method, **setup.config.matcher_params)  # tuning parameters checked before any frame
    run: dict[str, Any] = {
        "command": "batch", "prismstereo": __version__, "versions": library_versions(),
        "rig": rig_obj.to_dict(), "config": setup.config.to_dict(),
        "faces": {"left": int(setup.pair.left_face), "right": int(setup.pair.right_face)},
        "disparity_range": list(setup.disparity_range), "outputs": list(chosen),
        "inputs": [os.fspath(i) for i in inputs], "frames": len(frames),
        "setup_s": {**{k: round(v, 4) for k, v in setup.timings.items()}, "total": round(t_setup, 4)},
    }
    if preset is not None:
        run["preset_profile"] = preset_record(preset, setup.config)
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    _check_resume(out_dir, run)
    remove_partial(frames_dir)
    write_json(out_dir / "run.json", run)

    rows: dict[str, dict[str, Any]] = {}
    todo: list[Frame] = []
    for f in frames:
        prev = finished_row(frames_dir, f.name, chosen)
        if prev is not None:
            rows[f.name] = {**prev, "resumed": True}
        else:
            todo.append(f)
    if len(rows):
        say(f"batch: {len(rows)} of {len(frames)} frames already finished in {frames_dir}, skipped")
    interrupted = False
    t_compute = time.perf_counter()
    if todo:
        try:
            with _dask_client(client, scheduler, workers, threads_per_worker, processes, retries) as (c, sched):
                link, notice = _dashboard(c)
                say(notice)
                run["scheduler"] = {**sched, "numba_threads": numba_threads or "auto", "dashboard": link}
                if link is None:
                    run["scheduler"]["dashboard_note"] = notice.split(": ", 1)[1]
                interrupted = _submit_all(c, setup, todo, frames_dir, chosen, rows, retries=retries,
                                          numba_threads=numba_threads,
                                          progress=_progress_bar(len(frames), len(rows), progress), say=say,
                                          on_frame=on_frame, run=run)
        finally:
            if client is None:  # our cluster is closed: nothing writes any more, staging leftovers can go
                remove_partial(frames_dir)
    wall = time.perf_counter() - t_compute
    ordered = []
    for f in frames:
        row = rows.get(f.name) or finished_row(frames_dir, f.name, chosen)  # done as Ctrl-C came: on disk
        if row is None:
            row = {**_base_row(f), "status": "interrupted", "error": "KeyboardInterrupt: not finished"}
        ordered.append(row)
    computed = sum(1 for r in ordered if r["status"] in ("ok", "failed") and not r.get("resumed"))
    run["totals"] = {"frames": len(frames), "ok": sum(r["status"] == "ok" for r in ordered),
                     "failed": sum(r["status"] != "ok" for r in ordered),
                     "resumed": sum(bool(r.get("resumed")) for r in ordered), "computed": computed,
                     "wall_s": round(wall, 3), "frames_per_s": round(computed / wall, 4) if wall > 0 else 0.0,
                     "total_s": round(time.perf_counter() - t_start, 3), "interrupted": interrupted}
    write_summary(out_dir, ordered, {"totals": run["totals"]})
    write_json(out_dir / "run.json", run)
    summary = BatchSummary(out_dir=out_dir, rows=ordered, run=run)
    if interrupted:
        raise KeyboardInterrupt
    return summary


def _submit_all(c: Any, setup: DepthSetup, todo: list[Frame], frames_dir: Path, outputs: tuple[str, ...],
                rows: dict[str, dict[str, Any]], *, retries: int, numba_threads: int | None, progress: Any,
                say: Callable[[str], None],
                on_frame: Callable[[dict[str, Any]], None] | None, run: dict[str, Any]) -> bool:
    """Submit the frames a window at a time and collect their rows; returns True when interrupted."""
    from distributed import as_completed

    host_threads = _host_threads(c)
    nthreads = max(1, sum(c.nthreads().values()))
    say(f"batch: {len(todo)} frames on {len(host_threads)} Dask workers ({nthreads} threads)")
    token = uuid.uuid4().hex[:8]
    # The per-rig tables travel once, as one task that every frame depends on: each worker fetches its
    # result once and keeps it while it has frames. Unlike scattered data, a task's result is rebuilt
    # from its recipe (these bytes, held by the scheduler) when the workers that hold it die.
    setup_f = c.submit(pickle.loads, pickle.dumps(setup, protocol=pickle.HIGHEST_PROTOCOL),
                       key=f"prismstereo-setup-{token}", pure=False, retries=retries)
    window = 2 * nthreads + 2
    pending = iter(todo)
    by_key: dict[str, Frame] = {}
    futures = as_completed()
    extra = {"rig": run["rig"].get("name")}

    def submit_next() -> None:
        f = next(pending, None)
        if f is None:
            return
        fut = c.submit(process_frame, setup_f, f, str(frames_dir), outputs, host_threads=host_threads,
                       client_pid=os.getpid(), numba_threads=numba_threads, extra=extra,
                       key=f"prismstereo-frame-{token}-{f.name}",
                       retries=retries, pure=False)
        by_key[fut.key] = f
        futures.add(fut)

    for _ in range(window):
        submit_next()
    try:
        for fut in futures:
            f = by_key.pop(fut.key)
            try:
                row = fut.result()
            except Exception as exc:  # noqa: BLE001 - the task was lost (its worker died more than `retries` times)
                row = {**_base_row(f), "error": _error_line(exc)}
            rows[f.name] = row
            fut.release()
            if progress is not None:
                progress.update(1)
            if on_frame is not None:
                on_frame(row)
            submit_next()
    except KeyboardInterrupt:
        c.cancel(list(futures.futures))
        return True
    finally:
        if progress is not None:
            progress.close()
    return False
