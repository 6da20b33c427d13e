"""A NumPy copy of the calibration GP for fast repeated evaluation inside MCMC.

The fitted BoTorch model (constant mean, RBF or Matern-5/2 kernel with ARD lengthscales
and unit outputscale on standardised targets, Gaussian noise, ``Standardize`` outcome
transform) is copied into plain arrays: the posterior mean costs one kernel row per point.

Sample functions use pathwise conditioning (Wilson et al., "Efficiently sampling
functions from Gaussian process posteriors", ICML 2020): a prior sample from F random
Fourier features (Rahimi & Recht; frequencies from the kernel's spectral density, normal
for RBF and Student-t with 2 nu = 5 degrees of freedom for Matern-5/2), corrected by the
Matheron update f_post(x) = f_prior(x) + k(x, X) (K + s^2 I)^(-1) (y - f_prior(X) - eps),
eps ~ N(0, s^2 I).  Each sample is a consistent function that can be evaluated anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_solve, solve_triangular

from smcbayes.errors import SurrogateError
from smcbayes.surrogate.gp import rotate

if TYPE_CHECKING:
    from smcbayes.surrogate.gp import Surrogate

Array = NDArray[np.float64]


def _kernel(kind: str, x: Array, z: Array, lengthscale: Array) -> Array:
    """k(x, z) with unit outputscale; ``x`` ``(n, d)``, ``z`` ``(m, d)`` -> ``(n, m)``."""
    a, b = x / lengthscale, z / lengthscale
    sq = np.maximum((a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T, 0.0)
    if kind == "rbf":
        return np.exp(-0.5 * sq)
    r = np.sqrt(5.0 * sq)
    return (1.0 + r + r * r / 3.0) * np.exp(-r)


@dataclass
class NumpyGP:
    """Posterior of log(loss) in plain arrays (targets in original, unstandardised units).

    Attributes:
        kind: ``rbf`` or ``matern52``.
        x: training inputs of the kernel, ``(N, d)`` (unit cube, rotated by ``rotation``).
        lengthscale: ``(d,)``.
        mean_const, noise: constant mean and noise variance (standardised units).
        y_mean, y_std: the outcome standardisation.
        alpha: (K + s^2 I)^-1 (y - c), ``(N,)``.
        chol: Cholesky factor of K + s^2 I, ``(N, N)``.
        y: standardised targets, ``(N,)``.
        rotation: orthogonal ``(d, d)`` matrix; the kernel acts on ``u @ rotation`` (``x`` is
            stored rotated), or ``None``.
    """

    kind: str
    x: Array
    lengthscale: Array
    mean_const: float
    noise: float
    y_mean: float
    y_std: float
    alpha: Array
    chol: Array
    y: Array
    rotation: Array | None = None

    @classmethod
    def from_surrogate(cls, surrogate: Surrogate) -> NumpyGP:
        """Copy a :class:`~smcbayes.surrogate.gp.Surrogate`, its input rotation included."""
        gp = cls.from_botorch(surrogate.model)
        gp.rotation = surrogate.rotation
        return gp

    def features(self, u: Array) -> Array:
        """The kernel's inputs ``(W, d)`` at unit-cube points ``u`` ``(W, d)``."""
        return rotate(u, self.rotation)

    @classmethod
    def from_botorch(cls, model) -> NumpyGP:
        """Copy a fitted SingleTaskGP (no input transform, Standardize outcome transform); its
        inputs are the model's own (use :meth:`from_surrogate` for a rotated surrogate)."""
        cov = model.covar_module
        name = type(cov).__name__
        if name == "RBFKernel":
            kind = "rbf"
        elif name == "MaternKernel" and abs(float(cov.nu) - 2.5) < 1e-12:
            kind = "matern52"
        else:
            raise SurrogateError(f"the posterior emulator supports RBF and Matern-5/2 kernels, not {name}")
        x = model.train_inputs[0].detach().numpy().astype(float)
        y = model.train_targets.detach().numpy().astype(float)
        ls = cov.lengthscale.detach().numpy().reshape(-1).astype(float)
        c = float(model.mean_module.constant.detach())
        noise = float(model.likelihood.noise.detach().reshape(-1)[0])
        ot = model.outcome_transform
        K = _kernel(kind, x, x, ls) + noise * np.eye(x.shape[0])
        chol = np.linalg.cholesky(K + 1e-10 * np.eye(x.shape[0]))
        alpha = cho_solve((chol, True), y - c, check_finite=False)
        return cls(kind, x, ls, c, noise, float(ot.means.reshape(-1)[0]), float(ot.stdvs.reshape(-1)[0]),
                   alpha, chol, y)

    def mean(self, u: Array) -> Array:
        """Posterior mean of log(loss) at ``u`` ``(W, d)``, ``(W,)``."""
        k = _kernel(self.kind, self.features(u), self.x, self.lengthscale)
        return (self.mean_const + k @ self.alpha) * self.y_std + self.y_mean

    def std(self, u: Array) -> Array:
        """Posterior standard deviation of the latent log(loss), ``(W,)``."""
        k = _kernel(self.kind, self.features(u), self.x, self.lengthscale)
        v = solve_triangular(self.chol, k.T, lower=True, check_finite=False)
        return np.sqrt(np.maximum(1.0 - (v * v).sum(0), 0.0)) * self.y_std

    def predict(self, u: Array) -> tuple[Array, Array]:
        """Posterior mean and standard deviation of log(loss) at ``u`` ``(W, d)``, ``(W,)``
        each: :meth:`smcbayes.surrogate.gp.Surrogate.predict` without torch's overhead, for
        the thousands of candidates of an active-learning round."""
        return self.mean(u), self.std(u)

    def sample_functions(self, count: int, rng: np.random.Generator, features: int = 2048) -> PathSamples:
        """``count`` posterior sample functions (pathwise conditioning)."""
        d = self.x.shape[1]
        z = rng.standard_normal((count, features, d))
        if self.kind == "matern52":
            z = z * np.sqrt(5.0 / rng.chisquare(5.0, size=(count, features, 1)))
        omega = z / self.lengthscale
        phase = rng.uniform(0.0, 2.0 * np.pi, size=(count, features))
        w = rng.standard_normal((count, features))
        paths = PathSamples(self, omega, phase, w, np.zeros((count, self.x.shape[0])))
        prior_at_x = paths.prior(self.x)  # (count, N)
        eps = np.sqrt(self.noise) * rng.standard_normal(prior_at_x.shape)
        resid = (self.y - self.mean_const)[None, :] - prior_at_x - eps
        paths.update = cho_solve((self.chol, True), resid.T, check_finite=False).T
        return paths


