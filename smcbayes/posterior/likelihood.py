"""Likelihood of the parameters emulated from the GP of log(loss).

Error model: the measured force of configuration k is the simulated force plus Gaussian
errors of unknown variance sigma_k^2.  With a Jeffreys prior p(sigma) ~ 1/sigma integrated
out, the likelihood of N_k independent points is proportional to SSE_k^(-N_k/2).  With one
GP for the global loss L = (1/p) sum_k MSE_k we use the global form with a common
variance,

    log p(data | psi) = -(N_eff / 2) * log L(psi) + const,

where N_eff = sum_k N_k / tau_k counts *independent* points: the residuals of a press
curve are strongly autocorrelated (smooth model error, correlated sensor drift, the
digitiser's pixel steps), and using the raw number of resampled points would make the
posterior absurdly narrow.  tau_k is the integrated autocorrelation time of the residual
series of configuration k at the best calibrated point, estimated with Sokal's adaptive
window (the estimator emcee uses for chains): tau = 1 + 2 sum_{t=1}^{M} rho(t) with the
smallest window M >= c tau(M), c = 5.

Emulator uncertainty: log L(psi) is known only through the GP, f ~ GP(mu, k).  Averaging
the likelihood over the GP's pointwise predictive distribution (a lognormal mean,
exp(-a mu + a^2 s^2 / 2) with a = N_eff/2 ~ 10^2) would reward the emulator's ignorance
with enormous weights.  Instead we average the *posterior* over the emulator: S sample
functions f_s are drawn from the GP (pathwise / Matheron samples, consistent at every
point), each gives a normalised posterior p_s(psi) ~ exp(-a f_s(psi)) prior(psi), and the
reported posterior is their equal-weight mixture, p(psi) = (1/S) sum_s p_s(psi).  Where the
GP is sure the mixture components agree; where it is not, they spread, widening the
posterior honestly.  ``--refine`` then adds forward evaluations where that matters.

Prior: uniform on the search box in the sampled coordinates, i.e. uniform in the unit
cube of :class:`~smcbayes.forward.parameters.ParameterSpace` (log-uniform for tau*, B,
tau_c).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.errors import SurrogateError
from smcbayes.posterior.emulator import NumpyGP
from smcbayes.surrogate.gp import Surrogate

Array = NDArray[np.float64]


def integrated_autocorr_time(series: Array, c: float = 5.0) -> float:
    """Integrated autocorrelation time (in samples) of a 1-D series, >= 1.

    Args:
        series: shape ``(N,)``.
        c: Sokal's window constant.
    """
    x = np.asarray(series, dtype=float)
    x = x - x.mean()
    n = x.size
    if n < 4 or not np.any(x):
        return 1.0
    f = np.fft.rfft(x, n=2 * n)
    acf = np.fft.irfft(f * np.conjugate(f))[:n]
    acf /= acf[0]
    taus = 2.0 * np.cumsum(acf) - 1.0
    window = np.arange(n) < c * taus
    m = int(np.argmin(window)) if not window.all() else n - 1
    return float(max(taus[m], 1.0))


def effective_points(residuals: Sequence[Array]) -> tuple[Array, Array]:
    """Integrated autocorrelation times and effective numbers of independent points.

    Args:
        residuals: one residual series per configuration, each ``(N_k,)`` on a uniform grid.

    Returns:
        ``(tau, n_eff)``, each ``(K,)``; n_eff_k = N_k / tau_k.
    """
    tau = np.array([integrated_autocorr_time(r) for r in residuals])
    n = np.array([np.asarray(r).size for r in residuals], dtype=float)
    return tau, n / tau


@dataclass
class EmulatedPosterior:
    """Log posterior densities on the unit cube from a GP of log(loss).

    Attributes:
        surrogate: the fitted GP (targets: natural log of the loss).
        n_eff: effective number of independent points N_eff (global).
        functions: number S of GP sample functions in the mixture (0: the GP mean only).
        seed: seed of the sample functions.
    """

    surrogate: Surrogate
    n_eff: float
    functions: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        if not np.isfinite(self.n_eff) or self.n_eff <= 0:
            raise SurrogateError(f"effective number of points must be > 0, got {self.n_eff}")
        self.gp = NumpyGP.from_botorch(self.surrogate.model)
        self._paths = None
        if self.functions > 0:
            self._paths = self.gp.sample_functions(self.functions, np.random.default_rng(self.seed))

    @property
    def components(self) -> int:
        """Number of mixture components (1 when the GP mean is used)."""
        return max(self.functions, 1)

    def log_loss(self, u: Array, component: int | None = None) -> Array:
        """Emulated log(loss) at ``u`` ``(W, d)``: sample function ``component`` or the mean."""
        u = np.atleast_2d(u)
        if self._paths is None or component is None:
            return self.gp.mean(u)
        return self._paths(u, component)

    def log_prob_fn(self, component: int | None) -> Callable[[Array], Array]:
        """Vectorised log posterior ``(W, d) -> (W,)`` of one mixture component."""
        a = 0.5 * self.n_eff

        def log_prob(u: Array) -> Array:
            u = np.atleast_2d(u)
            inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
            out = np.full(u.shape[0], -np.inf)
            if np.any(inside):
                out[inside] = -a * self.log_loss(u[inside], component)
            return out

        return log_prob

    def log_likelihood(self, log_loss: Array) -> Array:
        """log p(data | psi) + const from log(loss) values (true or emulated)."""
        return -0.5 * self.n_eff * np.asarray(log_loss, dtype=float)
