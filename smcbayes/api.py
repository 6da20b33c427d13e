"""The Python API: the project loader and the stages as functions with typed results.

Each stage reads and writes a run directory exactly as the command line does, so a run
started in a notebook can be continued, reported or inspected from the shell and back::

    import smcbayes
    project = smcbayes.load_project("configs/verify-slip-2d.toml")
    cal = smcbayes.calibrate(project, "runs/slip", budget=12, init=6)
    post = smcbayes.sample_posterior(cal.run_dir, walkers=16, steps=300, correct_draws=0)
    cal.best_params, post.table()  # dicts of values and of quantiles

Torch and the other heavy modules load when a stage runs, not on ``import smcbayes``.
The names differ from the subpackages (``smcbayes.posterior`` is the package of the
posterior stage, ``smcbayes.sample_posterior`` the function).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from smcbayes.config import DiagnoseSpec, PosteriorSpec, ProjectConfig, load_project, override
from smcbayes.run import RunDir, RunIdentity
from smcbayes.simulation.executors.base import make_executor
from smcbayes.simulation.problem import ExternalSpec, build_problem

PathLike = str | os.PathLike[str]

__all__ = ["CalibrationResult", "DiagnosisResult", "PosteriorResult", "calibrate", "diagnose_gap",
           "load_project", "sample_posterior", "write_report"]


@dataclass(frozen=True)
class CalibrationResult:
    """A finished calibration.

    Attributes:
        run_dir: its run directory.
        summary: the content of ``summary.json``.
    """

    run_dir: RunDir
    summary: dict[str, Any]

    @property
    def best_params(self) -> dict[str, float]:
        """Best parameter values in their units (fixed ones included)."""
        return {k: float(v["value"]) for k, v in (self.summary.get("best_params") or {}).items()}

    @property
    def best_loss_kN2(self) -> float | None:
        """Loss at the best point (kN^2)."""
        return self.summary.get("best_loss_kN2")


@dataclass(frozen=True)
class PosteriorResult:
    """A finished posterior stage.

    Attributes:
        run_dir: the run directory.
        summary: the content of ``posterior/summary.json``.
    """

    run_dir: RunDir
    summary: dict[str, Any]

    def table(self) -> dict[str, dict[str, float]]:
        """Per parameter: mean, sd, 5/50/95 % quantiles, R-hat and ESS.

        An importance-weighted posterior (the emulated posterior sampled by importance, or
        one corrected by the forward model) has no R-hat (NaN) and the importance ESS; the
        R-hat of the emcee chains that seeded its proposal is in
        ``summary["emulator_parameters"]``.
        """
        keys = ("mean", "sd", "q05", "q50", "q95", "r_hat", "ess")
        return {p["name"]: {k: p[k] for k in keys} for p in self.summary["parameters"]}

    @property
    def warnings(self) -> list[str]:
        """The stage's warnings in plain words."""
        return list(self.summary.get("warnings") or [])

    def inference_data(self) -> Any:
        """The posterior as ``arviz.InferenceData`` (``posterior.nc``), e.g. for ``arviz.plot_pair``."""
        import arviz

        return arviz.from_netcdf(str(self.run_dir.stage_dir("posterior") / "posterior.nc"))


@dataclass(frozen=True)
class DiagnosisResult:
    """A finished diagnosis.

    Attributes:
        out: its output folder.
        summary: the content of its ``summary.json``.
    """

    out: Path
    summary: dict[str, Any]

    @property
    def best_effect(self) -> str | None:
        """The effect named (``None``: no effect explains the gap beyond noise)."""
        return (self.summary.get("decision") or {}).get("best")

    @property
    def selected_effects(self) -> list[str]:
        """The effect set forward selection grew from the named effect (empty: none), the
        ``effects=`` of the next :func:`calibrate`."""
        return [str(e) for e in self.summary.get("selected_effects") or []]

    @property
    def statement(self) -> str:
        """The decision in one sentence."""
        return str((self.summary.get("decision") or {}).get("statement", ""))


def _project(project: ProjectConfig | PathLike) -> ProjectConfig:
    return project if isinstance(project, ProjectConfig) else load_project(project)


