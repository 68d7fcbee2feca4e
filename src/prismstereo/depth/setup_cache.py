"""On-disk cache of a rig's virtual cameras and rectification, the per-rig part of a depth run.

Fitting the virtual cameras and building the rectification maps depend only on the rig, the pair of faces
and the camera model, yet a ``prismstereo depth`` call (a new process) would redo them for every capture.
They are kept in one ``.npz`` file per set-up (arrays only, read without pickle):

- content: the virtual cameras, the rectified pair with its remap tables and the pair's epipolar curves
  (:class:`~prismstereo.rectify.epipolar.EpipolarTable`); in a second file of the same key (``rays-*.npy``,
  read only by exact triangulation) the exact ray of every rectified pixel
  (:class:`~prismstereo.depth.triangulation.RayTable`, 96 bytes per pixel: one (4, h, w, 3) float64 array,
  mapped into memory copy-on-write rather than read, so a run reads the pages triangulation touches and no
  zip member's checksum, 177 MB at 3 MP); in a third (``range-*.npz``) the
  rig-only part of the automatic search range (:class:`~prismstereo.depth.search_range.RigRange`: the depths
  at which the views overlap and their common view);
- key: SHA-256 of the resolved rig (:meth:`~prismstereo.config.Rig.to_dict`, which holds the image size),
  the pair of faces, the camera model, the package version and the source of the modules that compute the
  set-up (``cameras``, ``optics``, ``rectify``, ``config``, this module), so that an edited library never
  reads an older result;
- folder: ``$PRISMSTEREO_CACHE_DIR``, else ``$XDG_CACHE_HOME/prismstereo``, else ``~/.cache/prismstereo``;
  ``PRISMSTEREO_CACHE=0`` (or ``off``, ``no``, ``false``) disables it;
- writes go to a temporary file in the folder, renamed over the entry (concurrent writers each write a
  whole file, the last rename wins; readers never see a partial one); a file that cannot be read (truncated,
  corrupt, another layout) counts as missing and is rewritten; a folder that cannot be written (read-only,
  disk full) costs the saving only (logged), never the run; the folder keeps the :data:`MAX_ENTRIES`
  most recently written entries.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np

import prismstereo
from prismstereo.cameras import VirtualView
from prismstereo.cameras.pinhole import PinholeCamera
from prismstereo.config import Rig
from prismstereo.depth.search_range import RigRange
from prismstereo.depth.triangulation import RayTable
from prismstereo.rectify import RectifiedPair
from prismstereo.rectify.epipolar import EpipolarTable

log = logging.getLogger(__name__)
T = TypeVar("T")

__all__ = ["cache_folder", "load_range", "load_rays", "load_setup", "load_view", "save_range", "save_rays",
           "save_setup", "save_view",
           "setup_key"]

_OFF = {"0", "off", "no", "false"}
#: bump when the file layout changes
_LAYOUT = 3
_SOURCES = ("cameras", "optics", "rectify", "config.py", "depth/setup_cache.py", "depth/triangulation.py",
            "depth/search_range.py")
#: entries kept in the folder (the oldest beyond are removed when one is written)
MAX_ENTRIES = 32


def cache_folder() -> Path | None:
    """The cache folder, or None when ``PRISMSTEREO_CACHE`` disables the cache."""
    if os.environ.get("PRISMSTEREO_CACHE", "").strip().lower() in _OFF:
        return None
    if os.environ.get("PRISMSTEREO_CACHE_DIR"):
        return Path(os.environ["PRISMSTEREO_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "prismstereo"


def _source_digest() -> bytes:
    root = Path(prismstereo.__file__).parent
    h = hashlib.sha256()
    for name in _SOURCES:
        p = root / name
        for f in sorted(p.rglob("*.py")) if p.is_dir() else [p]:
            h.update(str(f.relative_to(root)).encode())
            h.update(f.read_bytes())
    return h.digest()


def setup_key(rig: Rig, faces: tuple[int, int], calibration: str) -> str:
    """Hex key of a set-up (module docstring)."""
    h = hashlib.sha256()
    h.update(json.dumps({"rig": rig.to_dict(), "faces": list(faces), "calibration": calibration,
                         "version": prismstereo.__version__, "layout": _LAYOUT}, sort_keys=True,
                        default=str).encode())
    h.update(_source_digest())
    return h.hexdigest()[:40]


def _path(rig: Rig, faces: tuple[int, int], calibration: str, kind: str = "setup", suffix: str = ".npz"
          ) -> Path | None:
    folder = cache_folder()
    return None if folder is None else folder / f"{kind}-{setup_key(rig, faces, calibration)}{suffix}"


def load_setup(rig: Rig, faces: tuple[int, int], calibration: str
               ) -> tuple[tuple[VirtualView, ...], RectifiedPair, EpipolarTable] | None:
    """The cached virtual cameras, rectified pair and epipolar curves of ``faces``, or None (no entry,
    unreadable, disabled)."""
    path = _path(rig, faces, calibration)
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        views = tuple(
            VirtualView(face=int(f), name=str(n), method=str(d["method"]),
                        camera=PinholeCamera(K=K, R=R, C=C, dist=dist[:int(nd)]), rms_px=float(rms),
                        max_px=float(mx))
            for f, n, K, R, C, dist, nd, rms, mx in zip(d["faces"], d["names"], d["K"], d["R"], d["C"],
                                                        d["dist"], d["ndist"], d["rms"], d["max"], strict=True))
        by_face = {v.face: v for v in views}
        lf, rf = (int(v) for v in d["pair_faces"])
        pair = RectifiedPair(
            left_face=lf, right_face=rf, K=d["pair_K"], R=d["pair_R"], C_left=d["C_left"], C_right=d["C_right"],
            size=(int(d["size"][0]), int(d["size"][1])), map_left=d["map_left"], map_right=d["map_right"],
            valid_left=d["valid_left"], valid_right=d["valid_right"], method=str(d["pair_method"]),
            remap=str(d["remap"]), reference_depth_mm=float(d["reference_depth_mm"]), view_left=by_face[lf],
            view_right=by_face[rf], rig=rig, disparity_offset=float(d["disparity_offset"]))
        epipolar = EpipolarTable.from_arrays(d)
        if {lf, rf} != set(faces) or pair.map_left.shape[:2] != (pair.size[1], pair.size[0]):
            raise ValueError("another set-up")
    except (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile) as exc:
        log.info("set-up cache entry %s unreadable (%s): computing it again", path, exc)
        return None
    log.debug("set-up of faces %s read from %s", faces, path)
    return views, pair, epipolar


def save_setup(rig: Rig, faces: tuple[int, int], calibration: str, views: Sequence[VirtualView],
               pair: RectifiedPair, epipolar: EpipolarTable) -> Path | None:
    """Store a set-up (best effort: returns the file, or None when disabled or it could not be written)."""
    path = _path(rig, faces, calibration)
    if path is None:
        return None
    nd = max((v.camera.dist.size for v in views), default=0)
    dist = np.zeros((len(views), nd))
    for i, v in enumerate(views):
        dist[i, :v.camera.dist.size] = v.camera.dist
    arrays = {
        "faces": np.array([v.face for v in views]), "names": np.array([v.name for v in views]),
        "method": np.array(views[0].method if views else ""),
        "K": np.stack([v.camera.K for v in views]), "R": np.stack([v.camera.R for v in views]),
        "C": np.stack([v.camera.C for v in views]), "dist": dist,
        "ndist": np.array([v.camera.dist.size for v in views]),
        "rms": np.array([v.rms_px for v in views]), "max": np.array([v.max_px for v in views]),
        "pair_faces": np.array([pair.left_face, pair.right_face]), "pair_K": pair.K, "pair_R": pair.R,
        "C_left": pair.C_left, "C_right": pair.C_right, "size": np.array(pair.size),
        "map_left": pair.map_left, "map_right": pair.map_right, "valid_left": pair.valid_left,
        "valid_right": pair.valid_right, "pair_method": np.array(pair.method), "remap": np.array(pair.remap),
        "reference_depth_mm": np.array(pair.reference_depth_mm),
        "disparity_offset": np.array(pair.disparity_offset),
        **epipolar.to_arrays(),
    }
    return _write(path, arrays)


def load_rays(rig: Rig, faces: tuple[int, int], calibration: str, *, shape: tuple[int, int]) -> RayTable | None:
    """The cached exact-ray table of a set-up (:class:`~prismstereo.depth.triangulation.RayTable`) whose
    rectified views are ``shape`` (h, w), or None (no entry, unreadable, another shape, disabled). Its arrays
    map the entry's file copy-on-write (module docstring): writing to them changes the file on no disk."""
    path = _path(rig, faces, calibration, "rays", ".npy")
    if path is None or not path.is_file():
        return None
    try:
        a = np.load(path, mmap_mode="c", allow_pickle=False)
        want = (4, *shape, 3)
        if a.shape != want or a.dtype != np.float64:
            raise ValueError(f"of shape {a.shape} and type {a.dtype}, expected {want} float64")
    except (OSError, ValueError, EOFError) as exc:
        log.info("ray table cache entry %s unreadable (%s): computing it again", path, exc)
        return None
    return RayTable(*(np.asarray(a[i]) for i in range(4)))


