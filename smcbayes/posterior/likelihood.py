"""Likelihood of the parameters emulated from the GP of log(loss).

Error model: the measured force of configuration k is the simulated force plus Gaussian
errors of unknown variance sigma_k^2.  With a Jeffreys prior p(sigma) ~ 1/sigma integrated
out, the likelihood of N_k independent points is proportional to SSE_k^(-N_k/2).  With one
GP for the global loss L = (1/p) sum_k MSE_k we use the global form with a common
variance,

    log p(data | psi) = -(N_eff / 2) * log L(psi) + const,

where N_eff counts *independent* points: the residuals of a press curve are strongly
autocorrelated (smooth model error, correlated sensor drift, the digitiser's pixel steps),
and using the raw number of resampled points would make the posterior absurdly narrow.

N_eff is estimated at the best calibrated point in two ways, and the smaller is used
(each can overstate it, in different situations):

* the sandwich (Godambe) argument of :func:`sandwich_points`: the pseudo-likelihood above
  is calibrated when its curvature matches the sampling variance of its score, which is
  computed from the residuals r_ki and the force sensitivities s_ki (central differences
  of the forward model), lag covariances included.  It weights the error correlation where
  each parameter acts, and it reduces to sum_k N_k for white residuals on curves of
  equal length.  It fails when the
  residuals are correlated over a whole curve (a systematic model error, as on the thesis
  press data): the lag sums then span the record, and at the optimum the score sums nearly
  cancel, so the score variance is underestimated and N_eff overstated (4205 against 23 on
  the 9 thesis configurations);
* sum_k N_k / tau_k, with tau_k the integrated autocorrelation time of the residual
  series of configuration k (Sokal's adaptive window, the estimator emcee uses for
  chains: tau = 1 + 2 sum_{t=1}^{M} rho(t) with the smallest window M >= c tau(M), c = 5).
  It overstates N_eff when the misfit concentrates where a parameter acts (the steep end
  of a closing), which the sandwich sees.  Its autocovariance is taken about zero, not
  about the record's mean: the error model says the residuals have mean zero, and a press
  curve lasts only a few correlation times of the force error (1.1 mm/s closes in about
  3 s against a drift correlated over 0.5 s), so subtracting the mean removes the
  low-frequency error power that makes neighbouring points redundant.

On synthetic white + Ornstein-Uhlenbeck force noise over three such closings (tested),
against the generalised-least-squares information of the raw samples, the centred
residual estimate overstated N_eff 1.6-fold, the estimate about zero by 3 % and the
sandwich estimate understated it by 22 % (medians; slightly conservative).

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
from scipy.stats import chi2

from smcbayes.errors import SurrogateError
from smcbayes.posterior.emulator import NumpyGP
from smcbayes.surrogate.gp import Surrogate

Array = NDArray[np.float64]


def integrated_autocorr_time(series: Array, c: float = 5.0, centred: bool = True) -> float:
    """Integrated autocorrelation time (in samples) of a 1-D series, >= 1.

    Args:
        series: shape ``(N,)``.
        c: Sokal's window constant.
        centred: autocovariance about the sample mean (a series whose mean is unknown, such
            as a chain); ``False``: about zero (a series whose mean is zero by assumption,
            such as residuals under the error model).
    """
    return _sokal(series, c, centred)[0]


def _sokal(series: Array, c: float, centred: bool) -> tuple[float, int]:
    """Integrated autocorrelation time and Sokal's window M (lags) of a 1-D series."""
    x = np.asarray(series, dtype=float)
    if centred:
        x = x - x.mean()
    n = x.size
    if n < 4 or not np.any(x):
        return 1.0, 0
    f = np.fft.rfft(x, n=2 * n)
    acf = np.fft.irfft(f * np.conjugate(f))[:n]
    acf /= acf[0]
    taus = 2.0 * np.cumsum(acf) - 1.0
    window = np.arange(n) < c * taus
    m = int(np.argmin(window)) if not window.all() else n - 1
    return float(max(taus[m], 1.0)), m


