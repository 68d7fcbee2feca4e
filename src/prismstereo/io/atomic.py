"""Safe output writes: nothing half-written, nothing but regular files ever replaced.

Every output goes to a temporary file (or folder) beside its target and is renamed onto the target only
when it is complete. Rules (docs/formats.md, "Outputs"):

* A target may be a new path or an existing **regular file**, which is replaced. A target that is a
  **symbolic link** is written through: the file the link points to is replaced and the link is kept (a
  link to anything but a regular file or a new path is refused). Folders, devices (``/dev/null``,
  ``/dev/full``), pipes and sockets are never replaced: :class:`~prismstereo.errors.OutputError`.
* A command that writes several files stages them in a hidden temporary folder and moves them into place
  together at the end (:func:`output_dir`, :func:`output_files`); on any failure, Ctrl-C included, the
  staging is removed and the output folder is left as it was (not even created).
* Operating-system failures while writing (disk full, quota, read-only file system) become
  ``OutputError`` naming the path.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

from prismstereo.errors import OutputError

__all__ = [
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_dir",
    "check_output_file",
    "os_error_reason",
    "output_dir",
    "output_files",
]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def os_error_reason(exc: OSError) -> str:
    """The reason the system refused a read or write, in words (disk full, file too large, its own message)."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return "no space left on the device"
    if exc.errno == errno.EFBIG:
        return "file too large for this file system or process limit"
    return exc.strerror or str(exc) or type(exc).__name__


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _existing_ancestor(path: Path) -> Path:
    probe = path.absolute()
    while not os.path.lexists(probe):
        probe = probe.parent
    return probe


def _probe_writable(folder: Path, shown: str, what: str) -> None:
    # a real test: root passes os.access everywhere, read-only mounts and full disks do not
    try:
        Path(tempfile.mkdtemp(prefix=".prismstereo-probe-", dir=folder)).rmdir()
    except OSError as exc:
        raise OutputError(f"expected {what}, got {shown!r} ({os_error_reason(exc)})") from None


def resolve_output_file(path: str | os.PathLike[str]) -> Path:
    """The file that writing ``path`` replaces (a symlink's target), checked to be a regular file or new.

    Raises
    ------
    OutputError
        If the path (or a link's target) is a folder, a device, a pipe or a socket, or lies under a file.
    """
    shown = str(path)
    target = Path(path)
    if target.is_symlink():
        target = Path(os.path.realpath(target))
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise OutputError(f"expected an output file path, got {shown!r} (a parent of it is a file)") from None
    except OSError as exc:
        raise OutputError(f"expected an output file path, got {shown!r} ({os_error_reason(exc)})") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise OutputError(f"expected a new or regular output file, got {shown!r} ({_kind(st.st_mode)}; "
                          "refusing to replace it)")
    anc = _existing_ancestor(target.parent if str(target.parent) else Path("."))
    if not anc.is_dir():
        raise OutputError(f"expected an output file path, got {shown!r} ({str(anc)!r} is a file)")
    return target


def check_output_file(path: str | os.PathLike[str]) -> None:
    """Fail early (OutputError) if ``path`` cannot be written as a file; creates nothing."""
    target = resolve_output_file(path)
    anc = _existing_ancestor(target.parent if str(target.parent) else Path("."))
    if not os.access(anc, os.W_OK | os.X_OK):
        raise OutputError(f"expected a writable output folder for {str(path)!r}, got {str(anc)!r} "
                          "(permission denied)")
    _probe_writable(anc, str(path), "a writable output file path")


def check_output_dir(path: str | os.PathLike[str]) -> None:
    """Fail early (OutputError) if ``path`` cannot become a writable folder; creates nothing."""
    shown = str(path)
    p = Path(path).absolute()
    if p.exists() and not p.is_dir():
        mode = os.stat(p).st_mode
        what = "an existing file" if stat.S_ISREG(mode) else _kind(mode)
        raise OutputError(f"expected an output folder, got {shown!r} ({what})")
    if not p.exists() and p.is_symlink():
        raise OutputError(f"expected an output folder, got {shown!r} (a dangling symbolic link)")
    probe = _existing_ancestor(p)
    if not probe.is_dir():
        raise OutputError(f"expected an output folder, got {shown!r} ({str(probe)!r} is a file)")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"expected a writable output folder, got {shown!r} (permission denied)")
    _probe_writable(probe, shown, "a writable output folder")