def save_rays(rig: Rig, faces: tuple[int, int], calibration: str, table: RayTable) -> Path | None:
    """Store a set-up's exact-ray table (best effort, as :func:`save_setup`): the four (h, w, 3) arrays as one
    (4, h, w, 3) ``.npy``, in the order left origins, left directions, right origins, right directions."""
    path = _path(rig, faces, calibration, "rays", ".npy")
    if path is None:
        return None
    stacked = np.stack([table.left_origins, table.left_directions, table.right_origins, table.right_directions])
    return _write(path, {"rays": stacked}, single=True)


def load_range(rig: Rig, faces: tuple[int, int], calibration: str, *, shape: tuple[int, int]) -> RigRange | None:
    """The cached rig-only search range of a set-up whose rectified views are ``shape`` (h, w), or None."""
    return _load_entry(_path(rig, faces, calibration, "range"), RigRange.from_arrays, lambda r: r.region.shape,
                       shape=shape, what="search range")


def save_range(rig: Rig, faces: tuple[int, int], calibration: str, found: RigRange) -> Path | None:
    """Store a set-up's rig-only search range (best effort, as :func:`save_setup`)."""
    path = _path(rig, faces, calibration, "range")
    return None if path is None else _write(path, found.to_arrays())


def _view_path(rig: Rig, faces: tuple[int, int], calibration: str, depth_mm: tuple[float, float]) -> Path | None:
    """The ``view-*.npz`` entry of a set-up and a depth range (the two depths' exact float64 bits)."""
    folder = cache_folder()
    if folder is None:
        return None
    bits = np.asarray(depth_mm, dtype=np.float64).tobytes().hex()
    return folder / f"view-{setup_key(rig, faces, calibration)}-{bits}.npz"


