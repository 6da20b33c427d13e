"""Gaussian-process surrogate of log(loss) over the unit cube (BoTorch SingleTaskGP).

Inputs are the free parameters mapped to ``[0, 1]^d`` by
:meth:`~smcbayes.forward.parameters.ParameterSpace.to_unit` (tau*, B and tau_c in log10);
the target is ``log(loss)`` (natural log, loss in kN^2), standardised by the model's
outcome transform.  The state file (``gp.pt``) keeps the torch ``state_dict``, the
training data, the kernel name and the input rotation (if any), so that
:func:`load_surrogate` rebuilds the same posterior.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gpytorch
import numba
import numpy as np
import torch
from botorch.exceptions import ModelFittingError
from botorch.fit import fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.transforms.outcome import Standardize
from botorch.models.utils.gpytorch_modules import get_covar_module_with_dim_scaled_prior
from gpytorch.mlls import ExactMarginalLogLikelihood
from gpytorch.utils.warnings import NumericalWarning
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from smcbayes.errors import SurrogateError

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]
KERNELS = ("rbf", "matern52")
DTYPE = torch.float64
MAX_CHOLESKY = 5000
"""Largest training set solved by Cholesky.  gpytorch's default (800) switches larger sets
to conjugate gradients with a stochastic log-determinant, which for the posterior stage's
800-900 points is slower and makes the fitted hyperparameters depend on torch's random
state."""


@contextmanager
def gp_session(threads: int = 1) -> Iterator[None]:
    """Run torch and the BLAS libraries numpy and scipy load with ``threads`` threads,
    Cholesky solves up to :data:`MAX_CHOLESKY` points and without gpytorch's noise warnings.

    GPs of a few hundred points are fastest on one thread, and on a loaded machine torch's
    spinning thread pool makes them up to ten times slower.  The emulators' predictions
    are small products too (the emcee samplers ask for 16 rows at a time): with two BLAS
    threads the variance of 16 rows of a 735-point curve emulator took 3.5 times as long
    as with one.  One thread also makes the results independent of the machine's cores.
    numba's compiled kernels may share large calls out over every core, with the same
    values whatever their number.
    A small fixed noise is deliberate (deterministic simulator); gpytorch's floor of 1e-6
    in standardised units applies and its warning about it would flood the terminal.
    """
    # numba's threads share torch's OpenMP runtime: started later, by the first threaded
    # kernel call in the session, they would set torch's threads to every core
    numba.get_num_threads()
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        with (warnings.catch_warnings(), gpytorch.settings.max_cholesky_size(MAX_CHOLESKY),
              threadpool_limits(limits=threads, user_api="blas")):
            warnings.simplefilter("ignore", NumericalWarning)
            yield
    finally:
        torch.set_num_threads(previous)


@dataclass
class Surrogate:
    """A fitted GP and its training data.

    Attributes:
        model: the BoTorch model (posterior in log-loss units); its inputs are
            ``features(x_unit)``, not ``x_unit`` itself when ``rotation`` is set.
        x_unit: training inputs, shape ``(N, d)``, unit cube.
        log_loss: training targets, shape ``(N,)``, natural log of the loss (kN^2).
        kernel: ``rbf`` or ``matern52``.
        fitted: False if hyperparameter fitting failed and priors' modes were kept.
        noise: the fixed noise variance, or ``None`` if the noise was fitted.
        rotation: orthogonal ``(d, d)`` matrix R: the GP's inputs are ``x_unit @ R`` (its
            ARD lengthscales act along the columns of R), or ``None``: the unit cube's axes.
    """

    model: SingleTaskGP
    x_unit: Array
    log_loss: Array
    kernel: str
    fitted: bool = True
    noise: float | None = None
    rotation: Array | None = None

    def features(self, x_unit: Array) -> Array:
        """The GP's inputs ``(M, d)`` at unit-cube points ``(M, d)``."""
        return rotate(x_unit, self.rotation)

    def predict(self, x_unit: Array) -> tuple[Array, Array]:
        """Posterior mean and standard deviation of log(loss) at ``x_unit`` ``(M, d)``; ``(M,)`` each."""
        x = torch.as_tensor(self.features(x_unit), dtype=DTYPE)
        self.model.eval()
        with torch.no_grad(), gpytorch.settings.max_cholesky_size(MAX_CHOLESKY):
            post = self.model.posterior(x)
            mean = post.mean.squeeze(-1).numpy()
            std = post.variance.clamp_min(0).sqrt().squeeze(-1).numpy()
        return mean.astype(float), std.astype(float)


