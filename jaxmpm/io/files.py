"""Files written safely: never over a user's file unless asked, never over a directory, through a
temporary name renamed into place (an interrupted write leaves no partial file under the final
name), and not onto a disk without room. Used by `jaxmpm.io`, `jaxmpm.restart` and the commands."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import time
import uuid
from collections.abc import Iterator
from pathlib import Path


def check_space(folder: str | os.PathLike, needed: int) -> None:
    """OSError if the disk holding `folder` has less than `needed` bytes free, saying both."""
    folder = Path(folder)
    probe = folder
    while not probe.exists():
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if free < needed:
        raise OSError(
            f"not enough disk space in {folder}: the outputs need about {needed / 1e6:.1f} MB, "
            f"{free / 1e6:.1f} MB are free (fewer outputs: --n-out, or another --out)"
        )


def check_new(*paths: str | os.PathLike, overwrite: bool = False) -> None:
    """Raise FileExistsError naming the first of `paths` that exists, unless overwrite; and, even
    with overwrite, the first that is a directory (a file never replaces a directory). Then make
    sure each path's folder exists and can be written (`check_writable`), so that a run finds out
    before it computes anything, not when it saves its result."""
    for p in paths:
        if os.path.isdir(p):
            raise FileExistsError(
                f"{os.fspath(p)} is a directory: refusing to replace it with a file "
                "(allowed a file name; move or remove the directory)"
            )
    if not overwrite:
        for p in paths:
            if os.path.lexists(p):
                raise FileExistsError(
                    f"{os.fspath(p)} exists: refusing to overwrite it "
                    "(pass overwrite=True, or --overwrite on the command line)"
                )
    check_writable(*paths)


def check_writable(*paths: str | os.PathLike) -> None:
    """Create each path's folder if needed and write (then delete) a probe file there; OSError
    naming the folder and the reason where that fails (no permission, read-only disk, a file in
    the way)."""
    for path in {Path(p).parent: Path(p) for p in reversed(paths)}.values():
        make_parent(path)
        folder = path.parent
        probe = folder / f".jaxmpm-write-probe.{uuid.uuid4().hex[:12]}"
        try:
            os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        except OSError as e:
            raise OSError(
                f"cannot write in {os.fspath(folder)}: {e.strerror or e} (allowed a folder this user can write to)"
            ) from None
        os.unlink(probe)


def make_parent(path: Path) -> None:
    """Create path's folder (and the folders above it); FileExistsError naming the path and the
    component in the way where a component of the folder is a file."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        block = next((q for q in reversed(path.parents) if os.path.lexists(q) and not q.is_dir()), path.parent)
        raise FileExistsError(
            f"cannot write {os.fspath(path)}: {os.fspath(block)} is a file, not a folder "
            "(allowed a path whose folders are folders or do not exist yet)"
        ) from None
    except OSError as e:
        raise OSError(
            f"cannot create the folder {os.fspath(path.parent)}: {e.strerror or e} "
            "(allowed a folder this user can create and write to)"
        ) from None


# the temporary files of `atomic_write` and `check_writable`: .<name>.<pid>-<12 hex>.tmp (or, written by
# earlier versions, .<name>.<12 hex>.tmp) and .jaxmpm-write-probe.<12 hex>
_TEMPORARY = re.compile(r"^\.(?:.+\.(?:(?P<pid>\d+)-)?[0-9a-f]{12}\.tmp|jaxmpm-write-probe\.[0-9a-f]{12})$")
_UNOWNED_AGE = 600.0  # s: a temporary file that names no process is stale after this long


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by another user
        return True
    return True


def remove_stale_temporaries(folder: str | os.PathLike) -> list[str]:
    """Delete the temporary files that killed runs left in `folder` (a run killed while it wrote a
    file: SIGKILL, a power cut): those whose process is gone, and those naming no process that are
    older than _UNOWNED_AGE. Returns the names deleted (empty where none, or no such folder)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    gone = []
    for p in sorted(folder.iterdir()):
        m = _TEMPORARY.match(p.name)
        if not m or not p.is_file() or p.is_symlink():
            continue
        pid = m.group("pid")
        if pid is not None and (int(pid) == os.getpid() or _alive(int(pid))):
            continue
        try:
            if pid is None and time.time() - p.stat().st_mtime < _UNOWNED_AGE:
                continue
            p.unlink()
        except FileNotFoundError:
            continue
        gone.append(p.name)
    return gone


@contextlib.contextmanager
def atomic_write(path: Path) -> Iterator[str]:
    """Yield a fresh temporary name in path's directory (naming this process, so that a later run
    knows it stale once the process is gone: `remove_stale_temporaries`); rename it to `path` on
    success, delete it on error (the final name never holds a partial file)."""
    make_parent(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{uuid.uuid4().hex[:12]}.tmp")
    try:
        yield os.fspath(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
