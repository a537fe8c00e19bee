"""Atomic writes: write to a temporary name in the target folder, then rename onto the target.

A crash or an error mid-write leaves the previous file (or nothing) in place, never a half-written one.

Commands that write several files wrap their work in :func:`output_transaction`: every
:func:`atomic_path` inside it keeps its temporary file until the transaction ends, then all are renamed
onto their targets (success) or all removed (error, Ctrl-C, SIGTERM) — all or nothing.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import tempfile
from collections.abc import Iterator
from os import PathLike
from pathlib import Path

from core.errors import InputFileError


class _Transaction:
    """Pending renames and removals of one :func:`output_transaction`, and the folders it created."""

    def __init__(self) -> None:
        self.renames: list[tuple[Path, Path]] = []
        self.removals: list[Path] = []
        self.created_dirs: list[Path] = []

    def commit(self) -> None:
        for _tmp, target in self.renames:
            if target.is_dir():
                raise InputFileError("is a folder, expected an output file path", target)
        for tmp, target in self.renames:
            os.replace(tmp, target)
        for path in self.removals:
            if path not in {t for _, t in self.renames}:
                path.unlink(missing_ok=True)

    def rollback(self) -> None:
        for tmp, _target in self.renames:
            tmp.unlink(missing_ok=True)
        for folder in reversed(self.created_dirs):
            with contextlib.suppress(OSError):
                folder.rmdir()  # only when still empty


_TRANSACTION: contextvars.ContextVar[_Transaction | None] = contextvars.ContextVar("output_transaction", default=None)


@contextlib.contextmanager
def output_transaction() -> Iterator[None]:
    """All-or-nothing outputs: files written with :func:`atomic_path` inside appear only when the block ends
    without an exception; otherwise none of them does (and folders created for them are removed when empty).

    Code inside must not read back a file it wrote in the same transaction (it is not there yet).
    Nested transactions join the outer one.
    """
    if _TRANSACTION.get() is not None:
        yield
        return
    tx = _Transaction()
    token = _TRANSACTION.set(tx)
    try:
        yield
    except BaseException:
        _TRANSACTION.reset(token)
        tx.rollback()
        raise
    _TRANSACTION.reset(token)
    try:
        tx.commit()
    except BaseException:
        tx.rollback()
        raise


def check_output_file(path: str | PathLike[str]) -> Path:
    """Refuse an output file path early: an existing folder there, a file where a parent folder should be,
    or a parent that cannot be written. Raises :class:`InputFileError` naming the offending path."""
    target = Path(path)
    if target.is_dir():
        raise InputFileError("is a folder, expected an output file path", target)
    _check_parent(target)
    return target


def check_output_dir(path: str | PathLike[str]) -> Path:
    """Refuse an output folder path early: a file there, or a parent that cannot be written."""
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise InputFileError("is a file, expected an output folder", target)
    if target.is_dir():
        if not os.access(target, os.W_OK | os.X_OK):
            raise InputFileError("output folder is not writable", target)
        return target
    _check_parent(target)
    return target


def _check_parent(target: Path) -> None:
    parent = target.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputFileError("is a file, but the output path needs a folder here", parent)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputFileError("folder is not writable", parent)


def _make_parents(folder: Path, tx: _Transaction | None) -> None:
    missing = []
    p = folder
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        problem = f"cannot create the output folder ({err.strerror or err})"
        raise InputFileError(problem, err.filename or folder) from err
    if tx is not None:
        tx.created_dirs.extend(reversed(missing))


@contextlib.contextmanager
def atomic_path(path: str | PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it is renamed onto ``path``, on error removed.

    The temporary name keeps the target's suffix, so libraries that choose a format from the suffix
    (laspy's LAZ, open3d) behave as they would on the final name. Inside :func:`output_transaction` the
    rename waits for the end of the transaction. Raises :class:`InputFileError` naming ``path`` when the
    target is a folder or its folder cannot be created or written.
    """
    target = Path(path)
    tx = _TRANSACTION.get()
    if target.is_dir():
        raise InputFileError("is a folder, expected an output file path", target)
    _make_parents(target.parent, tx)
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent)
    except OSError as err:
        raise InputFileError(f"cannot write here ({err.strerror or err})", target) from err
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~_current_umask())  # mkstemp creates 0600; give the file the permissions open() would
    try:
        yield tmp
        if tx is not None:
            tx.renames.append((tmp, target))
        else:
            os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def remove_output(path: str | PathLike[str]) -> None:
    """Remove a stale output file (e.g. an origin sidecar); inside a transaction, when it commits."""
    target = Path(path)
    tx = _TRANSACTION.get()
    if tx is not None:
        tx.removals.append(target)
    else:
        target.unlink(missing_ok=True)


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: str | PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | PathLike[str], text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
