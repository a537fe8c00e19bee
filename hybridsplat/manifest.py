"""The project manifest: what every stage did, and whether it must run again.

``PROJECT/manifest.json`` holds, per stage: the hashes of its inputs, its configuration, the package versions,
wall-clock seconds, peak resident memory, counts, its outputs, and whether it was skipped and why. Whether a
stage reruns is the runner's decision (``hybridsplat.runner``); this module stores the records.
"""

from __future__ import annotations

import hashlib
import json
import threading
from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import psutil

from core.errors import FormatError
from core.io.json_io import read_json, to_jsonable, write_json_atomic
from hybridsplat import __version__

if TYPE_CHECKING:
    from hybridsplat.records import TypedRecord

R = TypeVar("R", bound="TypedRecord")


@dataclass
class StageRecord:
    """One stage's entry in the manifest (seconds and peak_mb refer to the run that produced the outputs).

    config: the stage's options and fingerprint as plain JSON data; inputs: relative path -> SHA-256.
    cached: true when the last pipeline run found the stage up to date and did not run it.
    bytes_expected / bytes_written: the stage's estimate of what it would write (checked against the free disk
    space before it ran) and the size of its outputs afterwards.
    """

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
    bytes_expected: int = 0
    bytes_written: int = 0
    finished_at: str = ""

    def is_current(self, inputs: dict[str, str], config: dict[str, Any], project: Path) -> bool:
        """Whether a run with these inputs and configuration would reproduce this record's outputs."""
        return (
            not self.skipped
            and self.inputs == inputs
            and self.config == config
            and all((project / o).exists() for o in self.outputs)
        )

    def result(self, result_type: type[R], where: Path | None = None) -> R:
        """The counts as the stage's typed result (its ``Stage.Result``), read tolerantly
        (:meth:`hybridsplat.records.TypedRecord.from_json`); a :class:`FormatError` naming ``where`` (the manifest
        file) and the key when a value has the wrong type. Other code reads results through
        :func:`hybridsplat.project_io.stage_result`."""
        return result_type.from_json(self.counts, where, f"stages.{self.name}.counts")

    def content(self) -> dict[str, Any]:
        """The record without what changes when nothing ran (the cached flag and its reason), nor the byte counts
        (recorded since 0.3.1: leaving them out keeps the digests of earlier projects' records)."""
        data = asdict(self)
        for key in ("cached", "bytes_expected", "bytes_written"):
            data.pop(key)
        if not self.skipped:
            data.pop("reason")
        return data


class Manifest:
    """The stage records of one project, loaded from and saved to its manifest file (``ProjectLayout.manifest``)."""

    def __init__(self, path: str | PathLike[str]) -> None:
        self.path = Path(path)
        self.project = self.path.parent
        self.stages: dict[str, StageRecord] = {}
        if self.path.exists():
            payload = read_json(self.path)
            try:
                stages = payload.get("stages", {}).items()
                self.stages = {name: StageRecord(**{"name": name, **rec}) for name, rec in stages}
            except (AttributeError, TypeError) as err:
                raise FormatError(f"not a manifest of this version ({err}); delete it to rerun", self.path) from err

    def save(self) -> None:
        payload = {
            "version": __version__,
            "versions": package_versions(),
            "stages": {name: asdict(rec) for name, rec in self.stages.items()},
        }
        write_json_atomic(self.path, payload)

    def result(self, name: str, result_type: type[R]) -> R | None:
        """Stage ``name``'s typed result as recorded (see :meth:`StageRecord.result`); None when it has no record
        or was skipped."""
        record = self.stages.get(name)
        if record is None or record.skipped:
            return None
        return record.result(result_type, self.path)

    def relative(self, path: Path) -> str:
        """``path`` relative to the project (absolute when outside it), as recorded."""
        return str(_rel(path, self.project))

    def record(self, record: StageRecord) -> StageRecord:
        self.stages[record.name] = record
        self.save()
        return record

    def mark_cached(self, name: str) -> StageRecord:
        record = self.stages[name]
        record.cached, record.reason = True, "up to date: inputs and configuration unchanged"
        self.save()
        return record

    def invalidate(self, name: str) -> None:
        """Forget stage ``name`` (before it reruns: a failure must not leave a record of older outputs)."""
        if self.stages.pop(name, None) is not None:
            self.save()

    def content_digest(self, exclude: tuple[str, ...] = ()) -> str:
        """SHA-256 of every stage's record content (see :meth:`StageRecord.content`), except ``exclude``."""
        data = {n: r.content() for n, r in sorted(self.stages.items()) if n not in exclude}
        return hashlib.sha256(json.dumps(to_jsonable(data), sort_keys=True).encode()).hexdigest()


class PeakMemory:
    """Peak resident memory (MB) of this process while the block runs, sampled every 20 ms by a thread; with
    ``children``, of this process and all its descendants together (a local Ray instance's workers)."""

    def __init__(self, interval_s: float = 0.02, children: bool = False) -> None:
        self.interval_s = interval_s
        self.peak_mb = 0.0
        self.children = children
        self._stop = threading.Event()
        self._process = psutil.Process()

    def _rss_mb(self) -> float:
        rss = self._process.memory_info().rss
        if self.children:
            for child in self._process.children(recursive=True):
                try:
                    rss += child.memory_info().rss
                except psutil.Error:  # ended between the listing and the reading
                    pass
        return rss / 2**20

    def _sample(self) -> None:
        while not self._stop.is_set():
            self.peak_mb = max(self.peak_mb, self._rss_mb())
            self._stop.wait(self.interval_s)

    def __enter__(self) -> PeakMemory:
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.peak_mb = max(self.peak_mb, self._rss_mb())


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
