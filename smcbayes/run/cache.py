"""The forward-run cache of a stage: what a killed stage already simulated, kept on disk.

Each model of a stage (the calibration's, the posterior's, the diagnosis's one per set of
effects) gets an append-only log ``<folder>/<tag>.jsonl``, ``tag`` a hash of the run's
identity, the model and the model's code (see
:meth:`smcbayes.run.directory.RunDir.forward_cache`), so a cache of another calibration,
model or model code is never read.  A line is either a batch marker ``{"batch": runs}``
written before a batch's runs start, or one forward run (one parameter row on one
configuration)::

    {"k": key, "c": config_id, "e": error, "f": force_mse_kN2, "d": displacement_mse_mm2,
     "s": status, "z": curves file or null, "i": row in it}

``key`` hashes the configuration id and the row's float64 bytes (free parameters, user
units): every random step of a stage is seeded, so a rerun asks for the very same rows
and finds them.  Curves (asked for by the curve batches: the calibration's design and
optimisation, the curve emulator's rounds, sensitivities, emulator check, bands,
diagnosis residuals) go to one ``.npz`` per task, written completely before its lines.
Lines are flushed as each task finishes and fsynced at the end of each batch, so a kill
loses at most the batch in flight.  Only successful rows are kept: a failure (possibly a
lost worker) is tried again by the next run.  A stage's cache may also read another's of
the same model, opened read only (``earlier``): the posterior reads the calibration's,
whose curves of the GP's points start the curve emulator.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.result import STATUS_OK, SimulationResult
from smcbayes.simulation.objective import TaskResult

Array = NDArray[np.float64]

MODEL_PACKAGES = ("forward", "data", "simulation")
"""Packages of ``smcbayes`` whose code decides a cached forward run's curves and errors."""

_CURVES = ("time_s", "gap_mm", "displacement_mm", "force_kN", "fill_fraction", "solid_fraction",
           "phase", "switch_time_s")


def cache_tag(identity: Mapping[str, Any], model: Sequence[str] = ()) -> str:
    """Hash of what makes forward runs comparable: the run's model identity (project,
    effects, overrides, fidelity, external simulator), a stage's extra effects ``model``,
    the package version, the source of the code that computes a run
    (:func:`model_source`) and the present contents of the files the external simulator
    depends on (its ``files``, :func:`file_digests`), so that a solver changed behind the
    same command line does not find its old runs."""
    try:
        version = metadata.version("smcbayes")
    except metadata.PackageNotFoundError:
        version = "unknown"
    key = {"identity": dict(identity), "model": list(model), "version": version, "source": model_source()}
    external = identity.get("external")
    files = external.get("files") if isinstance(external, Mapping) else None
    if files:
        key["external_files"] = file_digests(files)
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode("utf-8")).hexdigest()[:16]


def file_digests(paths: Sequence[str]) -> dict[str, str]:
    """SHA-256 of each file's contents, by its path as given; ``"missing"`` for a path that
    is not a file.  Read in blocks: a solver's study file may be large."""
    out: dict[str, str] = {}
    for name in paths:
        path = Path(name)
        if not path.is_file():
            out[name] = "missing"
            continue
        digest = hashlib.sha256()
        with path.open("rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
        out[name] = digest.hexdigest()
    return out


@functools.cache
def model_source() -> str:
    """Hash of this installation's sources of the forward model, the data and losses and
    the simulation layer (:data:`MODEL_PACKAGES`, :func:`source_digest`): a fixed or
    changed model must not read the runs its earlier code cached, although the package's
    version is still the same.  Read once, when this module is imported."""
    return source_digest(Path(__file__).resolve().parents[1])


def source_digest(root: Path) -> str:
    """SHA-256 of the ``.py`` files of :data:`MODEL_PACKAGES` under the package folder
    ``root`` (paths and contents); ``"unknown"`` where none is found (an installation
    without its sources, whose cache then goes by the version alone)."""
    digest = hashlib.sha256()
    found = False
    for package in MODEL_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode("utf-8"))
            digest.update(path.read_bytes())
            found = True
    return digest.hexdigest() if found else "unknown"


