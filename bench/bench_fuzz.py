"""Time and peak memory of every malformed-input case of ``tests/fuzz`` through the CLI.

Each case runs ``python -m hybridsplat ...`` in a subprocess (60 s, 2 GB address space, as the tests).
Peak memory is the child's own peak RSS (``wait4``) minus the baseline: the peak RSS of
``hybridsplat --version``, which imports the same command modules. Targets: every case < 5 s and
< 500 MB above the baseline. Prints one row per case, then the verdict counts (clean, traceback,
silent success, output left behind, unclear) and the slowest and largest cases, with ``uptime``'s load.

Usage: ``PYTHONPATH=. python bench/bench_fuzz.py [--only GLOB] [--repeat-baseline 3]``
"""

from __future__ import annotations

import argparse
import fnmatch
import os
import shutil
import sys
import tempfile
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from fuzz.cases import all_cases  # noqa: E402
from fuzz.harness import run_case, run_cli  # noqa: E402

TARGET_S = 5.0
TARGET_MB = 500.0


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="*", help="run only the cases whose name matches this glob")
    parser.add_argument("--repeat-baseline", type=int, default=3)
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="bench_fuzz_"))
    try:
        base = [run_cli(["--version"], root) for _ in range(args.repeat_baseline)]
        base_s = min(b[3] for b in base)
        base_mb = max(b[4] for b in base)
        print(f"load average before: {load()}")
        print(f"baseline `hybridsplat --version`: {base_s:.2f} s, peak RSS {base_mb:.0f} MB")
        print(f"{'case':46s} {'verdict':9s} {'exit':>4s} {'s':>6s} {'s-base':>6s} {'MB':>6s} {'MB-base':>7s}")
        outcomes = []
        for case in all_cases():
            if not fnmatch.fnmatch(case.name, args.only):
                continue
            o = run_case(case, root / case.name)
            outcomes.append(o)
            print(
                f"{o.case:46s} {o.verdict:9s} {o.code if o.code is not None else 'kill':>4} {o.seconds:6.2f} "
                f"{o.seconds - base_s:6.2f} {o.peak_rss_mb:6.0f} {o.peak_rss_mb - base_mb:7.0f}",
                flush=True,
            )
        counts = Counter(o.verdict for o in outcomes)
        slowest = max(outcomes, key=lambda o: o.seconds)
        largest = max(outcomes, key=lambda o: o.peak_rss_mb)
        print(f"\nload average after: {load()}")
        print(
            f"cases {len(outcomes)}: clean {counts['clean']}, traceback {counts['traceback']}, "
            f"silent success {counts['silent']}, output left behind {counts['leftover']}, unclear {counts['unclear']}"
        )
        print(
            f"slowest: {slowest.case} {slowest.seconds:.2f} s ({slowest.seconds - base_s:.2f} s above the "
            f"{base_s:.2f} s start-up); largest: {largest.case} {largest.peak_rss_mb:.0f} MB "
            f"({largest.peak_rss_mb - base_mb:.0f} MB above baseline)"
        )
        over_s = [o.case for o in outcomes if o.seconds > TARGET_S]
        over_mb = [o.case for o in outcomes if o.peak_rss_mb - base_mb > TARGET_MB]
        print(f"over {TARGET_S:g} s (wall, start-up included): {len(over_s)}; over {TARGET_MB:g} MB above baseline: "
              f"{len(over_mb)} {over_mb}")  # fmt: skip
        bad = [o for o in outcomes if o.verdict != "clean"]
        for o in bad:
            print(f"\n--- {o.case}: {o.verdict}, exit {o.code}, leftovers {o.leftovers}\n{o.stderr.strip()[-800:]}")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