def calibrate(project: ProjectConfig | PathLike, out: PathLike, *, effects: Sequence[str] | None = None,
              overrides: Mapping[str, float] | None = None, fidelity: str | None = None,
              external: ExternalSpec | None = None, workers: int = 1, scheduler: str | None = None,
              resume: bool = False, figures: bool = True, **settings: Any) -> CalibrationResult:
    """Calibrate ``project`` into the run directory ``out`` (as ``smcbayes calibrate``).

    Args:
        project: a loaded project or the path of its TOML file.
        out: the run directory (new, or an existing one with ``resume=True``).
        effects: effects switched on (default: the project's).
        overrides: fixed parameter values in their units, e.g. ``{"n": 0.4}``.
        fidelity: ``"1d"`` or ``"2d"`` (default: the project's solver).
        external: an external simulator instead of the native model.
        workers, scheduler: where evaluations run (process pool, Dask address).
        resume: continue the run in ``out`` with its own settings: only ``budget``,
            ``tolerance`` and ``polish`` may change them, any other setting given must agree
            with the run.
        figures: write the figures.
        **settings: fields of the ``[calibration]`` table, e.g. ``budget=60, init=20``.
    """
    from smcbayes.surrogate.calibration import calibrate as run_calibration

    project = _project(project)
    run = RunDir(out)
    if resume and run.is_run():
        spec = run.resumed_settings(project.calibration, settings, option="")
    else:
        spec = override(project.calibration, settings, source="calibrate()")
    spec.check()
    project = project.model_copy(update={"calibration": spec})  # truth= included
    fixed = dict(overrides or {})
    run.prepare(RunIdentity(project.model_dump(mode="json"), None if effects is None else list(effects),
                            fixed, fidelity, None if external is None else external.to_json(),
                            spec.model_dump(mode="json", exclude={"truth"})), resume)
    problem = build_problem(project, run.root, effects, fixed, fidelity, external, reuse_truth=resume)
    summary = run_calibration(problem, spec, run, make_executor(workers, scheduler), figures=figures)
    return CalibrationResult(run, summary)


def sample_posterior(run_dir: PathLike | RunDir, *, workers: int = 1, scheduler: str | None = None,
              **settings: Any) -> PosteriorResult:
    """The posterior stage of a calibration run (as ``smcbayes posterior``).

    Args:
        run_dir: the calibration's run directory.
        workers, scheduler: where the stage's forward runs execute.
        **settings: fields of the ``[posterior]`` table, e.g. ``walkers=32, correct_draws=0``.
    """
    from smcbayes.posterior.stage import run_posterior

    run = run_dir if isinstance(run_dir, RunDir) else RunDir(run_dir)
    run.require()
    base: PosteriorSpec = run.identity().project_config().posterior
    spec = override(base, settings, source="posterior()")
    return PosteriorResult(run, run_posterior(run, spec, make_executor(workers, scheduler)))


def diagnose_gap(run_dir: PathLike | RunDir, out: PathLike | None = None, *, figures: bool = True,
             workers: int = 1, scheduler: str | None = None, **settings: Any) -> DiagnosisResult:
    """The gap diagnosis of a calibration run (as ``smcbayes diagnose``).

    Args:
        run_dir: the calibration's run directory.
        out: output folder (default ``RUN_DIR/diagnose``).
        figures: write the figures.
        workers, scheduler: where the forward runs execute.
        **settings: fields of the ``[diagnose]`` table, e.g. ``effects=["press_compliance"]``.
    """
    from smcbayes.diagnose.load import context_from_run
    from smcbayes.diagnose.run import diagnose as run_diagnosis
    from smcbayes.diagnose.run import settings_for

    run = run_dir if isinstance(run_dir, RunDir) else RunDir(run_dir)
    run.require()
    base: DiagnoseSpec = run.identity().project_config().diagnose
    spec = override(base, settings, source="diagnose_gap()")
    ctx = context_from_run(run, lambda: make_executor(workers, scheduler))
    settings_ = settings_for(spec, ctx.base_effects, figures)  # bad effects fail here, before any run
    folder = run.begin_stage("diagnose", spec.model_dump(mode="json"), None if out is None else Path(out))
    try:
        summary = run_diagnosis(ctx, settings_, folder)
    finally:
        ctx.close()
    run.complete_stage("diagnose", summary, folder)
    return DiagnosisResult(folder, summary)


def write_report(run_dir: PathLike | RunDir, formats: Sequence[str] = ("html", "md"),
           diagnosis_dir: PathLike | None = None) -> list[Path]:
    """Write the run's report (as ``smcbayes report``); returns the files written."""
    from smcbayes.report import write_report as write

    root = run_dir.root if isinstance(run_dir, RunDir) else Path(run_dir)
    return write(root, formats, None if diagnosis_dir is None else Path(diagnosis_dir))
