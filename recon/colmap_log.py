"""Send COLMAP's (and glog's) output to a log file instead of the terminal.

COLMAP logs through glog and ``std::cout`` straight to the process's file descriptors 1 and 2, not through
Python's ``sys.stdout``; ``contextlib.redirect_stdout`` cannot catch it. :func:`native_output_to` therefore
points fds 1 and 2 at the log file with ``dup2`` for the duration of the block, while Python's own
``sys.stdout`` / ``sys.stderr`` (progress bars, messages) keep writing to the terminal through duplicates of the
original descriptors. On exit, glog warnings and errors written during the block are collected into one
readable line each (``NativeLog.warnings``); the caller decides how to show them.

File descriptors belong to the process: the redirection is process-wide, so blocks are serialised with a lock
(a nested block on the same thread redirects to its own file and restores the outer one on exit).
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import re
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

_LOCK = threading.RLock()
# glog prefix: severity letter, date (MMDD or YYYYMMDD), time, thread id, file:line] message
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_GLOG = re.compile(r"^([IWEF])\d{4,8} [\d:.]+\s+\d+ ([^:\]\s]+)(?::[^\]]*)?\] ?(.*)$")


@dataclass
class NativeLog:
    """What a :func:`native_output_to` block wrote: the log file, bytes written, and its warnings/errors as
    readable one-liners (``"COLMAP warning (mapper.cc): message"``; repeats counted, not repeated)."""

    path: Path
    num_bytes: int = 0
    warnings: list[str] = field(default_factory=list)


def _flush_c_stdio() -> None:
    """Flush C stdio buffers (``printf``/``std::cout`` output still in memory) before fds are swapped."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)


def summarise_warnings(text: str, limit: int = 20) -> list[str]:
    """glog W/E/F lines of ``text`` → one readable line per distinct message, in order of first appearance."""
    counts: dict[str, int] = {}
    for line in text.splitlines():
        m = _GLOG.match(_ANSI.sub("", line).strip())  # glog colours its lines when it believes it has a terminal
        if not m or m.group(1) == "I":
            continue
        kind = {"W": "warning", "E": "error", "F": "fatal error"}[m.group(1)]
        source = os.path.basename(m.group(2))
        message = " ".join(m.group(3).split())
        key = f"COLMAP {kind} ({source}): {message}"
        counts[key] = counts.get(key, 0) + 1
    lines = [k if n == 1 else f"{k} (x{n})" for k, n in counts.items()]
    if len(lines) > limit:
        lines = lines[:limit] + [f"... and {len(lines) - limit} more COLMAP warnings in the log"]
    return lines


def _python_stream(fd: int, like: io.TextIOBase) -> io.TextIOWrapper:
    """A text stream writing to ``fd`` (a duplicate of the original terminal descriptor), unbuffered by line."""
    encoding = getattr(like, "encoding", None) or "utf-8"
    errors = getattr(like, "errors", None) or "backslashreplace"
    raw = os.fdopen(fd, "wb", buffering=0, closefd=False)
    return io.TextIOWrapper(raw, encoding=encoding, errors=errors, line_buffering=True, write_through=True)


def _uses_fd(stream: object, fd: int) -> bool:
    try:
        return stream.fileno() == fd  # type: ignore[attr-defined]
    except (AttributeError, OSError, ValueError):
        return False  # pytest's capture, StringIO, ...: not the descriptor, leave it alone


@contextlib.contextmanager
def native_output_to(log_path: str | PathLike[str] | None) -> Iterator[NativeLog | None]:
    """Within the block, everything written to fds 1 and 2 (COLMAP, glog, C/C++ code) is appended to ``log_path``.

    ``log_path`` None: nothing is redirected (yields None). The log's parent folder is created. Python's
    ``sys.stdout``/``sys.stderr`` keep going to where they went before. On exit the yielded :class:`NativeLog`
    holds the byte count and the warnings written during the block.
    """
    if log_path is None:
        yield None
        return
    path = Path(log_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with _LOCK:
        log = NativeLog(path)
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        _flush_c_stdio()
        log_fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
        start = os.fstat(log_fd).st_size
        saved = {fd: os.dup(fd) for fd in (1, 2)}
        swapped: dict[str, object] = {}
        try:
            for fd in (1, 2):
                os.dup2(log_fd, fd)
            for name, fd in (("stdout", 1), ("stderr", 2)):
                stream = getattr(sys, name)
                if _uses_fd(stream, fd):
                    swapped[name] = stream
                    setattr(sys, name, _python_stream(saved[fd], stream))
            yield log
        finally:
            for name, original in swapped.items():
                with contextlib.suppress(Exception):
                    getattr(sys, name).flush()
                setattr(sys, name, original)
            _flush_c_stdio()
            for fd in (1, 2):
                os.dup2(saved[fd], fd)
                os.close(saved[fd])
            end = os.fstat(log_fd).st_size
            os.close(log_fd)
            log.num_bytes = end - start
            if log.num_bytes:
                with open(path, "rb") as f:
                    f.seek(start)
                    log.warnings = summarise_warnings(f.read().decode("utf-8", "replace"))
