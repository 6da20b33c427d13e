"""Acquisition: LogEI for one candidate per round, qLogEI for batches (minimising the loss)."""

from __future__ import annotations

import warnings

import numpy as np
import torch
from botorch.acquisition import LogExpectedImprovement, qLogExpectedImprovement
from botorch.acquisition.objective import GenericMCObjective
from botorch.optim import optimize_acqf
from botorch.sampling import SobolQMCNormalSampler
from numpy.typing import NDArray

from smcbayes.errors import SurrogateError
from smcbayes.surrogate.gp import DTYPE, Surrogate

Array = NDArray[np.float64]


def _negate(samples: torch.Tensor, X: torch.Tensor | None = None) -> torch.Tensor:
    return -samples[..., 0]


def propose(surrogate: Surrogate, q: int, seed: int, restarts: int = 8,
            raw_samples: int = 256, box: tuple[Array, Array] | None = None) -> tuple[Array, float]:
    """Maximise the log expected improvement below the best observed log(loss).

    Args:
        surrogate: the fitted GP of log(loss).
        q: number of candidates; ``q == 1`` uses analytic LogEI, ``q > 1`` joint qLogEI.
        seed: seeds the optimiser's raw samples and the quasi-Monte-Carlo sampler.
        restarts: gradient-based restarts of the optimiser.
        raw_samples: random points screened for the restarts.
        box: lower and upper corners ``(d,)`` of a sub-box of the unit cube to search in
            (a trust region); the whole cube if ``None``.

    Returns:
        candidates ``(q, d)`` in the unit cube, and the acquisition value (log scale).
    """
    if surrogate.rotation is not None:
        # the optimiser searches the model's own inputs, which a rotation moves off the cube
        raise SurrogateError("propose() needs a GP on unrotated unit-cube inputs")
    torch.manual_seed(seed)
    d = surrogate.x_unit.shape[1]
    best = float(np.min(surrogate.log_loss))
    if q == 1:
        acq = LogExpectedImprovement(surrogate.model, best_f=best, maximize=False)
    else:
        sampler = SobolQMCNormalSampler(sample_shape=torch.Size([256]), seed=seed)
        acq = qLogExpectedImprovement(surrogate.model, best_f=-best, sampler=sampler,
                                      objective=GenericMCObjective(_negate))
    lo, hi = (np.zeros(d), np.ones(d)) if box is None else box
    bounds = torch.as_tensor(np.stack([lo, hi]), dtype=DTYPE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        x, value = optimize_acqf(acq, bounds=bounds, q=q, num_restarts=restarts,
                                 raw_samples=raw_samples, options={"seed": seed})
    cand = np.clip(x.detach().numpy().reshape(q, d).astype(float), 0.0, 1.0)
    return cand, float(value.detach().reshape(-1)[0])
