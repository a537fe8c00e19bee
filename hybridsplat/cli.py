"""The ``hybridsplat`` command line.

Errors the toolkit raises on purpose (:class:`core.errors.HybridSplatError`) become one line on stderr
and exit code 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import pkgutil
import signal
import sys
import threading

import typer

import hybridsplat.commands
from core.errors import HybridSplatError
from hybridsplat import __version__

_state = {"debug": False}


def _version(value: bool) -> None:
    if value:
        typer.echo(f"hybridsplat {__version__}")
        raise typer.Exit()


def _root(
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks instead of one-line errors."),
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    _state["debug"] = debug


def build_app() -> typer.Typer:
    """The command line: every module of :mod:`hybridsplat.commands` registers its commands (the per-stage ones
    come from the registered stages' declarations, :mod:`hybridsplat.commands.stages`)."""
    app = typer.Typer(
        name="hybridsplat",
        help="Photogrammetry + Gaussian splatting for surveys: reconstruct, classify, fuse, export, evaluate.",
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
    )
    app.callback()(_root)
    for info in sorted(pkgutil.iter_modules(hybridsplat.commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"hybridsplat.commands.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(app)
    return app


try:
    app = build_app()
except KeyboardInterrupt:  # Ctrl-C while the (heavy) command modules are imported: same exit as later
    print("hybridsplat: interrupted", file=sys.stderr)
    sys.exit(130)


class Terminated(BaseException):
    """Raised in the main thread when the process receives SIGTERM.

    A ``BaseException`` (like ``KeyboardInterrupt``) so that ``except Exception`` blocks do not swallow it,
    while ``finally`` blocks and context managers (atomic writes, the pipeline's cleanup) still run.
    """


EXIT_OK, EXIT_INTERNAL, EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143
EXIT_BUSY, EXIT_DISK_SPACE, EXIT_REFUSED = 3, 4, 5
"""3: another process holds the project's lock; 4: not enough disk space (before a stage, or the disk filled up
during it); 5: the operating system refused a file operation (permission denied, read-only file system, too
many open files)."""


def _exit_code_of(err: HybridSplatError) -> int:
    from core.errors import DiskSpaceError, FileSystemRefusedError, ProjectBusyError

    for kind, code in ((ProjectBusyError, EXIT_BUSY), (DiskSpaceError, EXIT_DISK_SPACE)):
        if isinstance(err, kind):
            return code
    return EXIT_REFUSED if isinstance(err, FileSystemRefusedError) else EXIT_BAD_INPUT


def _os_error_code(err: OSError) -> int:
    """Exit status of an OSError outside a stage: full disk 4, refused by the system 5, else bad input when it
    names a file (an unwritable output, a folder where a file is expected), internal otherwise."""
    from hybridsplat.disk_space import SPACE_ERRNOS
    from hybridsplat.stage_failures import REFUSED_ERRNOS

    if err.errno in SPACE_ERRNOS:
        return EXIT_DISK_SPACE
    if err.errno in REFUSED_ERRNOS:
        return EXIT_REFUSED
    return EXIT_BAD_INPUT if err.filename is not None else EXIT_INTERNAL


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated()


def _error(text: str) -> None:
    print(f"hybridsplat: error: {' '.join(str(text).split())}", file=sys.stderr)


def _os_error_line(err: OSError) -> str:
    """``<file>: <problem>`` for an OSError (permission denied, is a directory, read-only file system...)."""
    problem = err.strerror or str(err) or type(err).__name__
    if err.filename is not None:
        return f"{err.filename}: {problem}"
    return problem


def run_cli(argv: list[str] | None = None, cli: typer.Typer | None = None) -> int:
    """Run the command line and return its exit status (never raises, except with ``--debug``).

    Exit statuses: 0 success; 2 bad input or usage (one line ``hybridsplat: error: <file>: <problem>``,
    or a usage line and the error); 1 internal error (one line naming the exception; ``--debug`` shows the
    traceback); 3 project busy, 4 disk space, 5 refused by the operating system (one line naming the file, and
    the stage when one ran); 130 Ctrl-C ("interrupted"); 143 SIGTERM ("terminated"). ``cli``: an app of
    :func:`build_app` (default: the one built at import). SIGTERM is converted into the
    :class:`Terminated` exception while the command runs, so ``finally`` blocks run as on Ctrl-C.
    """
    from typer._click import exceptions as click_exc

    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        try:
            rv = (cli or app)(args=args, prog_name="hybridsplat", standalone_mode=False)
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
        code = rv if isinstance(rv, int) and not isinstance(rv, bool) else EXIT_OK
        if code == EXIT_INTERRUPTED:  # typer turns KeyboardInterrupt into Exit(130) and returns the code
            print("hybridsplat: interrupted", file=sys.stderr)
        return code
    except HybridSplatError as err:
        if debug:
            raise
        _error(err.one_line())
        return _exit_code_of(err)
    except click_exc.NoArgsIsHelpError as err:
        err.show()
        return EXIT_BAD_INPUT
    except click_exc.UsageError as err:
        if err.ctx is not None:
            print(err.ctx.get_usage(), file=sys.stderr)
        hint = f" (see '{err.ctx.command_path} --help')" if err.ctx is not None else ""
        _error(err.format_message() + hint)
        return EXIT_BAD_INPUT
    except click_exc.ClickException as err:
        _error(err.format_message())
        return EXIT_BAD_INPUT
    except typer.Exit as ex:
        return int(ex.exit_code)
    except (typer.Abort, KeyboardInterrupt) as err:
        if isinstance(err.__cause__, EOFError):  # typer turns an uncaught EOFError into Abort
            if debug:
                raise
            _error(f"internal error: unexpected end of data (EOFError: {err.__cause__})")
            return EXIT_INTERNAL
        print("hybridsplat: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Terminated:
        print("hybridsplat: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    except OSError as err:  # the file system refused: unwritable output, a folder where a file is expected...
        if debug:
            raise
        _error(_os_error_line(err))
        return _os_error_code(err)
    except MemoryError:
        if debug:
            raise
        _error("out of memory (an input may declare far more data than it holds; run with --debug for details)")
        return EXIT_INTERNAL
    except Exception as err:
        signalled = _signal_behind(err)
        if signalled is not None:  # Ctrl-C or SIGTERM inside compiled code, reported by it as its own error
            if isinstance(signalled, Terminated):
                print("hybridsplat: terminated", file=sys.stderr)
                return EXIT_TERMINATED
            print("hybridsplat: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        if debug:
            raise
        _error(f"internal error: {type(err).__name__}: {err} (run with --debug for the traceback)")
        return EXIT_INTERNAL


def _signal_behind(err: BaseException) -> BaseException | None:
    """The KeyboardInterrupt or :class:`Terminated` that caused ``err``, if any. A signal that arrives while a numba
    kernel runs surfaces as ``SystemError: CPUDispatcher(...) returned a result with an exception set`` whose cause
    is the KeyboardInterrupt."""
    from core.errors import exception_chain

    return next((e for e in exception_chain(err) if isinstance(e, (KeyboardInterrupt, Terminated))), None)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script: runs :func:`run_cli` and exits with its status (returns on 0).

    After Ctrl-C or SIGTERM (every ``finally`` block has run by then) the process ends at once with
    ``os._exit``: worker threads a library left behind (a thread pool woken in the middle of starting a
    worker) would otherwise keep the interpreter from exiting — seen once in ten interrupted ``run``s.
    """
    code = run_cli(argv)
    if code in (EXIT_INTERRUPTED, EXIT_TERMINATED):
        _exit_now(code)
    if code != EXIT_OK:
        sys.exit(code)


def _exit_now(code: int) -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def entry() -> None:
    """The process entry point (console script and ``python -m hybridsplat``): :func:`main`, then exit.

    Once the command is over, Ctrl-C and SIGTERM are ignored while the interpreter shuts down, so that a
    signal arriving after a completed command cannot turn its exit status into a crash (-2).
    """
    try:
        code = run_cli()
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
    except KeyboardInterrupt:  # in the instant between the command's end and the lines above
        print("hybridsplat: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED
    if code in (EXIT_INTERRUPTED, EXIT_TERMINATED):
        _exit_now(code)
    sys.exit(code)
