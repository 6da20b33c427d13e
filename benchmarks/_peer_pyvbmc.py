"""PyVBMC as a peer of the posterior stage on the accuracy benchmark's exact target.

Variational Bayesian Monte Carlo (Acerbi 2018, NeurIPS; Huggins et al. 2023, "PyVBMC:
Efficient Bayesian inference in Python", JOSS 8(86) 5428): a GP surrogate of the log joint
density trained by active sampling and a variational Gaussian mixture.  It is given the
target of the benchmark's reference, -(N_eff/2) log L(u) on the unit cube u of the sampled
coordinates (uniform prior, so the log joint is the log-likelihood), one forward run per
evaluation, the calibrated best point as its start, the cube as its hard bounds and
[0.05, 0.95] as its plausible bounds.  Optional: ``pip install -e .[bench]``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np


def run_pyvbmc(log_post: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, budget: int, seed: int,
               draws: int = 20000) -> tuple[np.ndarray, dict[str, Any]]:
    """Run PyVBMC with at most ``budget`` evaluations of ``log_post`` (``(P, d) -> (P,)``).

    Returns draws of its variational posterior ``(draws, d)`` (unit cube) and a record:
    evaluations, its own convergence verdict, ELBO and its sd, seconds.
    """
    try:
        from pyvbmc import VBMC
    except ImportError as err:  # an optional peer, not a dependency of the library
        raise SystemExit("--peer pyvbmc needs PyVBMC: pip install -e '.[bench]'") from err
    d = x0.size
    calls = {"n": 0}

    def log_density(x: np.ndarray) -> float:
        calls["n"] += 1
        value = float(log_post(np.clip(np.atleast_2d(x), 0.0, 1.0))[0])
        return value if np.isfinite(value) else -1e10

    np.random.seed(seed)  # PyVBMC draws from NumPy's global generator
    start = time.perf_counter()
    lb, ub = np.zeros((1, d)), np.ones((1, d))
    plb, pub = np.full((1, d), 0.05), np.full((1, d), 0.95)
    x_start = np.clip(x0, 0.06, 0.94).reshape(1, d)
    vbmc = VBMC(log_density, x_start, lb, ub, plb, pub,
                options={"max_fun_evals": budget, "display": "off"})
    vp, results = vbmc.optimize()
    samples, _ = vp.sample(draws)
    record = {"evaluations": calls["n"], "budget": budget, "seed": seed,
              "success_flag": bool(results.get("success_flag", False)),
              "convergence_status": str(results.get("convergence_status", "")),
              "elbo": float(results.get("elbo", np.nan)), "elbo_sd": float(results.get("elbo_sd", np.nan)),
              "seconds": time.perf_counter() - start}
    return np.clip(samples, 0.0, 1.0), record