def effective_points(residuals: Sequence[Array], centred: bool = True) -> tuple[Array, Array]:
    """Integrated autocorrelation times and effective numbers of independent points.

    Args:
        residuals: one residual series per configuration, each ``(N_k,)`` on a uniform grid.
        centred: see :func:`integrated_autocorr_time`.

    Returns:
        ``(tau, n_eff)``, each ``(K,)``; n_eff_k = N_k / tau_k.
    """
    tau = np.array([integrated_autocorr_time(r, centred=centred) for r in residuals])
    n = np.array([np.asarray(r).size for r in residuals], dtype=float)
    return tau, n / tau


def sandwich_points(residuals: Sequence[Array], sensitivities: Sequence[Array], c: float = 5.0) -> float:
    """Global N_eff from the Godambe (sandwich) information of the pseudo-likelihood.

    The pseudo-likelihood l(psi) = -(N_eff / 2) log L(psi) is calibrated when its curvature
    equals the sampling variance of its score at the optimum.  With the Gauss-Newton
    curvature and the score's variance from the residuals, the magnitude adjustment of
    Pauli, Racugno and Ventura (Stat. Sinica 21, 2011), lambda = d / tr(H^-1 J), gives

        N_eff = d K L / tr(A^-1 B),
        A = sum_k (1/N_k) sum_i s_ki s_ki',     B = sum_k V_k / N_k^2,

    with K configurations of N_k points, residuals r_ki (measured - simulated, kN),
    sensitivities s_ki = d sim_ki / d psi (kN per unit of the sampled coordinates),
    L = (1/K) sum_k (1/N_k) sum_i r_ki^2 the loss, and V_k = sum_{|l| <= M} sum_i g_ki
    g_k,i+l' the variance of the sum of the score series g_ki = r_ki s_ki (lag products
    about zero over Sokal's window M of the residual series).  Unlike sum_k N_k / tau_k it
    weights the error correlation where each parameter acts (a parameter seen only in the
    last second of a curve gets
    that second's error structure).  With white residuals on curves of equal length it
    reduces to sum_k N_k (every curve is read on the same number of loss grid points).
    It is taken at the best calibrated point, not an exact optimum: a remaining mean score
    adds to B and lowers N_eff (the safe direction).
    Directions of A below 1e-8 of its largest eigenvalue (parameters the data do not
    see at all) are left out and d counts the rest.

    Args:
        residuals: per configuration ``(N_k,)``, kN.
        sensitivities: per configuration ``(N_k, d)``, kN per unit.
        c: Sokal's window constant.

    Returns:
        N_eff (> 0), or NaN when no direction is informed.
    """
    d = np.asarray(sensitivities[0]).shape[1]
    a, b, loss = np.zeros((d, d)), np.zeros((d, d)), 0.0
    for r, sens in zip(residuals, sensitivities, strict=True):
        r, sens = np.asarray(r, dtype=float), np.asarray(sens, dtype=float)
        n = r.size
        g = r[:, None] * sens
        v = g.T @ g
        for lag in range(1, _sokal(r, c, centred=False)[1] + 1):
            cross = g[:-lag].T @ g[lag:]
            v += cross + cross.T
        a += sens.T @ sens / n
        b += v / n**2
        loss += float(np.mean(r * r)) / len(residuals)
    evals, evecs = np.linalg.eigh(a)
    keep = evals > 1e-8 * max(float(evals.max()), 0.0)
    if not np.any(keep):
        return float("nan")
    proj = evecs[:, keep]
    trace = float(np.sum(np.diag(proj.T @ b @ proj) / evals[keep]))
    if not np.isfinite(trace) or trace <= 0:
        return float("nan")
    return float(keep.sum() * len(residuals) * loss / trace)


