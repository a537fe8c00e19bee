"""The project manifest: what every stage did, and whether it must run again.

``PROJECT/manifest.json`` holds, per stage: the hashes of its inputs, its configuration, the package versions,
wall-clock seconds, peak resident memory, counts, its outputs, and whether it was skipped and why. A stage is
skipped on re-run ("up to date") when its inputs' hashes and configuration are unchanged and its outputs
still exist; a stage the scene does not need is skipped with a reason of its own.
"""

from __future__ import annotations

import hashlib
import json
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import psutil

from core.errors import FormatError
from core.io.atomic import write_text_atomic
from hybridsplat import __version__

MANIFEST_NAME = "manifest.json"


@dataclass
class StageOutcome:
    """What a stage function returns: counts to record, or a skip with its reason."""

    counts: dict[str, Any] = field(default_factory=dict)
    skipped: bool = False
    reason: str | None = None


@dataclass
class StageRecord:
    """One stage's entry in the manifest (seconds and peak_mb refer to the run that produced the outputs)."""

    name: str
    seconds: float = 0.0
    peak_mb: float = 0.0
    skipped: bool = False
    reason: str | None = None
    cached: bool = False
    counts: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    inputs: dict[str, str] = field(default_factory=dict)
    outputs: list[str] = field(default_factory=list)
    finished_at: str = ""


class Manifest:
    """The stages of one project folder, loaded from and saved to ``PROJECT/manifest.json``."""

    def __init__(self, project: str | PathLike[str]) -> None:
        self.project = Path(project)
        self.path = self.project / MANIFEST_NAME
        self.stages: dict[str, StageRecord] = {}
        if self.path.exists():
            try:
                payload = json.loads(self.path.read_text(encoding="utf-8"))
                self.stages = {name: StageRecord(**rec) for name, rec in payload.get("stages", {}).items()}
            except (ValueError, TypeError) as err:
                raise FormatError(
                    f"manifest is not valid JSON of this version ({err}); delete it to rerun", self.path
                ) from err

    def save(self) -> None:
        payload = {
            "version": __version__,
            "versions": package_versions(),
            "stages": {name: asdict(rec) for name, rec in self.stages.items()},
        }
        self.project.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.path, json.dumps(payload, indent=2, default=_json_default) + "\n")

    def run_stage(
        self,
        name: str,
        fn: Callable[[], StageOutcome],
        *,
        inputs: Iterable[Path],
        outputs: Iterable[Path],
        config: dict[str, Any] | None = None,
        force: bool = False,
    ) -> StageRecord:
        """Run ``fn`` unless the recorded run is still valid; record timings, memory and counts; save."""
        config = json.loads(json.dumps(config or {}, default=_json_default))
        input_hashes = {str(_rel(p, self.project)): hash_path(p) for p in inputs}
        output_list = [str(_rel(p, self.project)) for p in outputs]
        previous = self.stages.get(name)
        if (
            not force
            and previous is not None
            and not previous.skipped
            and previous.inputs == input_hashes
            and previous.config == config
            and all((self.project / o).exists() for o in previous.outputs)
        ):
            previous.cached = True
            previous.reason = "up to date: inputs and configuration unchanged"
            self.save()
            return previous

        with PeakMemory() as memory:
            start = time.perf_counter()
            outcome = fn()
            seconds = time.perf_counter() - start
        record = StageRecord(
            name=name,
            seconds=round(seconds, 4),
            peak_mb=round(memory.peak_mb, 1),
            skipped=outcome.skipped,
            reason=outcome.reason,
            counts=outcome.counts,
            config=config,
            inputs=input_hashes,
            outputs=output_list if not outcome.skipped else [],
            finished_at=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        )
        self.stages[name] = record
        self.save()
        return record


class PeakMemory:
    """Peak resident memory (MB) of this process while the block runs, sampled every 20 ms by a thread."""

    def __init__(self, interval_s: float = 0.02) -> None:
        self.interval_s = interval_s
        self.peak_mb = 0.0
        self._stop = threading.Event()
        self._process = psutil.Process()

    def _sample(self) -> None:
        while not self._stop.is_set():
            self.peak_mb = max(self.peak_mb, self._process.memory_info().rss / 2**20)
            self._stop.wait(self.interval_s)

    def __enter__(self) -> PeakMemory:
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.peak_mb = max(self.peak_mb, self._process.memory_info().rss / 2**20)


def hash_path(path: str | PathLike[str], chunk: int = 1 << 20) -> str:
    """SHA-256 of a file's content or of a folder's files (names and contents, sorted); 'missing' if absent."""
    path = Path(path)
    digest = hashlib.sha256()
    if path.is_file():
        files = [path]
    elif path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.is_file() and not p.name.startswith("."))
    else:
        return "missing"
    for file in files:
        if path.is_dir():
            digest.update(str(file.relative_to(path)).encode())
        with file.open("rb") as f:
            while block := f.read(chunk):
                digest.update(block)
    return digest.hexdigest()


def package_versions() -> dict[str, str]:
    """Versions of the libraries whose behaviour shapes the results."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"hybridsplat": __version__}
    for name in ("numpy", "scipy", "torch", "pycolmap", "open3d", "numba", "scikit-learn", "plyfile", "laspy"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            continue
    return out


def _rel(path: Path, root: Path) -> Path:
    try:
        return Path(path).resolve().relative_to(root.resolve())
    except ValueError:
        return Path(path).resolve()


def _json_default(value: object) -> object:
    if isinstance(value, PathLike):
        return str(value)
    if hasattr(value, "tolist"):
        return value.tolist()  # numpy scalars and arrays
    if hasattr(value, "value"):
        return value.value  # enums
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