def rotate(x_unit: Array, rotation: Array | None) -> Array:
    """``x_unit @ rotation`` ``(M, d)`` (unchanged when ``rotation`` is ``None``)."""
    x = np.atleast_2d(np.asarray(x_unit, dtype=float))
    return x if rotation is None else x @ rotation


def build_model(x_unit: Array, log_loss: Array, kernel: str, noise: float | None = None) -> SingleTaskGP:
    """An unfitted SingleTaskGP on the given data with the chosen kernel.

    Args:
        noise: fixed observation-noise variance of log(loss); ``None`` fits a noise term.
            A deterministic simulator's small noise falls below gpytorch's floor of 1e-6 in
            standardised units; the floor applies and its warning is not passed on (see
            :func:`gp_session`).
    """
    if kernel not in KERNELS:
        raise SurrogateError(f"unknown kernel '{kernel}'; accepted: {', '.join(KERNELS)}")
    x = torch.as_tensor(x_unit, dtype=DTYPE)
    y = torch.as_tensor(log_loss, dtype=DTYPE).reshape(-1, 1)
    covar = get_covar_module_with_dim_scaled_prior(ard_num_dims=x.shape[-1],
                                                   use_rbf_kernel=kernel == "rbf")
    yvar = None if noise is None else torch.full_like(y, noise)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumericalWarning)
        return SingleTaskGP(x, y, train_Yvar=yvar, covar_module=covar, outcome_transform=Standardize(m=1))


def hyperparameters(model: SingleTaskGP) -> dict[str, torch.Tensor]:
    """The fitted part of ``model``'s state (kernel, mean, noise), without the outcome
    transform, which belongs to the training targets."""
    return {k: v for k, v in model.state_dict().items() if not k.startswith("outcome_transform")}


def matched_axes(old: Array | None, new: Array | None, d: int, min_overlap: float = 0.8) -> Array | None:
    """For each column of the rotation ``new`` ``(d, d)`` the column of ``old`` it continues
    (``None`` = the cube's axes), or ``None`` when some axis has no partner with
    ``|cos| >= min_overlap`` or two share one (the axes turned too far for the old
    lengthscales to mean anything along the new ones)."""
    overlap = np.abs((np.eye(d) if old is None else old).T @ (np.eye(d) if new is None else new))
    partner = np.argmax(overlap, axis=0)
    if len(set(partner.tolist())) < d or np.min(overlap[partner, np.arange(d)]) < min_overlap:
        return None
    return partner


def warm_start(model: SingleTaskGP, start: Surrogate, kernel: str, noise: float | None,
               rotation: Array | None) -> bool:
    """Load the hyperparameters of ``start`` into the unfitted ``model`` (whose inputs are
    rotated by ``rotation``), its ARD lengthscales carried to the matching axes; returns
    False and leaves the model as built when the kernel, the noise model or the axes do
    not match."""
    d = model.train_inputs[0].shape[-1]
    partner = matched_axes(start.rotation, rotation, d)
    if start.kernel != kernel or start.noise != noise or partner is None:
        logger.debug("GP fit without warm start: kernel, noise model or input axes changed")
        return False
    state = {**model.state_dict(), **hyperparameters(start.model)}
    key = "covar_module.raw_lengthscale"
    state[key] = state[key][..., torch.as_tensor(partner)]
    model.load_state_dict(state)
    return True


