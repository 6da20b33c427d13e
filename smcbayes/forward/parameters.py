"""Calibrated parameters: names with units, search bounds, log scaling, physical limits.

A parameter vector ``theta`` is an array of shape ``(P, d)`` in the engineering units
named by each parameter (``tau_c_MPa`` in MPa).  :class:`ParameterSpace` maps it to the
unit cube (log-scaled where ``log`` is set) for the optimiser and to SI for the solvers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from smcbayes.errors import ConfigError, SolverError, closest


@dataclass(frozen=True)
class Parameter:
    """One scalar model parameter.

    Attributes:
        name: identifier with its unit suffix, e.g. ``tau_c_MPa``.
        symbol: key of the SI value inside the solvers, e.g. ``tau_c`` (in Pa).
        unit: unit of the value as given by the user, e.g. ``MPa`` (``-`` if none).
        si_scale: factor from the user's unit to SI (1e6 for MPa).
        lower, upper: search bounds in the user's unit.
        log: search in log10 space (scale parameters).
        default: value used when the parameter is neither set nor searched.
        valid: open physical interval; values outside it are rejected, not clipped.
        description: one line for ``--help``, tables and reports.
    """

    name: str
    symbol: str
    unit: str
    si_scale: float
    lower: float
    upper: float
    log: bool
    default: float
    valid: tuple[float, float]
    description: str

    def check_value(self, value: float, source: str) -> None:
        """Raise :class:`ConfigError` if ``value`` is outside the physical interval."""
        lo, hi = self.valid
        if not np.isfinite(value) or not (lo < value < hi):
            raise ConfigError(
                f"{source}: {self.name}={value!r} is outside the physical range "
                f"({lo:g}, {hi:g}) {self.unit} ({self.description})"
            )


BASE_PARAMETERS: tuple[Parameter, ...] = (
    Parameter("n", "n", "-", 1.0, 0.2, 0.6, False, 0.4, (0.0, 1.0 + 1e-12),
              "power-law index of the modified Cross law"),
    Parameter("tau_star_Pa", "tau_star", "Pa", 1.0, 1e3, 1e5, True, 1e4, (0.0, np.inf),
              "Cross transition stress tau*"),
    Parameter("B_Pa_s", "B", "Pa s", 1.0, 1e3, 1e5, True, 1e4, (0.0, np.inf),
              "zero-shear viscosity at the mould temperature (Arrhenius prefactor)"),
    Parameter("tau_c_MPa", "tau_c", "MPa", 1e6, 0.005, 1.0, True, 0.05, (-1e-300, np.inf),
              "critical wall shear stress of the slip law"),
    Parameter("m", "m", "-", 1.0, 1.0, 1.9, False, 1.5, (0.0, np.inf),
              "slip exponent"),
)


@dataclass(frozen=True)
class ParameterSpace:
    """An ordered set of parameters; some searched, some fixed.

    Attributes:
        parameters: every parameter the model takes, in order.
        fixed: values (user units) of parameters that are not searched.
    """

    parameters: tuple[Parameter, ...]
    fixed: Mapping[str, float] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        """All parameter names in order."""
        return [p.name for p in self.parameters]

    @property
    def free(self) -> list[Parameter]:
        """The searched parameters, in order."""
        return [p for p in self.parameters if p.name not in self.fixed]

    @property
    def free_names(self) -> list[str]:
        """Names of the searched parameters."""
        return [p.name for p in self.free]

    @property
    def dim(self) -> int:
        """Number of searched parameters ``d``."""
        return len(self.free)

    def get(self, name: str) -> Parameter:
        """Look a parameter up by name; unknown names raise with a suggestion."""
        for p in self.parameters:
            if p.name == name:
                return p
        raise ConfigError(
            f"unknown parameter '{name}'{closest(name, self.names)}; "
            f"accepted: {', '.join(self.names)}"
        )

    def with_fixed(self, values: Mapping[str, float], source: str = "--set") -> ParameterSpace:
        """Return a copy in which ``values`` (user units) are fixed."""
        fixed = dict(self.fixed)
        for name, value in values.items():
            self.get(name).check_value(float(value), source)
            fixed[name] = float(value)
        return replace(self, fixed=fixed)

    def with_bounds(self, bounds: Mapping[str, tuple[float, float]]) -> ParameterSpace:
        """Return a copy with new search bounds (user units) for the named parameters."""
        params = []
        for p in self.parameters:
            if p.name in bounds:
                lo, hi = (float(b) for b in bounds[p.name])
                if not lo < hi:
                    raise ConfigError(f"bounds of {p.name}: lower {lo:g} must be < upper {hi:g}")
                p.check_value(lo, f"lower bound of {p.name}")
                p.check_value(hi, f"upper bound of {p.name}")
                p = replace(p, lower=lo, upper=hi)
            params.append(p)
        unknown = set(bounds) - set(self.names)
        for name in unknown:
            self.get(name)
        return replace(self, parameters=tuple(params))

    def defaults(self) -> dict[str, float]:
        """Fixed values where given, defaults otherwise (user units)."""
        return {p.name: float(self.fixed.get(p.name, p.default)) for p in self.parameters}

    # -- conversions between unit cube, user units and full batches ----------------------
    def _bounds_t(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        free = self.free
        log = np.array([p.log for p in free], dtype=bool)
        lo = np.array([p.lower for p in free], dtype=float)
        hi = np.array([p.upper for p in free], dtype=float)
        # log10 only where log-scaled: linear parameters may have a zero bound
        lo = np.where(log, np.log10(np.where(log, lo, 1.0)), lo)
        hi = np.where(log, np.log10(np.where(log, hi, 1.0)), hi)
        return lo, hi, log

    def from_unit(self, u: ArrayLike) -> NDArray[np.float64]:
        """Map points of the unit cube, shape ``(P, d)``, to user units ``(P, d)``."""
        u = np.atleast_2d(np.asarray(u, dtype=float))
        lo, hi, log = self._bounds_t()
        x = lo + u * (hi - lo)
        return np.where(log, 10.0 ** np.where(log, x, 0.0), x)

    def to_unit(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Map user-unit vectors ``(P, d)`` of the free parameters to the unit cube."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        lo, hi, log = self._bounds_t()
        x = np.where(log, np.log10(np.where(log, theta, 1.0)), theta)
        return (x - lo) / (hi - lo)

    def batch(self, theta: ArrayLike | None = None) -> dict[str, NDArray[np.float64]]:
        """Full parameter batch, name -> ``(P,)`` array in user units.

        Args:
            theta: free-parameter vectors, shape ``(P, d)``; ``None`` gives one row of
                defaults.
        """
        if theta is None:
            theta = np.array([[self.defaults()[p.name] for p in self.free]])
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if theta.shape[1] != self.dim:  # vectors come from code (a sampler, a design)
            raise SolverError(
                f"parameter vectors have {theta.shape[1]} columns, expected {self.dim} "
                f"({', '.join(self.free_names)})"
            )
        n_rows = theta.shape[0]
        out: dict[str, NDArray[np.float64]] = {}
        col = 0
        for p in self.parameters:
            if p.name in self.fixed:
                out[p.name] = np.full(n_rows, self.fixed[p.name])
            else:
                out[p.name] = theta[:, col].copy()
                col += 1
        return out


def validate_batch(params: Mapping[str, NDArray[np.float64]],
                   parameters: Sequence[Parameter]) -> None:
    """Raise :class:`ConfigError` if any value of a batch is outside its physical range."""
    for p in parameters:
        values = np.asarray(params[p.name])
        lo, hi = p.valid
        bad = ~np.isfinite(values) | (values <= lo) | (values >= hi)
        if np.any(bad):
            first = float(values[np.argmax(bad)])
            p.check_value(first, "parameter batch")


def to_si(params: Mapping[str, NDArray[np.float64]],
          parameters: Sequence[Parameter]) -> dict[str, NDArray[np.float64]]:
    """Convert a user-unit batch (name -> ``(P,)``) to SI keyed by symbol."""
    return {p.symbol: np.asarray(params[p.name], dtype=float) * p.si_scale for p in parameters}
