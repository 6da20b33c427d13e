"""The run directory: the one contract between the stages.

Only this module knows the names of the files in ``RUN_DIR``; every stage reads and
writes them through :class:`RunDir`.  Layout::

    config.json          identity: resolved project, effects, fixed values, solver
                         fidelity, external simulator, calibration settings
    evaluations.jsonl    append-only evaluation log of the calibration (runlog)
    summary.json         calibration summary (``stop_reason`` "running" while it runs)
    best_params.json     best parameter values with units (and which are fixed)
    gp.pt                GP state of the calibration
    best_curves/<id>.csv simulated curves at the best point, every configuration
    commands.jsonl       the command lines that made the run, one per stage run
    truth-data/          synthetic measured curves of a check with known truth
    work/                work folders of the external simulator
    posterior/           the posterior stage: status.json, summary.json, outputs
                         (bands/<id>.csv: the predictive bands and mean)
    diagnose/            the diagnosis stage (default folder): status.json, summary.json

A stage folder's ``status.json`` says ``running`` from the stage's start until its
summary is written, then ``complete``: a folder left ``running`` by a killed process reads
as ``interrupted``.
"""

from __future__ import annotations

import datetime as dt
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import CalibrationSpec, ProjectConfig, override
from smcbayes.errors import ConfigError, RunDirError
from smcbayes.run.cache import ForwardCache, cache_tag, file_digests
from smcbayes.run.runlog import LOG_NAME, RunLog, write_json
from smcbayes.simulation.problem import ExternalSpec, Problem, build_problem

StageState = Literal["absent", "running", "interrupted", "complete"]

IDENTITY_KEYS = ("project", "effects", "overrides", "fidelity", "external", "seed", "init",
                 "batch", "kernel", "failed", "restarts", "raw_samples", "noise",
                 "local_evaluations", "local_radius", "patience", "retries")
"""Settings that must match for ``--resume`` (the budget, tolerance and local search may change)."""

RESUME_CHANGES = ("budget", "tolerance", "polish")
"""The calibration settings a resumed run may change; the others are the run's own."""

_MODEL_KEYS = ("project", "effects", "overrides", "fidelity", "external")


