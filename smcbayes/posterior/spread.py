"""How far the emulator's own uncertainty moves the posterior.

The emulated posterior uses the GP mean of the log-likelihood.  Where the GP is unsure, a
GP sample function (a log-likelihood the GP finds as plausible as its mean) gives another
posterior.  If those posteriors differ from the GP mean's by more than the accuracy
aimed at, the data spent on the emulator do not determine the posterior yet, whatever the
error at the reported posterior's own draws says: that error cannot see a tail or an arm
that the GP mean rates too low, while a sample function that rates it higher extends the
posterior into it.  The check costs no forward run, only chains on a few sample
functions (the same functions as the mixture of Kandasamy, Schneider & Poczos 2017,
"Query efficient posterior estimation in scientific experiments via Bayesian active
learning", Artificial Intelligence 243, and of PyVBMC's posterior uncertainty,
Acerbi 2018).  The stage then pools those functions' posteriors with the GP mean's into the
reported posterior, so the same uncertainty that the check measures also widens the result.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

SPREAD_FUNCTIONS = 4
"""GP sample functions whose posteriors are compared with the reported one."""
SPREAD_MAX = 0.10
"""Largest quantile shift (share of the prior range) the emulator's uncertainty may cause
for the posterior to count as determined: the accuracy the synthetic benchmark asks of the
posterior's 5/50/95 % quantiles."""
QUANTILES = (0.05, 0.5, 0.95)


def quantile_shifts(reported_unit: Array, function_draws: Sequence[Array]) -> Array:
    """Largest |quantile difference| per parameter ``(d,)`` (unit cube, i.e. share of the
    prior range) between the reported draws ``(N, d)`` and each sample function's draws
    ``(M_k, d)``, over the 5/50/95 % quantiles and the functions."""
    ref = np.quantile(reported_unit, QUANTILES, axis=0)
    shifts = [np.max(np.abs(np.quantile(d, QUANTILES, axis=0) - ref), axis=0) for d in function_draws]
    return np.max(np.array(shifts), axis=0)


def emulator_spread(reported_unit: Array, control_unit: Array, function_draws: Sequence[Array],
                    names: Sequence[str], steps: int) -> dict[str, Any]:
    """Quantile shifts of the posteriors of GP sample functions against the reported
    posterior, less the shift of a control chain on the GP mean sampled like the
    functions' chains (the chains' own sampling noise).

    Args:
        reported_unit: the reported posterior's draws ``(N, d)``, unit cube.
        control_unit: draws ``(M, d)`` of the GP mean's posterior from a chain of at most ``steps``.
        function_draws: one unit-cube sample ``(M_k, d)`` per GP sample function, from chains
            of at most ``steps``.
        names: the free parameters' names, ``d`` of them.

    Returns:
        ``{"functions", "steps", "max_quantile_shift", "per_parameter": {name: shift},
        "sampling_noise": {name: shift of the control chain}}``, the shifts net of the noise.
    """
    noise = quantile_shifts(reported_unit, [control_unit])
    shifts = np.maximum(quantile_shifts(reported_unit, function_draws) - noise, 0.0)
    return {"functions": len(function_draws), "steps": int(steps),
            "max_quantile_shift": float(np.max(shifts)),
            "per_parameter": {n: float(v) for n, v in zip(names, shifts, strict=True)},
            "sampling_noise": {n: float(v) for n, v in zip(names, noise, strict=True)}}


def share_words(spread: dict[str, Any], noun: str = "") -> str:
    """The share of sample functions a spread below 1 leaves out, in words ("one in 10",
    or with ``noun`` "GP sample function ", "one GP sample function in 10")."""
    return f"one {noun}in {1.0 / (1.0 - spread.get('shift_level', 1.0)):.0f}"


def pooled_words(spread: dict[str, Any]) -> str:
    """How far pooling the sample functions' posteriors moved the reported posterior
    (``pooled_shift`` of a curve emulator's spread), or "" when not recorded."""
    moved = spread.get("pooled_shift")
    return "" if moved is None else f"moving a 5/50/95 % quantile by up to {moved:.2g} of its range"


def spread_words(spread: dict[str, Any]) -> str:
    """A spread record (:func:`emulator_spread`, or the curve emulator's, which bounds the
    move of all but a share ``1 - shift_level`` of its functions and has a standard error
    over its supports) in words, for the terminal and the report."""
    level, count = spread.get("shift_level", 1.0), spread.get("functions") or 0
    shift, se = spread.get("max_quantile_shift"), spread.get("max_quantile_shift_se")
    amount = "n/a" if shift is None else f"{shift:.2f}"
    error = ""
    if shift is not None and se is not None:
        amount = f"{shift:.3f}"
        error = f" (standard error {se:.3f} over its {spread.get('supports')} supports)"
    # the log-loss emulator's spread is net of its chains' noise; the curve emulator's
    # functions share the mean's points, so there is none to take off
    noise = " beyond the chains' own noise" if spread.get("steps") else ""
    if level >= 1.0:
        return (f"the posteriors of {count} GP sample functions move a 5/50/95 % quantile by up to "
                f"{amount} of its range{noise}{error}")
    return (f"for each parameter and 5/50/95 % quantile, all but {share_words(spread)} of {count} GP "
            f"sample functions' posteriors move it by at most {amount} of its range{noise}{error}")
