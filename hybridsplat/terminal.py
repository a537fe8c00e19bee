"""What a user sees while the pipeline runs: progress bars with ETA, one summary line per stage, and nothing else.

COLMAP and glog write to the process's file descriptors 1 and 2 directly (not through Python), so the only way to
keep their lines off the terminal is to point those descriptors at the stage's log file while it runs
(:meth:`Terminal.capture`). The terminal itself is a duplicate of the original stderr, kept open for rich.
Python warnings raised during a stage become one readable line each (and are kept in the log).
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

ProgressCallback = Callable[[str, int, int], None]  # (label, done, total), as recon.mvs.Progress; see stage()


class Terminal:
    """Progress bars and summary lines on the user's terminal (stderr), quiet when ``quiet`` or not a TTY."""

    def __init__(self, quiet: bool = False) -> None:
        from rich.console import Console

        self._stream: IO[str] = _duplicate_stderr()
        self.console = Console(file=self._stream, stderr=False, highlight=False, soft_wrap=True)
        self.quiet = quiet
        self._progress = None

    def line(self, text: str) -> None:
        """One line on the terminal (shown even while a stage's output is captured)."""
        if self._progress is not None:
            self._progress.console.print(text, markup=False, highlight=False)
        else:
            self.console.print(text, markup=False, highlight=False)

    @contextlib.contextmanager
    def stage(self, name: str, log_path: Path) -> Iterator[ProgressCallback]:
        """While a stage runs: its COLMAP/glog output and warnings go to ``log_path``; yields a progress callback."""
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        progress = Progress(
            TextColumn(f"{name:<10}" + " {task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("eta"),
            TimeRemainingColumn(),
            console=self.console,
            transient=True,
            disable=self.quiet or not self.console.is_terminal,  # no bars (nor blank lines) in logs and pipes
            redirect_stdout=False,  # Python prints during a stage belong to the log, like COLMAP's
            redirect_stderr=False,
        )
        tasks: dict[str, int] = {}

        def update(label: str, done: int, total: int) -> None:
            # "name: details" keeps one bar per name while the details (a loss, a count) change
            key = label.split(": ", 1)[0]
            if key not in tasks:
                tasks[key] = progress.add_task(label, total=max(int(total), 1))
            progress.update(tasks[key], description=label, completed=int(done), total=max(int(total), 1))

        log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(log_path, "a", encoding="utf-8") as log, _redirect_fds(log), _warnings_to(self, log):
            self._progress = progress
            try:
                with progress:
                    yield update
            finally:
                self._progress = None


def _duplicate_stderr() -> IO[str]:
    try:
        return os.fdopen(os.dup(sys.stderr.fileno()), "w", buffering=1, encoding="utf-8", errors="replace")
    except (AttributeError, OSError, ValueError):  # no real stderr (embedded use): write where Python writes
        return sys.stderr


@contextlib.contextmanager
def _redirect_fds(log: IO[str]) -> Iterator[None]:
    """Point fds 1 and 2 at ``log`` (C libraries included); Python's own sys.stdout/err follow the fds."""
    saved = []
    try:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        for fd in (1, 2):
            saved.append((fd, os.dup(fd)))
            os.dup2(log.fileno(), fd)
    except (OSError, ValueError, AttributeError):
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        saved = []
    try:
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)


@contextlib.contextmanager
def _warnings_to(terminal: Terminal, log: IO[str]) -> Iterator[None]:
    def show(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ARG001
        text = " ".join(str(message).split())
        log.write(f"warning: {category.__name__}: {text} ({filename}:{lineno})\n")
        terminal.line(f"  warning: {text}")

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield
