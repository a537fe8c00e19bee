"""Disk space: refuse a stage that would not fit, and tell a disk that filled up from other failures.

Each stage estimates what it will write (:meth:`hybridsplat.stages.base.Stage.expected_bytes`, from its inputs'
sizes and counts); the runner compares that with the free space of the project's file system before the stage
touches anything (:func:`check_space`), and after a failure asks :func:`disk_full_behind` whether the disk was the
cause, so that the error names the stage, the file and the space instead of a library's message.
"""

from __future__ import annotations

import errno
import os
import shutil
from collections.abc import Iterable
from os import PathLike
from pathlib import Path

from core.errors import DiskSpaceError, exception_chain

RESERVE_BYTES = 1 << 20
"""Space kept free beyond a stage's estimate: the manifest, the stage's log and the lock's holder file (~100 kB)."""

FULL_BELOW_BYTES = 1 << 20
"""A file system with less free than this after a failure is taken to have filled up during the stage."""

SPACE_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


def format_bytes(n: int | float) -> str:
    """``1.5 MB`` style (powers of 1024, as ``df -h``)."""
    value = float(n)
    for unit in ("B", "kB", "MB", "GB"):
        if abs(value) < 1024 or unit == "GB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    return f"{value:.1f} TB"


def free_bytes(folder: str | PathLike[str]) -> int:
    """Free bytes (for this user) on the file system of ``folder`` (its nearest existing parent)."""
    path = Path(folder).resolve()
    while not path.exists() and path != path.parent:
        path = path.parent
    return shutil.disk_usage(path).free


def tree_bytes(paths: Iterable[str | PathLike[str]]) -> int:
    """Bytes of the files at ``paths`` (folders: every file inside, recursively; missing paths count 0)."""
    total = 0
    for path in map(Path, paths):
        if path.is_file() and not path.is_symlink():
            total += path.stat().st_size
        elif path.is_dir() and not path.is_symlink():
            for folder, _dirs, files in os.walk(path):
                for name in files:
                    file = Path(folder) / name
                    if not file.is_symlink():
                        total += file.stat().st_size
    return total


def newest_file(paths: Iterable[str | PathLike[str]]) -> Path | None:
    """The most recently modified file at or under ``paths`` (the one a failed stage was most likely writing)."""
    newest: tuple[float, Path] | None = None
    for path in map(Path, paths):
        files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else []
        for file in files:
            mtime = file.stat().st_mtime
            if newest is None or mtime > newest[0]:
                newest = (mtime, file)
    return newest[1] if newest is not None else None


def check_space(stage: str, folder: str | PathLike[str], needed: int, reclaimable: int = 0) -> None:
    """Raise :class:`DiskSpaceError` when ``needed`` bytes (+ :data:`RESERVE_BYTES`) do not fit in ``folder``.

    reclaimable: bytes the stage frees before it writes (its previous outputs, removed when it reruns).
    """
    free = free_bytes(folder)
    if needed + RESERVE_BYTES <= free + reclaimable:
        return
    raise DiskSpaceError(
        f"stage {stage} needs about {format_bytes(needed + RESERVE_BYTES)} here but "
        f"{format_bytes(free + reclaimable)} are free; nothing was changed: free some space (or move the project) "
        "and run again",
        folder,
        needed=needed,
        free=free,
    )


def os_error_behind(err: BaseException, numbers: Iterable[int]) -> OSError | None:
    """The OSError with one of the errno ``numbers`` that caused ``err`` (or is ``err``), following the chain of
    causes and contexts (a library may re-raise it as its own error); None if there is none."""
    wanted = set(numbers)
    return next((e for e in exception_chain(err) if isinstance(e, OSError) and e.errno in wanted), None)


def space_errno_behind(err: BaseException) -> OSError | None:
    """The out-of-space OSError (ENOSPC, EDQUOT) behind ``err``, if any."""
    return os_error_behind(err, SPACE_ERRNOS)


def disk_full_behind(err: BaseException, folder: str | PathLike[str]) -> bool:
    """Whether ``err`` (raised while a stage wrote into ``folder``) came from a full disk: an ENOSPC/EDQUOT error
    behind it, or (for libraries that report it in their own words, e.g. COLMAP) a file system left with almost
    nothing free (< :data:`FULL_BELOW_BYTES`)."""
    if space_errno_behind(err) is not None:
        return True
    try:
        return free_bytes(folder) < FULL_BELOW_BYTES
    except OSError:
        return False