def fit_surrogate(x_unit: Array, log_loss: Array, kernel: str, seed: int,
                  noise: float | None = None, rotation: Array | None = None,
                  start: Surrogate | None = None) -> Surrogate:
    """Fit the GP's hyperparameters by maximum marginal likelihood.

    Args:
        x_unit: inputs ``(N, d)`` in the unit cube.
        log_loss: targets ``(N,)``, finite.
        kernel: ``rbf`` (squared exponential, as in the thesis) or ``matern52``.
        seed: torch seed for the fitting restarts.
        noise: fixed noise variance of log(loss) (deterministic simulators: small, e.g.
            1e-6); ``None`` fits a noise term as the thesis did.
        rotation: orthogonal ``(d, d)`` matrix; the kernel acts on ``x_unit @ rotation``
            (see :class:`Surrogate`); ``None``: on ``x_unit``.
        start: a GP of the same kernel whose hyperparameters start the fit (a warm start
            from a fit on fewer points converges in about half the iterations).
    """
    if x_unit.shape[0] < 2 or not np.all(np.isfinite(log_loss)):
        raise SurrogateError("the GP needs at least 2 finite training targets")
    torch.manual_seed(seed)
    inputs = rotate(x_unit, rotation)
    model = build_model(inputs, log_loss, kernel, noise)
    if start is not None:
        warm_start(model, start, kernel, noise, rotation)
    mll = ExactMarginalLogLikelihood(model.likelihood, model)
    fitted = True
    with warnings.catch_warnings(), gpytorch.settings.max_cholesky_size(MAX_CHOLESKY):
        warnings.simplefilter("ignore")
        try:
            fit_gpytorch_mll(mll)
        except ModelFittingError:
            fitted = False
            model = build_model(inputs, log_loss, kernel, noise)
    model.eval()
    return Surrogate(model, np.asarray(x_unit, float), np.asarray(log_loss, float), kernel, fitted,
                     noise, None if rotation is None else np.asarray(rotation, float))


def condition_surrogate(surrogate: Surrogate, x_unit: Array, log_loss: Array) -> Surrogate:
    """The GP of ``surrogate`` (hyperparameters, kernel, noise, rotation) conditioned on new
    training data ``x_unit`` ``(N, d)``, ``log_loss`` ``(N,)`` without refitting.

    One Cholesky factorisation instead of a hyperparameter fit (tens of marginal-likelihood
    gradients, each a few times the cost of the factorisation).  The new targets are
    standardised with the fitted GP's own mean and scale, so that its mean, variance and
    noise keep their values in log-loss units.
    """
    if x_unit.shape[0] < 2 or not np.all(np.isfinite(log_loss)):
        raise SurrogateError("the GP needs at least 2 finite training targets")
    model = build_model(surrogate.features(x_unit), log_loss, surrogate.kernel, surrogate.noise)
    # BoTorch re-standardises the training targets with the loaded transform's statistics
    model.load_state_dict(surrogate.model.state_dict())
    model.eval()
    return Surrogate(model, np.asarray(x_unit, float), np.asarray(log_loss, float), surrogate.kernel,
                     surrogate.fitted, surrogate.noise, surrogate.rotation)


def save_surrogate(path: Path, surrogate: Surrogate, meta: dict[str, Any]) -> None:
    """Write ``gp.pt``: state dict, training data, kernel and ``meta`` (parameter names...)."""
    tmp = Path(path).with_suffix(".tmp")
    torch.save({
        "state_dict": surrogate.model.state_dict(),
        "train_x_unit": torch.as_tensor(surrogate.x_unit, dtype=DTYPE),
        "train_log_loss": torch.as_tensor(surrogate.log_loss, dtype=DTYPE),
        "kernel": surrogate.kernel,
        "fitted": surrogate.fitted,
        "noise": surrogate.noise,
        "rotation": None if surrogate.rotation is None else torch.as_tensor(surrogate.rotation, dtype=DTYPE),
        "target": "natural log of the loss (kN^2)",
        "meta": meta,
    }, tmp)
    tmp.replace(path)


def load_surrogate(path: str | Path) -> tuple[Surrogate, dict[str, Any]]:
    """Rebuild the surrogate saved by :func:`save_surrogate`; returns it and its ``meta``."""
    path = Path(path)
    if not path.is_file():
        raise SurrogateError(f"{path}: GP state not found (run `smcbayes calibrate` first)")
    state = torch.load(path, weights_only=False)
    x = state["train_x_unit"].numpy()
    y = state["train_log_loss"].numpy()
    noise = state.get("noise")
    rotation = state.get("rotation")
    rotation = None if rotation is None else rotation.numpy()
    model = build_model(rotate(x, rotation), y, state["kernel"], noise)
    model.load_state_dict(state["state_dict"])
    model.eval()
    surrogate = Surrogate(model, x, y, state["kernel"], bool(state.get("fitted", True)), noise, rotation)
    return surrogate, state["meta"]