def row_key(config_id: str, row: Array) -> str:
    """Key of one forward run: the configuration and the exact float64 bytes of ``row`` ``(d,)``."""
    data = np.ascontiguousarray(row, dtype="<f8").tobytes()
    return hashlib.sha256(config_id.encode("utf-8") + b"\0" + data).hexdigest()[:32]


@dataclass(frozen=True)
class CacheStats:
    """What a cache file holds.

    Attributes:
        stored: forward runs kept (lines of runs).
        started: forward runs of all batches begun (sum of the batch markers); ``started -
            stored`` were lost in flight (or failed) and had to be made again.
        batches: batches begun.
    """

    stored: int
    started: int
    batches: int


class ForwardCache:
    """The cache of one model of a stage (module docstring).

    Args:
        folder: the stage's cache folder (created on the first write).
        tag: the identity hash of the run and model.
        earlier: another stage's cache of the same model (the same tag), read where this
            one lacks a run (the posterior reads the calibration's curves of the GP's
            points there); open it ``read_only``.
        read_only: never write, not even to cut off a line a kill left short (read up to it).

    Raises:
        ValueError: ``earlier`` belongs to another model.
    """

    def __init__(self, folder: Path, tag: str, earlier: ForwardCache | None = None,
                 read_only: bool = False) -> None:
        if earlier is not None and earlier.tag != tag:
            raise ValueError(f"the earlier cache {earlier.path} holds runs of another model than {tag}")
        self.folder = Path(folder)
        self.tag = tag
        self.earlier = earlier
        self.read_only = read_only
        self.path = self.folder / f"{tag}.jsonl"
        self._records: dict[str, dict[str, Any]] = {}
        self._npz: dict[str, dict[str, Any]] = {}
        self._fh: TextIO | None = None
        self._files = 0
        self._started = 0
        self._batches = 0
        self._stored = 0
        self._load()

    def __len__(self) -> int:
        return len(self._records)

    def _load(self) -> None:
        if not self.path.is_file():
            return
        raw = self.path.read_bytes()
        end = raw.rfind(b"\n") + 1
        # a line cut short by a kill: dropped so that appends start clean
        if end < len(raw) and not self.read_only:
            with self.path.open("r+b") as fh:
                fh.truncate(end)
        for line in raw[:end].decode("utf-8", errors="replace").splitlines():
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if not isinstance(rec, dict):
                continue
            if "batch" in rec:
                self._started += int(rec["batch"])
                self._batches += 1
            elif "k" in rec:
                self._records[rec["k"]] = rec
                self._stored += 1
        self._files = len(list(self.folder.glob(f"{self.tag}-*.npz")))

    def other_models(self) -> list[str]:
        """Tags of the runs of other models kept in this cache's folder (the other
        ``<tag>.jsonl`` files beside this one's): an earlier model code, project or
        external solver."""
        if not self.folder.is_dir():
            return []
        return sorted(p.stem for p in self.folder.glob("*.jsonl") if p != self.path)

    def stats(self) -> CacheStats:
        """Runs kept and runs begun, over every invocation that wrote this file."""
        return CacheStats(self._stored, self._started, self._batches)

    # -- the RunCache contract of smcbayes.simulation.runner --------------------------------
    def lookup(self, config_id: str, theta: Array, curves: bool) -> list[TaskResult | None]:
        """Per row of ``theta`` ``(P, d)``: its kept one-row result (here, or else in the
        ``earlier`` cache), or ``None`` when the row was never run (or ``curves`` are wanted
        and only its errors were kept)."""
        out: list[TaskResult | None] = []
        for row in np.atleast_2d(theta):
            rec = self._records.get(row_key(config_id, row))
            result = None
            if rec is not None and (not curves or rec.get("z")):
                result = self._result(rec, curves)
            if result is None and self.earlier is not None:
                result = self.earlier.lookup(config_id, row[None, :], curves)[0]
            out.append(result)
        return out

    def holds(self, config_ids: Sequence[str], theta: Array) -> NDArray[np.bool_]:
        """Per row of ``theta`` ``(P, d)``: whether its curves on every one of
        ``config_ids`` are kept here (or in the ``earlier`` cache), without reading them (a
        curves file is complete before its lines are written; one damaged since is held
        here, and :meth:`lookup` then finds nothing).  A row kept on some of them only is
        not held, though :meth:`lookup` finds those."""
        return np.array([all(self._kept(row_key(cid, row)) for cid in config_ids)
                         for row in np.atleast_2d(theta)], dtype=bool)

    def _kept(self, key: str) -> bool:
        rec = self._records.get(key)
        if rec is not None and rec.get("z") and (self.folder / rec["z"]).is_file():
            return True
        return self.earlier is not None and self.earlier._kept(key)

    def begin(self, runs: int) -> None:
        """Mark the start of a batch of ``runs`` forward runs."""
        self._write([{"batch": int(runs)}])
        self._started += int(runs)
        self._batches += 1

    def store(self, result: TaskResult, theta: Array) -> None:
        """Keep the successful rows of a finished task (``theta`` ``(n, d)``: its rows)."""
        good = [j for j, s in enumerate(result.status) if s == STATUS_OK]
        if not good:
            return
        name = None
        if result.curves is not None:
            name = f"{self.tag}-{self._files:06d}.npz"
            self._files += 1
            self._write_curves(name, result.curves)
        recs = [{"k": row_key(result.config_id, theta[j]), "c": result.config_id,
                 "e": float(result.error[j]), "f": float(result.force_mse_kN2[j]),
                 "d": float(result.displacement_mse_mm2[j]), "s": result.status[j],
                 "z": name, "i": j} for j in good]
        self._write(recs)
        for rec in recs:
            self._records[rec["k"]] = rec
        self._stored += len(recs)

    def commit(self) -> None:
        """fsync the log (end of a batch)."""
        if self._fh is not None:
            self._fh.flush()
            os.fsync(self._fh.fileno())

    def close(self) -> None:
        """Make the log durable and close it."""
        if self._fh is not None:
            self.commit()
            self._fh.close()
            self._fh = None

    # -- files ---------------------------------------------------------------------------
    def _write(self, recs: list[dict[str, Any]]) -> None:
        if self.read_only:
            raise ValueError(f"{self.path}: opened read only")
        if self._fh is None:
            self.folder.mkdir(parents=True, exist_ok=True)
            self._fh = self.path.open("a", encoding="utf-8")
        # one write per task: the lines reach the OS at once, so a killed process keeps them
        self._fh.write("".join(json.dumps(r) + "\n" for r in recs))
        self._fh.flush()

    def _write_curves(self, name: str, curves: SimulationResult) -> None:
        if self.read_only:
            raise ValueError(f"{self.path}: opened read only")
        self.folder.mkdir(parents=True, exist_ok=True)
        tmp = self.folder / f".{name}.tmp"
        arrays = {k: getattr(curves, k) for k in _CURVES}
        meta = json.dumps({"status": curves.status, "effects": list(curves.effects)})
        with tmp.open("wb") as fh:
            np.savez(fh, meta=np.array(meta), **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.folder / name)

    def _curves(self, name: str) -> dict[str, Any] | None:
        if name not in self._npz:
            try:
                with np.load(self.folder / name, allow_pickle=False) as data:
                    loaded = {k: data[k] for k in (*_CURVES, "meta")}
            except (OSError, ValueError, KeyError, zipfile.BadZipFile):
                return None
            if len(self._npz) > 64:  # curve batches are few: a small memory bound is enough
                self._npz.pop(next(iter(self._npz)))
            self._npz[name] = loaded
        return self._npz[name]

    def _result(self, rec: dict[str, Any], curves: bool) -> TaskResult | None:
        sim = None
        if curves:
            data = self._curves(rec["z"])
            if data is None:
                return None
            i = int(rec["i"])
            meta = json.loads(str(data["meta"]))
            sim = SimulationResult(rec["c"], *(np.array(data[k][i:i + 1]) for k in _CURVES),
                                   [meta["status"][i]], tuple(meta["effects"]))
        return TaskResult((0,), rec["c"], np.array([rec["e"]], dtype=float),
                          np.array([rec["f"]], dtype=float), np.array([rec["d"]], dtype=float),
                          [rec["s"]], 0.0, sim)


model_source()  # the code this process runs, before any later edit of its files
