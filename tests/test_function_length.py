"""No function over 80 lines in the packages, bench/ and scripts/, numba kernels excepted (a kernel is kept whole:
splitting it costs calls in its inner loop)."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FOLDERS = ("core", "data_synth", "recon", "classify", "fusion", "eval", "hybridsplat", "bench", "scripts")
MAX_LINES = 80


def _is_kernel(node: ast.FunctionDef) -> bool:
    return any("njit" in ast.unparse(d) or "numba.jit" in ast.unparse(d) for d in node.decorator_list)


def test_no_function_is_over_80_lines_outside_numba_kernels():
    long = []
    for folder in FOLDERS:
        for path in sorted((REPO / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not _is_kernel(node):
                    lines = node.end_lineno - node.lineno + 1
                    if lines > MAX_LINES:
                        long.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, "split these functions:\n" + "\n".join(long)
