"""One writer at a time on a project folder: an OS file lock, with who holds it written beside it.

A command that writes a project (``run``, a per-stage command, ``measure``, the viewer's *Export*) holds an
exclusive ``flock`` on ``PROJECT/.hybridsplat.lock`` while it works; commands that only read it (``view``,
``info``, ``render``, ``export`` on a project's file, ``status``) take a shared lock while they read. The OS drops a
``flock`` when its process dies, however it dies, so a lock can never outlive its holder on a local file system.

Beside it, ``PROJECT/.hybridsplat.lock.json`` (written atomically) names the writer: pid, host, command, start time,
the stages it will run and the one running now. The writer deletes it when it releases the lock; if it is still
there when the next writer gets the OS lock, its writer died (SIGKILL, power loss): on this host that is checked
(the pid is gone, or now belongs to a process started later) and the lock is taken over with a message.

Network file systems: NFSv4 and Linux NFSv3 with ``lockd`` honour ``flock`` across hosts, but some (SMB mounts
with ``nobrl``, a few FUSE file systems, NFS with ``nolock``) accept it without locking anything. The holder
file is a second line of defence there: a writer that finds it naming a live process on this host, or any
process on another host, refuses (it cannot tell whether a process on another host is alive; if it is gone,
delete the ``.hybridsplat.lock.json`` the message names).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import shlex
import socket
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from os import PathLike
from pathlib import Path

from core.errors import ProjectBusyError
from hybridsplat.layout import ProjectLayout

LOCK_NAME = ProjectLayout(".").lock.name
HOLDER_NAME = ProjectLayout(".").lock_holder.name
PROJECT_MARKERS = (LOCK_NAME, ProjectLayout(".").manifest.name, ProjectLayout(".").config.name)
READER_WAIT_S = 10.0  # a writer waits this long for readers (they hold the lock only while they read)
_HELD: dict[Path, ProjectLock] = {}  # locks this process holds, by resolved project folder (re-entrant)


def _now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S")


def _process_start(pid: int) -> float | None:
    """When process ``pid`` started (seconds since the epoch), None when there is no such process."""
    import psutil

    try:
        return psutil.Process(pid).create_time()
    except (psutil.NoSuchProcess, psutil.ZombieProcess, psutil.AccessDenied):
        return None


@dataclass(frozen=True)
class LockHolder:
    """The process that holds (or held) a project's write lock.

    started / stage_started: local time ``YYYY-MM-DD HH:MM:SS``; process_started: the process's start time
    (seconds since the epoch), which tells a live holder from a new process that was given its pid.
    """

    pid: int
    host: str
    command: str
    started: str
    process_started: float
    stages: tuple[str, ...] = ()
    stage: str | None = None
    stage_started: str | None = None

    @classmethod
    def this_process(cls, command: str | None = None, stages: Sequence[str] = ()) -> LockHolder:
        pid = os.getpid()
        return cls(
            pid=pid,
            host=socket.gethostname(),
            command=command or shlex.join(["hybridsplat", *sys.argv[1:]]),
            started=_now(),
            process_started=_process_start(pid) or 0.0,
            stages=tuple(stages),
        )

    def is_alive(self) -> bool | None:
        """Whether the holder still runs: True / False on this host, None for a process on another host."""
        if self.host != socket.gethostname():
            return None
        start = _process_start(self.pid)
        return start is not None and abs(start - self.process_started) < 1.0

    def describe(self) -> str:
        """``'hybridsplat run ...' (pid 12, host h, since 2026-11-27 08:00:00; now at stage mvs, since ...)``."""
        where = f"pid {self.pid}, host {self.host}, since {self.started}"
        if self.stage:
            where += f"; now at stage {self.stage}, since {self.stage_started}"
        return f"'{self.command}' ({where})"


def read_holder(project: str | PathLike[str]) -> LockHolder | None:
    """The holder recorded in ``PROJECT/.hybridsplat.lock.json``; None when there is none (or it is unreadable)."""
    path = Path(project) / HOLDER_NAME
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        data["stages"] = tuple(data.get("stages", ()))
        return LockHolder(**data)
    except (OSError, ValueError, TypeError):
        return None


def enclosing_project(path: str | PathLike[str], levels: int = 4) -> Path | None:
    """The project folder that ``path`` is (or lies in, at most ``levels`` folders down), else None."""
    folder = Path(path).resolve()
    if not folder.is_dir():
        folder = folder.parent
    for candidate in [folder, *folder.parents][: levels + 1]:
        if any((candidate / marker).is_file() for marker in PROJECT_MARKERS):
            return candidate
    return None


@dataclass
class ProjectLock:
    """The lock of project folder ``root``: ``exclusive`` for a writer, shared for a reader (see the module doc).

    Use as a context manager, or :meth:`acquire` / :meth:`release`. ``command`` and ``stages`` describe a
    writer to the others (default: this process's command line). ``took_over``: the holder of a lock that a
    dead process left, when :meth:`acquire` took it over (the caller says so).
    """

    root: Path
    exclusive: bool = True
    command: str | None = None
    stages: Sequence[str] = ()
    took_over: LockHolder | None = None
    holder: LockHolder | None = None
    _fd: int | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.root = Path(self.root)

    @property
    def lock_path(self) -> Path:
        return self.root / LOCK_NAME

    @property
    def holder_path(self) -> Path:
        return self.root / HOLDER_NAME

    def acquire(self) -> ProjectLock:
        """Take the lock now, or raise :class:`ProjectBusyError` naming its holder.

        Within one process the lock is re-entrant: under a lock this process already holds on the project (an
        exclusive one, or a shared one for a reader), acquiring does nothing (a second ``flock`` from the same
        process would wait for itself)."""
        key = self.root.resolve()
        held = _HELD.get(key)
        if held is not None and (held.exclusive or not self.exclusive):
            self.holder = held.holder
            return self
        try:
            fd = self._open()
        except OSError as err:
            raise _refused(err) from err
        if fd is None:  # a reader of a folder where no lock can be created: nobody can write it through us
            return self
        try:
            self._lock(fd)
            self._check_previous_holder()
            if self.exclusive:
                self.holder = LockHolder.this_process(self.command, self.stages)
                self._write_holder(self.holder)
        except BaseException as err:
            os.close(fd)
            self._fd = None
            if isinstance(err, OSError):
                raise _refused(err) from err
            raise
        _HELD[key] = self
        return self

    def note_stage(self, stage: str) -> None:
        """Record the stage this writer starts now (``hybridsplat status`` shows it)."""
        owner = self if self._fd is not None else _HELD.get(self.root.resolve())
        if owner is not None and owner.exclusive and owner.holder is not None:
            owner.holder = replace(owner.holder, stage=stage, stage_started=_now())
            with contextlib.suppress(OSError):  # a full disk must not stop the run for a progress note
                owner._write_holder(owner.holder)

    def release(self) -> None:
        if self._fd is None:
            return
        _HELD.pop(self.root.resolve(), None)
        if self.exclusive:
            with contextlib.suppress(OSError):
                self.holder_path.unlink(missing_ok=True)
        fcntl.flock(self._fd, fcntl.LOCK_UN)
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> ProjectLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    # -- internals ----------------------------------------------------------------------------------
    def _open(self) -> int | None:
        """The lock file, open for writing where this user may (NFS needs that for an exclusive lock), else for
        reading (enough for flock on a local file system: a project another user made, a read-only mount)."""
        try:
            self._fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as err:
            if err.errno not in (errno.EACCES, errno.EPERM, errno.EROFS):
                raise
            try:
                self._fd = os.open(self.lock_path, os.O_RDONLY)
            except OSError:
                if self.exclusive:
                    raise err from None
                return None  # a reader of a folder with no lock file that it may not create: nobody writes it
        return self._fd

    def _lock(self, fd: int) -> None:
        mode = fcntl.LOCK_EX if self.exclusive else fcntl.LOCK_SH
        deadline = time.monotonic() + READER_WAIT_S
        while True:
            try:
                fcntl.flock(fd, mode | fcntl.LOCK_NB)
                return
            except BlockingIOError:
                holder = read_holder(self.root)
                if holder is None and time.monotonic() < deadline:
                    time.sleep(0.1)  # readers hold it briefly; a writer writes its name right after locking
                    continue
                raise self._busy(holder) from None

    def _check_previous_holder(self) -> None:
        previous = read_holder(self.root)
        if previous is None or previous.pid == os.getpid() and previous.host == socket.gethostname():
            return
        alive = previous.is_alive()
        if alive is False:
            if self.exclusive:
                self.took_over = previous
            return
        if alive is None:
            raise self._busy(
                previous,
                f"; the lock file was not locked, so the writer may be gone: if it is, delete {self.holder_path}",
            )
        raise self._busy(previous, " (this file system did not lock the project: a network file system?)")

    def _busy(self, holder: LockHolder | None, note: str = "") -> ProjectBusyError:
        if holder is None:
            who = "another hybridsplat command is reading it"
        else:
            who = f"{holder.describe()} is writing it"
        action = "wait for it to finish" if holder is not None else "try again when it is done"
        return ProjectBusyError(
            f"the project is busy: {who}{note}; {action} (see 'hybridsplat status {self.root}')", self.root, holder
        )

    def _write_holder(self, holder: LockHolder) -> None:
        """Write the holder file atomically; an OSError names the holder file (not its temporary)."""
        data = asdict(holder)
        data["stages"] = list(holder.stages)
        tmp = self.root / f"{HOLDER_NAME}.{os.getpid()}.tmp"
        try:
            tmp.write_text(json.dumps(data, indent=1), encoding="utf-8")
            os.replace(tmp, self.holder_path)
        except OSError as err:
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
            raise OSError(err.errno, err.strerror, str(self.holder_path)) from err


def _refused(err: OSError) -> Exception:
    """A refusal of the file system while taking the lock, in words (exit code 5), or ``err`` itself."""
    from core.errors import FileSystemRefusedError
    from hybridsplat.stage_failures import REFUSED_ERRNOS

    if err.errno not in REFUSED_ERRNOS:
        return err
    what = REFUSED_ERRNOS[err.errno]
    return FileSystemRefusedError(
        f"cannot take the project's write lock: {what} (is the project folder writable by this user?)",
        err.filename,
        errno=err.errno,
    )


@contextlib.contextmanager
def reading_project(path: str | PathLike[str]) -> Iterator[Path | None]:
    """A shared lock on the project ``path`` is (or lies in) while the block reads it; nothing when it is in none.

    Raises :class:`ProjectBusyError` when a writer holds it, so a reader never sees a half-written stage.
    """
    project = enclosing_project(path)
    if project is None:
        yield None
        return
    with ProjectLock(project, exclusive=False):
        yield project