def load_view(rig: Rig, faces: tuple[int, int], calibration: str, *, depth_mm: tuple[float, float],
              shape: tuple[int, int]) -> tuple[np.ndarray, tuple[int, int]] | None:
    """The cached :func:`~prismstereo.rectify.common_view` of a set-up over ``depth_mm`` (region of ``shape``
    (h, w), disparity pair), or None (no entry, unreadable, another shape, disabled)."""
    path = _view_path(rig, faces, calibration, depth_mm)
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            region, pair = np.asarray(z["region"], dtype=bool), z["disparity_px"]
            if region.shape != tuple(shape) or pair.shape != (2,):
                raise ValueError(f"of shape {region.shape}, expected {tuple(shape)}")
            return region, (int(pair[0]), int(pair[1]))
    except (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile) as exc:
        log.info("common view cache entry %s unreadable (%s): computing it again", path, exc)
        return None


def save_view(rig: Rig, faces: tuple[int, int], calibration: str, *, depth_mm: tuple[float, float],
              region: np.ndarray, disparity_px: tuple[int, int]) -> Path | None:
    """Store a set-up's common view over ``depth_mm`` (best effort, as :func:`save_setup`)."""
    path = _view_path(rig, faces, calibration, depth_mm)
    return None if path is None else _write(path, {"region": np.asarray(region, dtype=bool),
                                                   "disparity_px": np.asarray(disparity_px, dtype=np.int64)})


def _load_entry(path: Path | None, from_arrays: Callable[[dict[str, np.ndarray]], T],
                shape_of: Callable[[T], tuple[int, ...]], *, shape: tuple[int, int], what: str) -> T | None:
    """An entry read back with ``from_arrays``, or None (no entry, unreadable, of another shape, disabled)."""
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            found = from_arrays({k: z[k] for k in z.files})
        if tuple(shape_of(found)) != tuple(shape):
            raise ValueError(f"of shape {tuple(shape_of(found))}, expected {tuple(shape)}")
    except (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile) as exc:
        log.info("%s cache entry %s unreadable (%s): computing it again", what, path, exc)
        return None
    return found


def _write(path: Path, arrays: dict[str, np.ndarray], *, single: bool = False) -> Path | None:
    """Write an entry atomically (module docstring); None when it could not be written. ``single``: the one
    array of ``arrays`` as an ``.npy``, else all of them as an ``.npz``."""
    tmp: str | None = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name.split('-')[0]}-", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            if single:
                (one,) = arrays.values()
                np.save(fh, one, allow_pickle=False)
            else:
                np.savez(fh, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        log.info("set-up not cached in %s (%s): the next run computes it again", path.parent, exc)
        return None
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
    _prune(path.parent)
    return path


def _prune(folder: Path) -> None:
    """Keep the :data:`MAX_ENTRIES` most recently written entries (each edit of the geometry code or rig makes
    a new key; the old files would otherwise stay)."""
    try:
        for kind in ("setup", "rays", "range", "view"):
            entries = sorted(folder.glob(f"{kind}-*.np[yz]"), key=lambda p: p.stat().st_mtime, reverse=True)
            for old in entries[MAX_ENTRIES:]:
                old.unlink()
    except OSError:  # another process pruned first, or the folder went away: nothing to keep tidy
        pass
