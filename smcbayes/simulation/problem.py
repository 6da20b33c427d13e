"""A calibration problem from a project: forward model (or external solver), data, loss.

Also builds the synthetic "measured" data of a check with known truth
(``[calibration] truth = {...}``): the truth is simulated on the training configurations
and written as ``force/<id>.csv`` (contact to force limit) and ``hold/<id>.csv`` (ram
travel under force control, negative = closing) in a folder of the run, which then serves
as the project's data directory.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smcbayes.config import DataSpec, ProjectConfig
from smcbayes.data.dataset import Dataset, load_dataset
from smcbayes.data.readers.csv import write_csv
from smcbayes.errors import ConfigError, DataError, DataWarning, FixedOutsideBoxWarning, SolverError
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.squeeze1d import Squeeze1D
from smcbayes.simulation.executors.base import Executor
from smcbayes.simulation.executors.external import ExternalSimulator
from smcbayes.simulation.objective import Simulator, SimulatorObjective
from smcbayes.simulation.runner import Runner


@dataclass(frozen=True)
class ExternalSpec:
    """How to run an external simulator (see :mod:`smcbayes.simulation.executors.external`).

    Attributes:
        command: the command template.
        timeout_s: wall-time limit of one run (s).
        output_format: what the command writes (``csv`` or ``moldflow``).
        files: the files the solver's results depend on (its script, study, mesh or
            material files, not the files it writes; kept as absolute paths, a relative one
            taken from the working directory, links not followed, sorted): their contents
            join the forward-run caches' tag (:func:`~smcbayes.run.cache.cache_tag`), so
            that runs of a solver changed behind the same command line are not reused, and
            a calibration refuses to resume once they changed
            (:meth:`~smcbayes.run.directory.RunDir.prepare`).

    Raises:
        ConfigError: ``files`` is one string instead of a sequence of paths.
    """

    command: str
    timeout_s: float = 3600.0
    output_format: str = "csv"
    files: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.files, str):
            raise ConfigError(f"external simulator files: a sequence of paths, not the one string "
                              f"{self.files!r}")
        # a run directory's identity holds them as a JSON list, compared on resume; a later
        # stage may run from another working directory; a link re-pointed later must count
        # as a change of the file, so it is not resolved
        object.__setattr__(self, "files", tuple(sorted({os.path.abspath(f) for f in self.files})))

    def missing(self) -> list[str]:
        """The ``files`` that are not (or no longer) files."""
        return [f for f in self.files if not Path(f).is_file()]

    def to_json(self) -> dict[str, Any]:
        """The spec as a run directory's identity records it (``files`` only when given, so
        that the identity, and with it the caches' tag, of a run without them is as it
        was before they existed)."""
        out: dict[str, Any] = {"command": self.command, "timeout_s": self.timeout_s,
                               "output_format": self.output_format}
        return {**out, "files": list(self.files)} if self.files else out


@dataclass
class Problem:
    """Everything a stage needs besides its settings.

    Attributes:
        project: the project (data_dir pointing at synthetic data for a truth check).
        model: the native forward model: the parameter space, the effects and the
            configurations' roles (it simulates only when it is also the simulator).
        objective: the run's simulator (``objective.simulator``: the native model or the
            external adapter), the measured data and the loss; every forward run of every
            stage goes through it (:meth:`runner`).
        train_ids: configurations in the loss.
        truth: true parameter values (user units) of a synthetic check, else ``None``.
    """

    project: ProjectConfig
    model: ForwardModel
    objective: SimulatorObjective
    train_ids: list[str]
    truth: dict[str, float] | None

    @property
    def simulator(self) -> Simulator:
        """The one simulator of the run (native or external)."""
        return self.objective.simulator

    @property
    def fast(self) -> bool:
        """Whether a forward run costs milliseconds: the built-in model with the 1-D solver
        (not an external simulator, not the 2-D solver's seconds per configuration).  The
        stages spend forward runs freely only then (the calibration's local search, the
        posterior's importance correction)."""
        return self.simulator is self.model and isinstance(self.model.solver, Squeeze1D)

    @property
    def dataset(self) -> Dataset:
        """Measured curves of every configuration that has them (training and validation)."""
        return self.objective.dataset

    @property
    def space(self):
        """The parameter space."""
        return self.model.space

    def measured_force(self, ids: Sequence[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Measured force curves ``(time_s, force_kN)`` of those of ``ids`` that have them."""
        return {cid: (m.force.time_s, m.force.values) for cid, m in self.dataset.measurements.items()
                if cid in ids and m.force is not None}

    def runner(self, executor: Executor | None = None, retries: int | None = None) -> Runner:
        """The run's objective bound to ``executor`` (in process when ``None``), failed
        runs retried ``retries`` times (default: the project's ``[calibration] retries``)."""
        return Runner(self.objective, executor,
                      retries=self.project.calibration.retries if retries is None else retries)


def write_truth_data(model: ForwardModel, truth: Mapping[str, float], ids: Sequence[str],
                     folder: Path) -> None:
    """Simulate ``truth`` on ``ids`` and write force and hold curves like the press data."""
    unknown = [k for k in truth if k not in model.space.names]
    if unknown:
        raise ConfigError(f"[calibration] truth: unknown parameter '{unknown[0]}'; "
                          f"accepted: {', '.join(model.space.names)}")
    params = {**model.space.defaults(), **{k: float(v) for k, v in truth.items()}}
    results = model.simulate_params({k: np.array([v]) for k, v in params.items()}, ids)
    (folder / "force").mkdir(parents=True, exist_ok=True)
    (folder / "hold").mkdir(parents=True, exist_ok=True)
    for cid, res in results.items():
        if res.status[0] != "ok":
            raise SolverError(f"[calibration] truth: simulation of '{cid}' {res.status[0]}")
        t, f, d = res.time_s[0], res.force_kN[0], res.displacement_mm[0]
        t_switch = res.switch_time_s[0]
        closing = t <= t_switch if np.isfinite(t_switch) else np.ones_like(t, dtype=bool)
        write_csv(folder / "force" / f"{cid}.csv", t[closing], f[closing], "force_kN", digits=10)
        if np.isfinite(t_switch) and np.count_nonzero(~closing) >= 2:
            hold = t >= t_switch
            d0 = np.interp(t_switch, t, d)
            write_csv(folder / "hold" / f"{cid}.csv", t[hold] - t_switch, -(d[hold] - d0),
                      "displacement_mm", digits=10)


def with_data_dir(project: ProjectConfig, folder: Path, ids: Sequence[str]) -> ProjectConfig:
    """Copy of ``project`` reading ``ids``' curves from ``folder`` (force and hold CSVs)."""
    configs = []
    for c in project.configuration:
        if c.id in ids:
            hold = folder / "hold" / f"{c.id}.csv"
            data = DataSpec(force=f"force/{c.id}.csv", hold=f"hold/{c.id}.csv" if hold.exists() else None)
            c = c.model_copy(update={"data": data})
        configs.append(c)
    return project.model_copy(update={"configuration": configs, "data_dir": str(folder.resolve())})


def build_problem(project: ProjectConfig, run_dir: Path, effects: Sequence[str] | None = None,
                  overrides: Mapping[str, float] | None = None, fidelity: str | None = None,
                  external: ExternalSpec | None = None, reuse_truth: bool = False) -> Problem:
    """Forward model, data and objective of a calibration of ``project``'s training set.

    Args:
        reuse_truth: read the synthetic curves of a truth check from ``run_dir/truth-data``
            where the calibration wrote them, instead of simulating them again.
    """
    model = ForwardModel(project, effects=effects, overrides=overrides, fidelity=fidelity)
    _warn_outside_box(model, overrides or {})
    if model.space.dim == 0:
        raise ConfigError("every parameter is fixed: free at least one ([parameters.X] fixed = false)")
    ids = model.ids("train")
    if not ids:
        raise ConfigError("no configuration has role = \"train\"; calibration needs training data")
    truth = project.calibration.truth
    if truth is not None:
        folder = run_dir / "truth-data"
        if not (reuse_truth and (folder / "force").is_dir()):
            write_truth_data(model, truth, ids, folder)
        project = with_data_dir(project, folder, ids)
        model = ForwardModel(project, effects=effects, overrides=overrides, fidelity=fidelity)
    dataset = _load_data(project, ids, synthetic=truth is not None)
    bare = [cid for cid in ids if cid not in dataset.measurements or dataset.measurements[cid].force is None]
    if bare:
        raise ConfigError(f"training configuration(s) {', '.join(bare)} have no measured force "
                          "curve: add data.force or set role = \"validation\"")
    simulator: Simulator = model
    if external is not None:
        if external.missing():
            raise ConfigError(f"the external simulator's file(s) {', '.join(external.missing())} "
                              "(--external-file, ExternalSpec.files) are missing: restore them")
        simulator = ExternalSimulator(project, model.space, external.command, run_dir / "work",
                                      external.timeout_s, external.output_format)
    objective = SimulatorObjective(simulator, dataset, ids, project.loss)
    full_truth = None if truth is None else {**model.space.defaults(), **truth}
    return Problem(project, model, objective, ids, full_truth)


def _warn_outside_box(model: ForwardModel, overrides: Mapping[str, float]) -> None:
    """A value fixed outside its parameter's search bounds is allowed (the bounds are for
    the search) but said, since it is often a typo or a unit slip."""
    for p in model.space.parameters:
        value = overrides.get(p.name)
        if value is not None and not p.lower <= value <= p.upper:
            warnings.warn(f"{p.name} = {value:g} is fixed outside its search bounds "
                          f"{p.lower:g}-{p.upper:g} {p.unit}", FixedOutsideBoxWarning, stacklevel=3)


def _load_data(project: ProjectConfig, train_ids: Sequence[str], synthetic: bool) -> Dataset:
    """Training curves (required: a bad file stops here) and the validation curves that can
    be read (for bands and held-out errors: a missing or bad one is left out with a
    :class:`DataWarning`, as it takes no part in the calibration).  A truth check has
    synthetic training curves only."""
    dataset = load_dataset(project, ids=train_ids, preprocess=project.preprocess)
    root = project.data_path()
    if synthetic or root is None or not root.is_dir():
        return dataset
    for spec in project.configuration:
        if spec.role != "validation" or spec.data is None:
            continue
        try:
            dataset.measurements.update(load_dataset(project, [spec.id], project.preprocess).measurements)
        except DataError as err:
            warnings.warn(f"validation configuration '{spec.id}' left out of bands and held-out "
                          f"errors: {err}", DataWarning, stacklevel=3)
    order = [c.id for c in project.configuration if c.id in dataset.measurements]
    return Dataset(project, {cid: dataset.measurements[cid] for cid in order}, dataset.preprocess)
