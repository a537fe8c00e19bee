"""Run one fuzz case: the CLI in a subprocess under a time limit and an address-space limit, then judge it.

Judgement of a malformed-input case (:func:`judge`):

- ``clean``: the expected exit status (2), one short stderr line ``hybridsplat: error: ...`` naming the
  file, no traceback, and none of the case's outputs left behind;
- ``traceback``: a Python traceback (or an "internal error" line) on stderr;
- ``silent``: exit status 0 on garbage;
- ``leftover``: an output exists afterwards;
- ``unclear``: anything else (wrong status, several lines, the file not named, killed by a limit).
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

from fuzz.cases import FuzzCase, Invocation

TIME_LIMIT_S = 60
ADDRESS_SPACE_BYTES = 2 * 1024**3
MAX_LINE = 300
#: The checkout whose CLI runs; HYBRIDSPLAT_FUZZ_REPO points the suite at another one (e.g. to show that a
#: case fails on an older main).
REPO = Path(os.environ.get("HYBRIDSPLAT_FUZZ_REPO") or Path(__file__).resolve().parents[2])
#: Heavy libraries whose import :func:`heavy_imports` reports (a bad input should be refused before them).
HEAVY = ("torch", "open3d", "numba", "sklearn", "pycolmap", "cv2")

#: ``python -c`` program equal to ``python -m hybridsplat ARGS`` that also writes, when the interpreter exits,
#: JSON ``{"modules": sorted names in sys.modules, "vm_hwm_kb": VmHWM of /proc/self/status}`` to the file
#: named by $HYBRIDSPLAT_MODULES_OUT. VmHWM is the peak RSS of the process's own address space: unlike
#: ``wait4``'s ``ru_maxrss`` it does not count the copy of the (possibly large) parent made by ``fork``.
MODULE_RECORDER = textwrap.dedent(
    """
    import atexit, json, os, runpy, sys

    def _record():
        hwm = None
        try:
            with open("/proc/self/status") as status:
                hwm = next((int(line.split()[1]) for line in status if line.startswith("VmHWM:")), None)
        except OSError:
            pass
        with open(os.environ["HYBRIDSPLAT_MODULES_OUT"], "w") as f:
            json.dump({"modules": sorted(sys.modules), "vm_hwm_kb": hwm}, f)

    atexit.register(_record)
    sys.argv[0] = "hybridsplat"
    runpy.run_module("hybridsplat", run_name="__main__", alter_sys=True)
    """
)


@dataclass(frozen=True)
class Outcome:
    """What one run of the CLI did. ``peak_rss_mb``: the child's peak resident memory (getrusage)."""

    case: str
    code: int | None
    stderr: str
    seconds: float
    peak_rss_mb: float  # VmHWM when the run was recorded (see MODULE_RECORDER), else wait4's ru_maxrss
    leftovers: tuple[str, ...]
    verdict: str
    invocation: Invocation
    modules: frozenset[str] | None = None  # names in sys.modules at exit, when recorded


def heavy_imports(modules: frozenset[str] | set[str]) -> list[str]:
    """The :data:`HEAVY` libraries among ``modules`` (top-level package names), in :data:`HEAVY` order."""
    tops = {name.split(".")[0] for name in modules}
    return [lib for lib in HEAVY if lib in tops]


def _read_record(record: Path) -> dict:
    try:
        data = json.loads(record.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def read_modules(record: Path) -> frozenset[str] | None:
    """The module names written by :data:`MODULE_RECORDER`, or None when nothing was written."""
    modules = _read_record(record).get("modules")
    return frozenset(modules) if isinstance(modules, list) else None


def _limits() -> None:  # runs in the child between fork and exec
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_BYTES, ADDRESS_SPACE_BYTES))


def run_cli(
    argv: list[str], cwd: Path, timeout: float = TIME_LIMIT_S, record_modules: Path | None = None
) -> tuple[int | None, str, str, float, float]:
    """(exit status, or None when killed at the time limit; stdout; stderr; seconds; the child's peak RSS in MiB).

    The child is reaped with ``os.wait4`` so that its peak resident memory is known. With ``record_modules``,
    the CLI runs through :data:`MODULE_RECORDER`, which writes the imported module names there at exit (read
    them with :func:`read_modules`), and the peak is the child's own VmHWM when it recorded one.
    """
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"}
    env.pop("HYBRIDSPLAT_LPIPS_WEIGHTS", None)
    program = ["-m", "hybridsplat"]
    if record_modules is not None:
        record_modules.unlink(missing_ok=True)
        env["HYBRIDSPLAT_MODULES_OUT"] = str(record_modules)
        program = ["-c", MODULE_RECORDER]
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        start = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, *program, *map(str, argv)],
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=err,
            preexec_fn=_limits,
        )
        code: int | None = None
        peak = float("nan")
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid == proc.pid:
                code = os.waitstatus_to_exitcode(status)
                peak = usage.ru_maxrss / 1024
                break
            if time.perf_counter() - start > timeout:
                proc.kill()
                _pid, _status, usage = os.wait4(proc.pid, 0)
                peak = usage.ru_maxrss / 1024
                break
            time.sleep(0.01)
        proc.returncode = -1 if code is None else code  # reaped here; keep Popen from waiting again
        if record_modules is not None and isinstance(hwm := _read_record(record_modules).get("vm_hwm_kb"), int):
            peak = hwm / 1024
        seconds = time.perf_counter() - start
        out.seek(0)
        err.seek(0)
        return code, out.read(), err.read(), seconds, peak


def judge(code: int | None, stderr: str, leftovers: list[str], inv: Invocation) -> str:
    lines = [line for line in stderr.strip().splitlines() if line.strip()]
    if "Traceback" in stderr or "internal error" in stderr:
        return "traceback"
    if code == 0 and inv.expect_code != 0:
        return "silent"
    if leftovers:
        return "leftover"
    if code != inv.expect_code:
        return "unclear"
    errors = [line for line in lines if line.startswith("hybridsplat: error:")]
    if len(errors) != 1 or len(errors[0]) > MAX_LINE or inv.culprit not in errors[0]:
        return "unclear"
    others = [line for line in lines if not line.startswith(("hybridsplat: error:", "Usage:"))]
    if others:
        return "unclear"
    return "clean"


def run_case(case: FuzzCase, folder: Path, timeout: float = TIME_LIMIT_S, record_modules: bool = False) -> Outcome:
    """Build ``case`` in ``folder``, run it and judge it (``record_modules``: also record the imported modules)."""
    folder.mkdir(parents=True, exist_ok=True)
    inv = case.build(folder)
    record = folder.parent / f".{folder.name}.modules.json" if record_modules else None
    code, _out, err, seconds, peak = run_cli(inv.argv, folder, timeout, record)
    modules = read_modules(record) if record is not None else None
    if record is not None:
        record.unlink(missing_ok=True)
    leftovers = [str(p) for p in inv.outputs if p.exists() and not (p.is_dir() and not any(p.iterdir()))]
    leftovers += [str(p) for p in folder.rglob(".*.tmp*")]  # temporary files of atomic writes
    verdict = judge(code, err, leftovers, inv)
    return Outcome(case.name, code, err, seconds, peak, tuple(leftovers), verdict, inv, modules)
