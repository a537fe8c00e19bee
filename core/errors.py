"""The toolkit's error hierarchy.

Every error that comes from bad input carries the file it concerns and the problem in words, so that
the CLI can print one readable line (``hybridsplat: <file>: <problem>``) and exit with code 2.
"""

from __future__ import annotations

from collections.abc import Iterator
from os import PathLike
from pathlib import Path


def exception_chain(err: BaseException) -> Iterator[BaseException]:
    """``err``, then what caused it (``__cause__``, else ``__context__``), and so on; each exception once. A
    library that re-raises an OSError or a KeyboardInterrupt as its own error keeps it in this chain."""
    seen: set[int] = set()
    link: BaseException | None = err
    while link is not None and id(link) not in seen:
        yield link
        seen.add(id(link))
        link = link.__cause__ or link.__context__


class HybridSplatError(Exception):
    """Base class of every error the toolkit raises on purpose.

    Parameters
    ----------
    problem:
        What is wrong, in words a user can act on (expected vs got, and how to fix it where known).
    path:
        The file or folder concerned, if any.
    """

    def __init__(self, problem: str, path: str | PathLike[str] | None = None) -> None:
        self.problem = problem
        self.path = Path(path) if path is not None else None
        super().__init__(self.one_line())

    def one_line(self) -> str:
        """The message as a single line: ``<path>: <problem>`` or just the problem."""
        text = " ".join(self.problem.split())
        return f"{self.path}: {text}" if self.path is not None else text


class InputFileError(HybridSplatError):
    """A file or folder that should be read is missing, unreadable, truncated or empty."""


class FormatError(HybridSplatError):
    """A file exists but its content does not follow the expected format (missing properties, bad header)."""


class DataError(HybridSplatError):
    """Values are invalid: NaN/inf coordinates, inconsistent array shapes, empty clouds where points are required."""


class ConfigError(HybridSplatError):
    """An option or configuration value is out of range or inconsistent."""


class ReconstructionError(HybridSplatError):
    """A reconstruction stage failed on valid input (images do not overlap, too few registered images)."""


class EmptyFusionError(ReconstructionError):
    """Depth-map fusion kept no point (every depth map empty or inconsistent). A tile of a tiled run where this
    happens (water, a textureless roof) contributes nothing instead of failing the run."""


class ProjectBusyError(HybridSplatError):
    """Another process holds the project's lock (``hybridsplat.project_lock``; exit code 3 on the command line)."""

    def __init__(self, problem: str, path: str | PathLike[str], holder: object = None) -> None:
        self.holder = holder
        super().__init__(problem, path)


class DiskSpaceError(HybridSplatError):
    """A stage would not fit on the disk (refused before it starts) or ran out of space while it wrote (exit code 4).

    needed / free: bytes (needed is None when the disk filled up during the stage)."""

    def __init__(self, problem: str, path: str | PathLike[str], needed: int | None = None, free: int = 0) -> None:
        self.needed, self.free = needed, free
        super().__init__(problem, path)


class FileSystemRefusedError(HybridSplatError):
    """The operating system refused a file operation during a stage: permission denied, read-only file system,
    too many open files (exit code 5). ``errno``: the OS error number."""

    def __init__(self, problem: str, path: str | PathLike[str] | None = None, errno: int | None = None) -> None:
        self.errno = errno
        super().__init__(problem, path)
