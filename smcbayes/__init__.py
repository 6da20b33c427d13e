"""smcbayes: identify SMC rheology from press force-time curves.

Layers (each sees only the one below it):

``forward`` (physics: material laws, geometry, press programme, solvers, effects)
-> ``data`` (measured curves, pre-processing, loss, synthetic data)
-> ``surrogate`` (design of experiments, GP, Bayesian optimisation, executors)
-> ``posterior`` (emulated likelihood, emcee, predictive bands)
-> ``diagnose`` (sim-to-real gap) -> ``report``; ``cli`` is a thin shell over them.
"""

from smcbayes.errors import (
    ConfigError,
    DataError,
    SmcBayesError,
    SolverError,
    SurrogateError,
)

__version__ = "0.1.0"

__all__ = [
    "ConfigError",
    "DataError",
    "SmcBayesError",
    "SolverError",
    "SurrogateError",
    "__version__",
]
