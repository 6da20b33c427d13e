"""The forward model: physics (effects) + configurations (cases) + a solver.

Built once from a validated project, it simulates any number of parameter vectors on any
subset of configurations.  It is the only thing the layers above see of the physics.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from smcbayes.config import MaterialSpec, ProjectConfig, SolverSpec
from smcbayes.errors import ConfigError, SlowPathWarning, SolverError, closest
from smcbayes.forward.case import Case
from smcbayes.forward.effects import EffectStack, available, get_effect
from smcbayes.forward.hele_shaw2d import HeleShaw2D
from smcbayes.forward.parameters import (
    BASE_PARAMETERS,
    Parameter,
    ParameterSpace,
    to_si,
    validate_batch,
)
from smcbayes.forward.result import SimulationResult
from smcbayes.forward.squeeze1d import Squeeze1D, Squeeze1DOptions

Array = NDArray[np.float64]


class Solver(Protocol):
    """The solver contract: one configuration, a batch of SI parameter sets."""

    name: str

    def solve(self, case: Case, p: dict[str, Array], effects: EffectStack,
              material: MaterialSpec) -> SimulationResult: ...


def make_solver(spec: SolverSpec, fidelity: str | None = None) -> Solver:
    """Solver for a fidelity (``1d`` or ``2d``) with the project's discretisation."""
    kind = fidelity or spec.fidelity
    if kind == "1d":
        return Squeeze1D(Squeeze1DOptions(
            closing_steps=spec.closing_steps, hold_steps=spec.hold_steps,
            per_decade=spec.stress_points_per_decade,
            output_closing_points=spec.output_closing_points,
            output_hold_points=spec.output_hold_points, shape_correction=spec.shape_correction))
    if kind == "2d":
        return HeleShaw2D.from_spec(spec)
    raise ConfigError(f"unknown fidelity '{kind}'; accepted: 1d, 2d")


def build_space(project: ProjectConfig, effects: EffectStack,
                overrides: Mapping[str, float] | None = None) -> ParameterSpace:
    """Parameter space of base + effect parameters with the project's bounds and values.

    ``[parameters.NAME]`` tables set ``value`` (the simulate value and, if ``fixed``, a
    constant) and ``bounds``; ``overrides`` (from ``--set``) fix values.  A table may name
    the parameter of any registered effect: it applies whenever that effect is switched on
    (a project can state its material's known solid density once, for every run that
    turns compressibility on), and is ignored otherwise.
    """
    params: list[Parameter] = list(BASE_PARAMETERS) + list(effects.parameters)
    names = [p.name for p in params]
    known = names + [q.name for cls in available().values() for q in cls.parameters if q.name not in names]
    for name in project.parameters:
        if name not in known:
            raise ConfigError(f"[parameters.{name}]: unknown parameter{closest(name, known)}; "
                              f"accepted: {', '.join(known)}")
    out: list[Parameter] = []
    fixed: dict[str, float] = {}
    for p in params:
        spec = project.parameters.get(p.name)
        if spec is not None and spec.value is not None:
            p.check_value(spec.value, f"[parameters.{p.name}].value")
            p = replace(p, default=float(spec.value))
            if spec.fixed:
                fixed[p.name] = float(spec.value)
        out.append(p)
    space = ParameterSpace(tuple(out))
    bounds = {n: s.bounds for n, s in project.parameters.items() if s.bounds is not None and n in names}
    space = space.with_bounds(bounds).with_fixed(fixed, "[parameters]")
    return space.with_fixed(dict(overrides or {}), "--set")


class ForwardModel:
    """Simulate configurations of a project for batches of parameter vectors.

    Args:
        project: the validated project.
        effects: effect names to switch on (default: the project's ``effects``).
        overrides: parameter values to fix (``--set``), user units.
        fidelity: ``1d`` or ``2d`` (default: the project's solver setting).
    """

    def __init__(self, project: ProjectConfig, effects: Sequence[str] | None = None,
                 overrides: Mapping[str, float] | None = None, fidelity: str | None = None) -> None:
        self.project = project
        self.effects = EffectStack([get_effect(n) for n in (project.effects if effects is None else effects)])
        self.space = build_space(project, self.effects, overrides)
        self.solver = make_solver(project.solver, fidelity)
        base = Path(project.base_dir)
        self.cases = {c.id: Case.from_spec(c, base) for c in project.configuration}
        self.warn_slow_path()

    def warn_slow_path(self) -> None:
        """Warn (:class:`SlowPathWarning`, once) if an effect or a measured ram profile
        keeps runs off the compiled marching kernel although it was not switched off."""
        check = getattr(self.solver, "slow_path", None)
        if check is None:
            return
        reasons = list(dict.fromkeys(r for case in self.cases.values() for r in check(case, self.effects)))
        if reasons:
            warnings.warn(f"{' and '.join(reasons)}: the compiled kernel does not implement "
                          "this, so these runs take the NumPy marching path, about 100-300 ms "
                          "per run instead of 1-3 ms (30-100x slower); calibration takes "
                          "correspondingly longer",
                          SlowPathWarning, stacklevel=3)

    @property
    def config_ids(self) -> list[str]:
        """All configuration ids, in file order."""
        return list(self.cases)

    def ids(self, role: str | None = None) -> list[str]:
        """Configuration ids with the given role (``train``/``validation``), or all."""
        return [c.id for c in self.project.configuration if role is None or c.role == role]

    def simulate(self, theta: ArrayLike | None = None,
                 config_ids: Iterable[str] | None = None) -> dict[str, SimulationResult]:
        """Run the free-parameter vectors ``theta`` ``(P, d)`` (user units) on configurations."""
        return self.simulate_params(self.space.batch(theta), config_ids)

    def simulate_params(self, params: Mapping[str, ArrayLike],
                        config_ids: Iterable[str] | None = None) -> dict[str, SimulationResult]:
        """Run a full parameter batch (name -> ``(P,)``, user units) on configurations."""
        batch = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in params.items()}
        missing = [p.name for p in self.space.parameters if p.name not in batch]
        if missing:  # the batch comes from code (a sampler, a design), not from a file
            raise SolverError(f"parameter batch lacks {', '.join(missing)}")
        validate_batch(batch, self.space.parameters)
        si = to_si(batch, self.space.parameters)
        out: dict[str, SimulationResult] = {}
        for cid in (self.config_ids if config_ids is None else list(config_ids)):
            if cid not in self.cases:
                raise ConfigError(f"unknown configuration '{cid}'{closest(cid, self.config_ids)}")
            try:
                out[cid] = self.solver.solve(self.cases[cid], si, self.effects, self.project.material)
            except FloatingPointError as err:
                raise SolverError(f"configuration '{cid}': {err}") from err
        return out
