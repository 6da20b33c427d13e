"""smcbayes: identify SMC rheology from press force-time curves.

Layers (each sees only those below it): ``config`` and ``errors`` at the bottom, then
``forward`` (physics) -> ``data`` (measured curves, loss) -> ``simulation`` (the simulator
seam and executors) -> ``run`` (the run directory) -> ``surrogate`` (Bayesian
calibration) -> ``posterior`` -> ``diagnose`` -> ``report`` -> ``commands``/``api`` ->
``cli``.

The Python API (:mod:`smcbayes.api`) is available from the package itself::

    import smcbayes
    cal = smcbayes.calibrate("configs/verify-slip-2d.toml", "runs/slip", budget=12, init=6)
"""

from __future__ import annotations

from typing import Any

from smcbayes.errors import (
    ConfigError,
    ContactOffsetWarning,
    ConvergenceWarning,
    DataError,
    ParameterOnBoundWarning,
    SlowPathWarning,
    SmcBayesError,
    SmcBayesWarning,
    SolverError,
    StaleRunsWarning,
    SurrogateError,
    UnreliablePosteriorWarning,
)

__version__ = "0.1.0"

_API = ("load_project", "calibrate", "sample_posterior", "diagnose_gap", "write_report",
        "CalibrationResult", "PosteriorResult", "DiagnosisResult")

__all__ = [
    "ConfigError", "ContactOffsetWarning", "ConvergenceWarning", "DataError", "ParameterOnBoundWarning",
    "SlowPathWarning", "SmcBayesError", "SmcBayesWarning", "SolverError", "StaleRunsWarning",
    "SurrogateError", "UnreliablePosteriorWarning",
    "__version__", *_API,
]


def __getattr__(name: str) -> Any:
    # the API pulls in pydantic and numpy: loaded on first use, so `smcbayes.errors` stays light
    if name in _API:
        from smcbayes import api

        return getattr(api, name)
    raise AttributeError(f"module 'smcbayes' has no attribute {name!r}")