@dataclass
class PathSamples:
    """Sample functions of a :class:`NumpyGP` posterior."""

    gp: NumpyGP
    omega: Array   # (S, F, d)
    phase: Array   # (S, F)
    weight: Array  # (S, F)
    update: Array  # (S, N)

    @property
    def count(self) -> int:
        return self.omega.shape[0]

    def prior(self, u: Array, which: int | None = None) -> Array:
        """Prior part (standardised, zero mean) at kernel inputs ``u`` ``(W, d)`` (rotated, see
        :meth:`NumpyGP.features`): ``(S, W)`` or ``(W,)``."""
        F = self.omega.shape[1]
        idx = range(self.count) if which is None else [which]
        out = np.stack([np.cos(u @ self.omega[s].T + self.phase[s]) @ self.weight[s] for s in idx])
        out *= np.sqrt(2.0 / F)
        return out if which is None else out[0]

    def __call__(self, u: Array, which: int) -> Array:
        """Sample function ``which`` of log(loss) (original units) at ``u`` ``(W, d)``."""
        u = self.gp.features(u)
        k = _kernel(self.gp.kind, u, self.gp.x, self.gp.lengthscale)
        f = self.gp.mean_const + self.prior(u, which) + k @ self.update[which]
        return f * self.gp.y_std + self.gp.y_mean
