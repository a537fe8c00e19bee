"""Write docs/cli.md, the command-line reference, from the command line itself (:mod:`hybridsplat.cli_reference`).

Usage, from the repository root: ``PYTHONPATH=$PWD .venv/bin/python scripts/gen_cli_reference.py [--check]``
(``--check``: write nothing, exit 1 when docs/cli.md is out of date).
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from core.io.atomic import atomic_path  # noqa: E402
from hybridsplat.cli_reference import render  # noqa: E402

TARGET = ROOT / "docs" / "cli.md"


def main(argv: list[str]) -> int:
    text = render()
    if "--check" in argv:
        current = TARGET.read_text(encoding="utf-8") if TARGET.is_file() else ""
        if current != text:
            print(f"{TARGET} is out of date: run scripts/gen_cli_reference.py", file=sys.stderr)
            return 1
        return 0
    with atomic_path(TARGET) as tmp:
        tmp.write_text(text, encoding="utf-8")
    print(f"wrote {TARGET}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