CAP_FLOOR_NATS = 15.0
"""The emulator's cap lies at least this many nats below the best: the closer the cap, the
closer to a narrow posterior the GP's targets drop to the plateau, and a GP overshoots
next to such a drop."""
PLATEAU_MASS = 1e-3
"""Share of a Gaussian posterior's mass that may lie beyond the start of the plateau."""
PLATEAU_MARGIN_NATS = 1.5
"""A capped GP's plateau begins this many nats below its cap (the GP mean scatters about
the capped value by about a nat)."""
PLATEAU_SLOPE = 10.0
"""Extra nats of log density per nat of emulated log-likelihood beyond the plateau's start."""


def cap_nats(dim: int) -> float:
    """Nats of log-likelihood below the best at which the emulator's targets are capped,
    for ``dim`` parameters: :data:`CAP_FLOOR_NATS`, or (from 9 parameters on) more, so that
    the plateau, which gets no density, starts beyond the drop that holds all but
    :data:`PLATEAU_MASS` of a Gaussian posterior's mass (its log density falls by
    chi^2_d / 2 from the mode) and truncates no more than that share of a posterior."""
    return max(CAP_FLOOR_NATS, 0.5 * float(chi2.ppf(1.0 - PLATEAU_MASS, dim)) + PLATEAU_MARGIN_NATS)


@dataclass
class EmulatedPosterior:
    """Log posterior densities on the unit cube from a GP of log(loss).

    A GP trained on targets capped ``cap_nats`` of log-likelihood below the best
    (:func:`smcbayes.posterior.active.fit_local`) only knows that its plateau lies at least
    that far below; the plateau covers most of the box, so at its face value (a density
    e^-cap of the peak's over a volume many times the posterior's) it can hold more mass
    than the posterior.  From :data:`PLATEAU_MARGIN_NATS` before the cap on, the log
    density therefore falls by a further :data:`PLATEAU_SLOPE` per nat (the plateau ends
    near e^-(cap + 15)), as the GPry sampler gives no density to the region its classifier
    puts below its threshold (Gammal, Schöneberg, Torrado & Fidler 2023, "Fast and robust
    Bayesian inference using Gaussian processes with GPry", JCAP 10, 021).  ``cap_nats``
    is in nats at this object's ``n_eff``, which must be the N_eff the targets were capped
    with (a tempered posterior takes ``cap_nats=None``).

    Attributes:
        surrogate: the fitted GP (targets: natural log of the loss).
        n_eff: effective number of independent points N_eff (global).
        functions: number S of GP sample functions in the mixture (0: the GP mean only).
        seed: seed of the sample functions.
        cap_nats: nats of log-likelihood below the best training target at which the GP's
            targets were capped, or ``None`` (uncapped, no plateau).
    """

    surrogate: Surrogate
    n_eff: float
    functions: int = 8
    seed: int = 0
    cap_nats: float | None = None

    def __post_init__(self) -> None:
        if not np.isfinite(self.n_eff) or self.n_eff <= 0:
            raise SurrogateError(f"effective number of points must be > 0, got {self.n_eff}")
        self.gp = NumpyGP.from_surrogate(self.surrogate)
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
        start = None if self.cap_nats is None else \
            a * float(np.min(self.surrogate.log_loss)) + self.cap_nats - PLATEAU_MARGIN_NATS

        def log_prob(u: Array) -> Array:
            u = np.atleast_2d(u)
            inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
            out = np.full(u.shape[0], -np.inf)
            if np.any(inside):
                nats = a * self.log_loss(u[inside], component)
                if start is not None:
                    nats = nats + PLATEAU_SLOPE * np.maximum(nats - start, 0.0)
                out[inside] = -nats
            return out

        return log_prob

    def log_likelihood(self, log_loss: Array) -> Array:
        """log p(data | psi) + const from log(loss) values (true or emulated)."""
        return -0.5 * self.n_eff * np.asarray(log_loss, dtype=float)