def _make_parents(folder: Path, shown: str) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"expected a writable output folder for {shown!r}, got {str(folder)!r} "
                          f"({os_error_reason(exc)})") from None


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it is renamed onto ``path``, on error removed.

    The temporary name keeps the suffix of ``path`` so that writers that dispatch on the extension
    (OpenCV's ``imwrite``) still work. Only a new path or a regular file is replaced (a symlink is written
    through to its target); anything else, and any OS error while writing, is an
    :class:`~prismstereo.errors.OutputError` naming ``path``.
    """
    shown = str(path)
    target = resolve_output_file(path)
    parent = target.parent if str(target.parent) else Path(".")
    _make_parents(parent, shown)
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix, dir=parent)
    except OSError as exc:
        raise OutputError(f"expected a writable output folder for {shown!r} ({os_error_reason(exc)})") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        # mkstemp creates owner-only files; outputs should get the usual permissions under the user's umask
        os.chmod(tmp, 0o666 & ~_umask())
        try:
            yield tmp
        except OSError as exc:
            if isinstance(exc, OutputError):
                raise
            raise OutputError(f"could not write {shown!r}: {os_error_reason(exc)}") from None
        _replace_file(tmp, target, shown)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _replace_file(src: Path, dest: Path, shown: str) -> None:
    # re-checked just before the rename: the target may have changed while the output was computed
    resolve_output_file(dest)
    try:
        os.replace(src, dest)
    except OSError as exc:
        raise OutputError(f"could not write {shown!r}: {os_error_reason(exc)}") from None


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


@contextlib.contextmanager
def output_files(paths: Sequence[str | os.PathLike[str]]) -> Iterator[list[Path]]:
    """Yield temporary paths for several output files that appear together or not at all.

    Each temporary path sits beside its target (same suffix). When the block succeeds, all targets are
    checked, then all are renamed into place; on failure (or Ctrl-C) the temporaries are removed.
    """
    targets = [resolve_output_file(p) for p in paths]
    tmps: list[Path] = []
    try:
        for shown, target in zip(paths, targets, strict=True):
            parent = target.parent if str(target.parent) else Path(".")
            _make_parents(parent, str(shown))
            try:
                fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix, dir=parent)
            except OSError as exc:
                raise OutputError(f"expected a writable output folder for {str(shown)!r} "
                                  f"({os_error_reason(exc)})") from None
            os.close(fd)
            tmps.append(Path(name))
            os.chmod(name, 0o666 & ~_umask())
        try:
            yield list(tmps)
        except OSError as exc:
            if isinstance(exc, OutputError):
                raise
            raise OutputError(f"could not write {', '.join(map(str, paths))}: {os_error_reason(exc)}") from None
        for target in targets:
            resolve_output_file(target)
        for shown, tmp, target in zip(paths, tmps, targets, strict=True):
            _replace_file(tmp, target, str(shown))
    finally:
        for tmp in tmps:
            with contextlib.suppress(OSError):
                tmp.unlink()


@contextlib.contextmanager
def output_dir(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a staging folder whose files are moved into ``path`` only if the block succeeds.

    A new output folder is staged as a hidden sibling and renamed into place in one step (its missing
    parents are created only then). For an existing folder the staging sits inside it and its files are
    moved in when all are written: files already there with other names are kept, files with the same
    names replaced (only regular files: a folder or device in the way is an ``OutputError`` before
    anything moves). A failure leaves ``path`` as it was.
    """
    shown = str(path)
    target = Path(path)
    check_output_dir(target)
    exists = target.is_dir()
    home = target if exists else _existing_ancestor(target.parent)
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{target.name or 'out'}.staging-", dir=home))
    except OSError as exc:
        raise OutputError(f"expected a writable output folder, got {shown!r} ({os_error_reason(exc)})") from None
    try:
        os.chmod(staging, 0o777 & ~_umask())  # mkdtemp makes it owner-only; it may become the output folder
        try:
            yield staging
        except OutputError as exc:  # name the output the user asked for, not the staging folder
            raise OutputError(str(exc).replace(str(staging), str(target))) from None
        except OSError as exc:
            where = exc.filename if isinstance(exc.filename, str) else shown
            where = where.replace(str(staging), str(target))
            raise OutputError(f"could not write {where!r}: {os_error_reason(exc)}") from None
        if not exists and not target.exists():
            _make_parents(target.parent, shown)
            try:
                os.rename(staging, target)
            except OSError as exc:
                raise OutputError(f"could not create {shown!r}: {os_error_reason(exc)}") from None
            return
        items = [item for item in sorted(staging.rglob("*")) if item.is_file()]
        moves = [(item, target / item.relative_to(staging)) for item in items]
        for _, dest in moves:  # everything checked before anything moves
            resolve_output_file(dest)
        for item, dest in moves:
            _make_parents(dest.parent, shown)
            _replace_file(item, dest, str(dest))
    finally:
        shutil.rmtree(staging, ignore_errors=True)
