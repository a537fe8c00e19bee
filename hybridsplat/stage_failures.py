"""A stage's failure in the user's words: which stage, which file, and what the operating system said.

The runner passes every exception a stage raises through :func:`explain_failure` before it cleans up: a full disk
becomes :class:`~core.errors.DiskSpaceError` (exit code 4), a refusal of the operating system (permission denied,
read-only file system, too many open files) :class:`~core.errors.FileSystemRefusedError` (exit code 5), each
naming the stage and the file; everything else passes unchanged.
"""

from __future__ import annotations

import errno
from collections.abc import Sequence
from pathlib import Path

from core.errors import DiskSpaceError, FileSystemRefusedError
from hybridsplat.disk_space import (
    disk_full_behind,
    format_bytes,
    free_bytes,
    newest_file,
    os_error_behind,
    space_errno_behind,
)

REFUSED_ERRNOS = {
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.EMFILE: "too many open files in this process (raise 'ulimit -n')",
    errno.ENFILE: "too many open files on this system",
}
AFTER_FAILURE = "the stage's partial outputs were removed; the earlier stages are as they were"


def _file_of(err: OSError | None) -> str | None:
    if err is None or err.filename is None:
        return None
    return str(err.filename)


def explain_failure(stage: str, err: BaseException, root: Path, outputs: Sequence[Path]) -> BaseException | None:
    """The error to show for ``err``, raised by stage ``stage`` of the project at ``root`` (before its
    ``outputs`` are removed); None to show ``err`` itself (interruptions are never rewritten)."""
    if not isinstance(err, Exception) or isinstance(err, (DiskSpaceError, FileSystemRefusedError)):
        return None
    if disk_full_behind(err, root):
        file = _file_of(space_errno_behind(err)) or newest_file(outputs) or root
        free = free_bytes(root)
        return DiskSpaceError(
            f"stage {stage} ran out of disk space while writing ({format_bytes(free)} free now; "
            f"{type(err).__name__}: {err}); {AFTER_FAILURE}: free some space and run again",
            file,
            free=free,
        )
    refused = os_error_behind(err, REFUSED_ERRNOS)
    if refused is not None:
        what = REFUSED_ERRNOS[refused.errno]
        return FileSystemRefusedError(
            f"stage {stage}: {what} ({refused.strerror or refused}); {AFTER_FAILURE}",
            _file_of(refused) or newest_file(outputs) or root,
            errno=refused.errno,
        )
    return None