def read_json(path: Path) -> Any:
    """Parsed JSON of ``path``, or ``None`` when missing or unreadable."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


@dataclass(frozen=True)
class RunIdentity:
    """What defines a calibration run (``config.json``).

    Attributes:
        project: the resolved project (validated :class:`ProjectConfig` as JSON).
        effects: effects switched on (``None``: the project's own list).
        overrides: fixed parameter values given on the command line (user units).
        fidelity: ``"1d"``, ``"2d"`` or ``None`` (the project's solver setting).
        external: the external simulator (command, timeout_s, output_format and, when
            given, the absolute paths of the ``files`` its results depend on) or ``None``.
        settings: the calibration settings.
    """

    project: dict[str, Any]
    effects: list[str] | None
    overrides: dict[str, float]
    fidelity: str | None
    external: dict[str, Any] | None
    settings: dict[str, Any]

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RunIdentity:
        """From the flat ``config.json`` layout."""
        return cls(dict(data["project"]), data.get("effects"), dict(data.get("overrides") or {}),
                   data.get("fidelity"), data.get("external"),
                   {k: v for k, v in data.items() if k not in _MODEL_KEYS})

    def to_json(self) -> dict[str, Any]:
        """The flat ``config.json`` layout (JSON-safe)."""
        out = {"project": self.project, "effects": self.effects, "overrides": self.overrides,
               "fidelity": self.fidelity, "external": self.external, **self.settings}
        return json.loads(json.dumps(out, default=str))

    def project_config(self) -> ProjectConfig:
        """The validated project."""
        return ProjectConfig.model_validate(self.project)


class RunDir:
    """A run directory (see the module docstring for its layout).

    Args:
        root: the directory (need not exist yet).
    """

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)

    def __repr__(self) -> str:
        return f"RunDir({str(self.root)!r})"

    # -- paths ---------------------------------------------------------------------------
    @property
    def log_path(self) -> Path:
        """``evaluations.jsonl``."""
        return self.root / LOG_NAME

    @property
    def gp_path(self) -> Path:
        """``gp.pt``: the calibration's GP state."""
        return self.root / "gp.pt"

    @property
    def figures(self) -> Path:
        """The calibration's figure folder."""
        return self.root / "figures"

    def stage_dir(self, stage: str, folder: Path | None = None) -> Path:
        """Folder of a later stage (``posterior``, ``diagnose``), or ``folder`` if given."""
        return Path(folder) if folder is not None else self.root / stage

    # -- identity ------------------------------------------------------------------------
    def is_run(self) -> bool:
        """Whether the directory holds a calibration (its identity file)."""
        return (self.root / "config.json").is_file()

    def require(self) -> None:
        """Raise :class:`ConfigError` unless this is a calibration run directory."""
        if not self.root.is_dir():
            raise ConfigError(f"{self.root}: run directory not found; pass the --out folder of "
                              "`smcbayes calibrate`")
        if not self.is_run() or self.calibration_summary() is None:
            raise ConfigError(f"{self.root}: not a calibration run directory (config.json and "
                              "summary.json missing or unreadable); run `smcbayes calibrate` first")

    def identity(self) -> RunIdentity:
        """The run's identity; raises :class:`ConfigError` when missing or damaged."""
        data = read_json(self.root / "config.json")
        if not isinstance(data, dict) or "project" not in data:
            raise ConfigError(f"{self.root / 'config.json'}: missing or damaged; it is written by "
                              "`smcbayes calibrate` and cannot be rebuilt")
        return RunIdentity.from_json(data)

    def prepare(self, identity: RunIdentity, resume: bool) -> None:
        """Create the directory, or check that a resumed run is the same calibration.

        The contents of the external simulator's files, if it names any, are recorded when
        the run begins (``external_files.json``).

        Raises:
            ConfigError: the path is a file; a run exists without ``resume``; ``resume`` of
                a folder that holds no run, or with other settings; a file of the external
                simulator is missing, or (``resume``) changed since the run began.
            RunDirError: ``resume`` of a run whose evaluation log is missing or emptied
                while its summary counts evaluations.
        """
        if self.root.exists() and not self.root.is_dir():
            raise ConfigError(f"{self.root}: is a file, not a run directory; choose another --out")
        cfg = self.root / "config.json"
        if resume:
            self._check_resumable(identity)
        elif self.log_path.exists() or cfg.exists():
            raise ConfigError(f"{self.root}: already holds a calibration run; add --resume to "
                              "continue it or choose another --out")
        files = ExternalSpec(**identity.external).files if identity.external else ()
        digests = self._check_external_files(files, resume)
        self.root.mkdir(parents=True, exist_ok=True)
        write_json(cfg, identity.to_json())
        if digests and not (resume and self.external_files_path.is_file()):
            write_json(self.external_files_path, digests)

    @property
    def external_files_path(self) -> Path:
        """``external_files.json``: the contents' SHA-256 of the external simulator's files
        when the run began, by path."""
        return self.root / "external_files.json"

    def changed_external_files(self) -> list[str]:
        """The external simulator's files whose contents differ from those the run began
        with (``external_files.json``; none when it did not record them)."""
        recorded = read_json(self.external_files_path)
        if not isinstance(recorded, dict):
            return []
        now = file_digests(sorted(recorded))
        return [f for f in sorted(recorded) if now[f] != recorded[f]]

    def _check_external_files(self, files: Sequence[str], resume: bool) -> dict[str, str]:
        """The contents' digests of the external simulator's ``files``, checked before the run
        (re)starts.

        Raises:
            ConfigError: a file is missing, or a resumed run's files changed since it began
                (its evaluations are the old solver's, which a resume would mix with the new
                one's).
        """
        missing = [f for f in files if not Path(f).is_file()]
        if missing:
            raise ConfigError(f"the external simulator's file(s) {', '.join(missing)} are missing")
        changed = self.changed_external_files() if resume else []
        if changed:
            raise ConfigError(f"{self.root}: the external simulator's file(s) {', '.join(changed)} "
                              "changed since the run began; its evaluations are the old solver's, "
                              "which a resume would mix with the new one's: start a new run with "
                              "another --out, or restore the files")
        return file_digests(files)

    def require_resumable(self) -> RunIdentity:
        """The identity of a run that ``--resume`` can continue.

        Raises:
            ConfigError: the folder does not exist, is a file, or holds no calibration run.
        """
        if self.root.exists() and not self.root.is_dir():
            raise ConfigError(f"{self.root}: is a file, not a run directory; choose another --out")
        if not self.is_run():
            where = ("does not exist" if not self.root.exists()
                     else "holds no calibration run (no config.json)")
            raise ConfigError(f"{self.root}: {where}; --resume continues a run started with the same --out")
        return self.identity()

    def _check_resumable(self, identity: RunIdentity) -> None:
        """A resumed run must exist, hold its log, and be the same calibration."""
        self.require_resumable()
        done = (self.calibration_summary() or {}).get("evaluations") or 0
        if done and (not self.log_path.is_file() or self.log_path.stat().st_size == 0):
            raise RunDirError(f"{self.log_path}: missing or empty, but {self.root / 'summary.json'} counts "
                              f"{done} evaluations; restore the log from a copy (a resume would evaluate "
                              "everything again) or start a new run with another --out")
        old, new = _comparable(read_json(self.root / "config.json") or {}), _comparable(identity.to_json())
        for key in IDENTITY_KEYS:
            if key in old and old.get(key) != new.get(key):
                raise ConfigError(f"{self.root}: --resume with a different '{key}' than the run "
                                  "was started with; use the same config and options")

    def resumed_settings(self, base: CalibrationSpec, given: Mapping[str, Any],
                         option: str = "--") -> CalibrationSpec:
        """The settings of a resumed run: the run's own (``config.json``) over ``base``, with
        only :data:`RESUME_CHANGES` taken from ``given``.

        Args:
            base: defaults for settings an older run did not record (the project's table).
            given: settings asked for explicitly (``None``: not given).
            option: how a setting is named in a message: ``"--"`` gives ``--init``, ``""``
                gives ``init`` (keyword arguments of the API).

        Raises:
            ConfigError: a setting other than the budget, the tolerance or the local
                search's budget is given and differs from the run's (one line naming it and
                the run's value).
        """
        recorded = {k: v for k, v in self.identity().settings.items() if k in CalibrationSpec.model_fields}
        own = override(base, recorded, source=str(self.root / "config.json"))
        resume = "--resume" if option else "resume=True"
        for key, value in given.items():
            if key in RESUME_CHANGES or value is None or key == "truth":
                continue  # the truth belongs to the project, compared by prepare()
            if key not in CalibrationSpec.model_fields or value == getattr(own, key):
                continue  # unknown names are reported by override() below
            raise ConfigError(f"{option}{key} {value}: the run in {self.root} was started with "
                              f"{key} = {getattr(own, key)}; {resume} changes only {option}budget, "
                              f"{option}tolerance and {option}polish (drop the option, "
                              "or start a new run with another --out)")
        return override(own, given, source=str(self.root))

    def load_problem(self) -> Problem:
        """The calibration problem of the run, as calibrated (no curve is simulated again:
        a truth check's synthetic data are read from ``truth-data/``)."""
        ident = self.identity()
        ext = ExternalSpec(**ident.external) if ident.external else None
        return build_problem(ident.project_config(), self.root, ident.effects, ident.overrides,
                             ident.fidelity, ext, reuse_truth=True)

    # -- calibration ---------------------------------------------------------------------
    def evaluation_log(self) -> RunLog:
        """The append-only evaluation log."""
        return RunLog(self.log_path)

    def calibration_summary(self) -> dict[str, Any] | None:
        """``summary.json`` of the calibration, or ``None``."""
        data = read_json(self.root / "summary.json")
        return data if isinstance(data, dict) else None

    def write_calibration_summary(self, summary: Mapping[str, Any]) -> None:
        """Write ``summary.json`` (atomically)."""
        write_json(self.root / "summary.json", summary)

    def write_best_params(self, best: Mapping[str, Any]) -> None:
        """Write ``best_params.json``."""
        write_json(self.root / "best_params.json", best)

    def best_theta(self, names: Sequence[str]) -> NDArray[np.float64]:
        """The best calibrated point ``(1, d)`` over ``names`` (user units).

        Raises:
            ConfigError: the calibration has no successful evaluation.
        """
        summary = self.calibration_summary() or {}
        best = summary.get("best_params")
        if not best:
            raise ConfigError(f"{self.root}: the calibration has no successful evaluation")
        return np.array([[best[n]["value"] for n in names]], dtype=float)

    def best_curves_path(self, config_id: str) -> Path:
        """CSV of the simulated curves at the best point on one configuration."""
        return self.root / "best_curves" / f"{config_id}.csv"

    # -- later stages --------------------------------------------------------------------
    def begin_stage(self, stage: str, settings: Mapping[str, Any], folder: Path | None = None) -> Path:
        """Mark a stage as running (its folder's ``status.json``); returns the folder."""
        out = self.stage_dir(stage, folder)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "status.json", {"stage": stage, "state": "running", "started": _now(),
                                         "settings": dict(settings)})
        return out

    def complete_stage(self, stage: str, summary: Mapping[str, Any], folder: Path | None = None) -> None:
        """Write a stage's ``summary.json``, then mark it complete."""
        out = self.stage_dir(stage, folder)
        write_json(out / "summary.json", summary)
        status = read_json(out / "status.json") or {"stage": stage}
        write_json(out / "status.json", {**status, "state": "complete", "finished": _now()})

    def stage_state(self, stage: str, folder: Path | None = None) -> StageState:
        """``absent``, ``interrupted`` (started, never finished) or ``complete``."""
        out = self.stage_dir(stage, folder)
        if not out.is_dir():
            return "absent"
        status = read_json(out / "status.json")
        summary = read_json(out / "summary.json")
        if isinstance(status, dict):
            if status.get("state") == "complete" and isinstance(summary, dict):
                return "complete"
            return "interrupted"
        # a stage folder written before status files existed
        return "complete" if isinstance(summary, dict) else "interrupted"

    def forward_cache(self, stage: str, folder: Path | None = None, model: Sequence[str] = (),
                      earlier: ForwardCache | None = None, read_only: bool = False) -> ForwardCache:
        """The forward-run cache of a stage's model (``<stage folder>/forward_cache/``), tied
        to the run's identity (project without its stage tables, effects, overrides,
        fidelity, external simulator and its files' contents), the model's extra effects
        ``model``, the package version and the model's source
        (:func:`~smcbayes.run.cache.cache_tag`), so that runs of another calibration,
        model or model code are never reused; it also reads the runs of the ``earlier``
        cache (another stage's, of the same model), and writes nothing if ``read_only``."""
        # the stage tables do not change a forward run, and a resume may rewrite them
        ident = _comparable(self.identity().to_json())
        tag = cache_tag({k: ident.get(k) for k in _MODEL_KEYS}, model)
        return ForwardCache(self.stage_dir(stage, folder) / "forward_cache", tag, earlier, read_only)

    def calibration_cache(self, read_only: bool = False) -> ForwardCache:
        """The calibration's forward-run cache (``RUN_DIR/forward_cache/``): the curves of
        the design's and the optimisation's evaluations, the GP's training points; a later
        stage opens it ``read_only``."""
        return self.forward_cache("calibration", self.root, read_only=read_only)

    def stage_summary(self, stage: str, folder: Path | None = None) -> dict[str, Any] | None:
        """A complete stage's ``summary.json``, or ``None``."""
        if self.stage_state(stage, folder) != "complete":
            return None
        data = read_json(self.stage_dir(stage, folder) / "summary.json")
        return data if isinstance(data, dict) else None

    # -- commands ------------------------------------------------------------------------
    def record_command(self, stage: str, argv: Sequence[str]) -> None:
        """Append the command line of a stage run (``commands.jsonl``) with its directory."""
        self.root.mkdir(parents=True, exist_ok=True)
        line = json.dumps({"stage": stage, "argv": list(argv), "cwd": str(Path.cwd()), "time": _now()})
        with (self.root / "commands.jsonl").open("a", encoding="utf-8") as fh:
            fh.write(line + "\n")

    def commands(self) -> list[dict[str, Any]]:
        """The recorded command lines, oldest first (unreadable lines skipped)."""
        path = self.root / "commands.jsonl"
        if not path.is_file():
            return []
        out = []
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if isinstance(rec, dict) and isinstance(rec.get("argv"), list):
                out.append(rec)
        return out


def _comparable(identity: Mapping[str, Any]) -> dict[str, Any]:
    """What must match on resume, written the same way by every version: the project
    without its stage tables (the settings are compared one by one, and the later stages'
    tables do not change the calibration), a fitted noise as ``"fit"``."""
    out = dict(identity)
    project = out.get("project")
    if isinstance(project, dict):
        out["project"] = {k: v for k, v in project.items()
                          if k not in ("calibration", "posterior", "diagnose")}
        out["project"]["truth"] = (project.get("calibration") or {}).get("truth")
    if "noise" in out and out["noise"] is None:
        out["noise"] = "fit"
    return out


def _now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
