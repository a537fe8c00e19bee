"""Measurements of products by content, so that an evaluation re-measures only what changed.

The eval stage measures every product each time it runs; after a retraining only the splats and the merged
product are new, yet the MVS cloud, the whole-scene baseline and its checkpoints took most of the time (about
two thirds of the stage on the benchmark's aerial scene). A product's measurement is a function of its files,
the evaluation's inputs (reference cloud, held-out views and their masks, LPIPS weights, τ) and the evaluation
code, so it is stored under the SHA-256 of all of these and restored when the key comes back.

An entry ``ROOT/<key>/`` holds ``entry.json`` (the product's ``metrics.json`` entry and its per-material table)
and ``files/``: what the measurement wrote into the eval folder (distance clouds, plots, render panels), under
the same relative paths, which the entry's ``files`` fields name. Entries are written to a temporary folder and
renamed, so an interrupted store leaves no half entry. The key covers the evaluation's source files
(``eval/`` and the renderer ``fusion/render/``; the caller adds the library versions to the settings): a changed
metric or renderer never restores an old figure.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import uuid
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from core.errors import HybridSplatError
from core.io.json_io import read_json, write_json_atomic

ENTRY = "entry.json"


def code_digest() -> str:
    """SHA-256 of the evaluation's and the renderer's source files."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for folder in (root / "eval", root / "fusion" / "render"):
        for path in sorted(folder.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def files_in(folder: Path) -> dict[str, int]:
    """Relative path → modification time (ns) of every file under ``folder`` (empty when it does not exist)."""
    if not folder.is_dir():
        return {}
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


@dataclass(frozen=True)
class StoredMeasurement:
    """A restored entry: the files it copied back into the eval folder (paths relative to it), the product's
    ``metrics.json`` entry and its per-material table as stored (the eval stage's; None without)."""

    files: tuple[str, ...]
    metrics: dict[str, Any]
    per_material: Any


class ProductCache:
    """Stored measurements under ``root``, keyed by :meth:`key`.

    settings: what every product's measurement depends on besides its own files and the evaluation's code (hashes
    of the reference cloud, held-out views, masks and weights; τ; library versions), JSON-serialisable."""

    def __init__(self, root: Path, settings: Mapping[str, Any]) -> None:
        self.root = Path(root)
        self._salt = json.dumps({"settings": settings, "code": code_digest()}, sort_keys=True, default=str)

    def key(self, name: str, file_hashes: Iterable[str]) -> str:
        """The key of product ``name`` made of files with these content hashes (in a fixed order)."""
        digest = hashlib.sha256(self._salt.encode())
        digest.update(json.dumps([name, list(file_hashes)]).encode())
        return digest.hexdigest()

    def restore(self, key: str, eval_dir: Path) -> StoredMeasurement | None:
        """Copy entry ``key``'s files into ``eval_dir`` and return what it holds, or None when there is no complete
        entry."""
        entry = self.root / key
        if not (entry / ENTRY).is_file():
            return None
        try:
            content = read_json(entry / ENTRY)
            if not (isinstance(content, dict) and {"files", "metrics", "per_material"} <= content.keys()):
                return None
            files, metrics = content["files"], content["metrics"]
            if not (isinstance(files, list) and all(isinstance(f, str) for f in files) and isinstance(metrics, dict)):
                return None
            for rel in files:
                target = eval_dir / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(entry / "files" / rel, target)
        except (HybridSplatError, OSError, TypeError):
            return None  # a damaged entry (edited, truncated, files deleted) is measured again, then replaced
        return StoredMeasurement(tuple(files), metrics, content["per_material"])

    def store(
        self, key: str, eval_dir: Path, written: Iterable[str], metrics: Mapping[str, Any], per_material: Any
    ) -> None:
        """Store a product's measurement: its metrics entry, its per-material table (or None) and the files it
        wrote into ``eval_dir`` (paths relative to it)."""
        entry = self.root / key
        staging = self.root / f".{key}.{uuid.uuid4().hex}"
        rels = sorted(written)
        for rel in rels:
            target = staging / "files" / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(eval_dir / rel, target)
        write_json_atomic(staging / ENTRY, {"files": rels, "metrics": metrics, "per_material": per_material})
        shutil.rmtree(entry, ignore_errors=True)
        staging.rename(entry)
