"""Compile the numba kernels once, at install time: the tiny synthetic scene through every stage (with the baseline).

Every kernel is ``@njit(cache=True)``, so numba writes its machine code beside the sources (``__pycache__``) and the
next process loads it instead of compiling: a fresh clone's first ``make demo`` or ``make test`` then runs its
stages as fast as a second run does. Run by ``scripts/bootstrap.sh`` after an install; about a minute on 2 cores.
Nothing is kept but the caches: the scene and the project go to a temporary folder.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    cli = [sys.executable, "-m", "hybridsplat"]
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="hybridsplat-warm-") as tmp:
        scene, project = Path(tmp) / "scene", Path(tmp) / "project"
        for args in (["synth", "--out", str(scene), "--preset", "tiny"],
                     ["run", str(scene), "--out", str(project), "--baseline", "--quiet"]):  # fmt: skip
            done = subprocess.run(cli + args, capture_output=True, text=True)
            if done.returncode != 0:
                tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
                print(f"warm_kernels: 'hybridsplat {args[0]}' failed: {tail[0]}", file=sys.stderr)
                return done.returncode
    print(f"warm_kernels: numba kernels compiled and cached in {time.perf_counter() - start:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
