"""Posterior draws as arviz InferenceData: summary table, diagnostics, correlations.

The mixture over GP sample functions is stored with one arviz chain per (component,
walker).  R-hat and ESS are computed within each component (its walkers as chains, the
usual treatment of an emcee ensemble); the worst component's R-hat is reported, and the
ESS summed over components (they are independent samplers of the pooled draws that the
quantiles come from).  Components differ on purpose (they are different plausible
emulators), so R-hat across them would measure emulator uncertainty, not sampler
convergence.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.errors import ConvergenceWarning, UnreliablePosteriorWarning
from smcbayes.forward.parameters import ParameterSpace
from smcbayes.posterior.sampler import Chains
from smcbayes.posterior.weights import weighted_moments, weighted_quantile

if TYPE_CHECKING:
    from smcbayes.posterior.correct import ImportanceSample

Array = NDArray[np.float64]
RHAT_WARN = 1.05
ESS_WARN = 200.0


@dataclass(frozen=True)
class ParameterSummary:
    """Posterior summary of one parameter (user units; quantiles 5/50/95 %).

    ``r_hat`` is that of emcee chains, NaN for an importance-weighted sample; ``ess`` is
    then the importance ESS.
    """

    name: str
    unit: str
    mean: float
    sd: float
    q05: float
    q50: float
    q95: float
    r_hat: float
    ess: float


def sampled_coordinates(space: ParameterSpace, theta: Array) -> tuple[Array, list[str]]:
    """Values in the sampled coordinates (log10 of log-searched parameters) and labels."""
    cols, labels = [], []
    for j, p in enumerate(space.free):
        cols.append(np.log10(theta[:, j]) if p.log else theta[:, j])
        labels.append(f"log10 {p.name}" if p.log else p.name)
    return np.column_stack(cols), labels


def stack_components(chains: Sequence[Chains]) -> tuple[Array, Array]:
    """Unit-cube draws of all components, ``(chains, draws, d)``, truncated to equal length."""
    draws = min(c.samples.shape[0] for c in chains)
    samples = np.concatenate([np.swapaxes(c.samples[-draws:], 0, 1) for c in chains], axis=0)
    logp = np.concatenate([np.swapaxes(c.log_prob[-draws:], 0, 1) for c in chains], axis=0)
    return samples, logp


def _chain_groups(space: ParameterSpace, chains: Sequence[Chains]
                  ) -> tuple[dict[str, Array], dict[str, Array], Array]:
    """Posterior and sample-stats dictionaries of the emcee chains (user units), arrays
    ``(chains, draws)``, and the component of each arviz chain ``(chains,)``."""
    unit, logp = stack_components(chains)
    n_chain, n_draw, d = unit.shape
    theta = space.from_unit(unit.reshape(-1, d)).reshape(n_chain, n_draw, d)
    posterior = {name: theta[..., j] for j, name in enumerate(space.free_names)}
    acceptance = np.concatenate([c.acceptance for c in chains])
    stats = {"lp": logp, "acceptance_fraction": np.repeat(acceptance[:, None], n_draw, axis=1)}
    component = np.repeat(np.arange(len(chains)), [c.samples.shape[1] for c in chains])
    return posterior, stats, component


def to_inference_data(space: ParameterSpace, chains: Sequence[Chains], attrs: dict[str, Any],
                      corrected: ImportanceSample | None = None, resampled: Array | None = None) -> Any:
    """arviz InferenceData with the posterior in user units and sampler statistics.

    Without a correction the ``posterior`` group holds the emcee chains of the emulated
    posterior.  With one (``corrected``, an
    :class:`~smcbayes.posterior.correct.ImportanceSample`, and ``resampled``, its
    equal-weight resample ``(R, d)`` in the unit cube) the ``posterior`` group is the
    resample (one chain, exact log posterior as ``lp``), the emcee chains move to the
    groups ``emulator_posterior`` and ``emulator_sample_stats``, and the weighted sample
    itself is in ``importance`` (parameters, ``log_weight`` Pareto-smoothed and normalised,
    ``log_target``, ``iteration``).
    """
    # arviz takes seconds to import; only the posterior stage needs it
    import arviz as az

    with warnings.catch_warnings():
        # arviz guesses the layout from the shapes and warns when an ensemble has more
        # walkers than draws; the arrays are (chain, draw) by construction
        warnings.simplefilter("ignore", UserWarning)
        return _inference_data(az, space, chains, attrs, corrected, resampled)


def _inference_data(az: Any, space: ParameterSpace, chains: Sequence[Chains], attrs: dict[str, Any],
                    corrected: ImportanceSample | None, resampled: Array | None) -> Any:
    posterior, stats, component = _chain_groups(space, chains)
    clean = {k: (float(v) if isinstance(v, np.floating) else v) for k, v in attrs.items()}
    if corrected is None:
        return az.from_dict(posterior=posterior, sample_stats=stats,
                            coords={"component": component}, attrs=clean)
    theta = space.from_unit(resampled)
    lp = corrected.log_target[_rows_of(corrected.unit, resampled)]
    idata = az.from_dict(posterior={n: theta[None, :, j] for j, n in enumerate(space.free_names)},
                         sample_stats={"lp": lp[None, :]}, attrs=clean)
    weighted = space.from_unit(np.clip(corrected.unit, 0.0, 1.0))
    importance = {n: weighted[None, :, j] for j, n in enumerate(space.free_names)}
    importance.update(log_weight=corrected.log_weight[None, :], log_target=corrected.log_target[None, :],
                      iteration=corrected.iteration[None, :].astype(float))
    idata.add_groups({"emulator_posterior": posterior, "emulator_sample_stats": stats,
                      "importance": importance}, coords={"component": component})
    return idata


def _rows_of(unit: Array, picked: Array) -> Array:
    """Row index in ``unit`` ``(N, d)`` of every row of ``picked`` ``(R, d)`` (resampled copies)."""
    lookup = {row.tobytes(): i for i, row in enumerate(unit)}
    return np.array([lookup[row.tobytes()] for row in picked], dtype=int)


def summarise(space: ParameterSpace, chains: Sequence[Chains]) -> list[ParameterSummary]:
    """Mean, sd, 5/50/95 % quantiles (pooled), the worst per-component R-hat and the ESS
    summed over components, all of the draws :func:`stack_components` keeps (each
    component cut to the shortest, so that each weighs the same)."""
    # arviz takes seconds to import; only the posterior stage needs it
    import arviz as az

    unit, _ = stack_components(chains)
    d = unit.shape[2]
    theta = space.from_unit(unit.reshape(-1, d))
    # from -inf, so that a component's NaN (chains that never moved) stays NaN, not converged
    rhat = np.full(d, -np.inf)
    ess = np.zeros(d)
    # per component, on the (equal-length) draws that make the pooled summary
    bounds = np.cumsum([0] + [c.samples.shape[1] for c in chains])
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        arr = unit[lo:hi]  # (walkers, draws, d)
        for j in range(d):
            value = float(az.rhat(arr[..., j]))
            rhat[j] = np.nan if np.isnan(value) or np.isnan(rhat[j]) else max(rhat[j], value)
            ess[j] += float(az.ess(arr[..., j]))
    out = []
    for j, p in enumerate(space.free):
        col = theta[:, j]
        q = np.quantile(col, [0.05, 0.5, 0.95])
        out.append(ParameterSummary(p.name, p.unit, float(col.mean()), float(col.std()),
                                    float(q[0]), float(q[1]), float(q[2]), rhat[j], ess[j]))
    return out


def summarise_weighted(space: ParameterSpace, unit: Array, weights: Array,
                       ess: float) -> list[ParameterSummary]:
    """Summary of a weighted sample (the importance-corrected posterior).

    Its R-hat is NaN: no chain made the sample, whose reliability its Pareto k-hat and
    importance ESS judge (the R-hat of the chains that seeded the proposal belongs to
    their own summary, :func:`summarise`).

    Args:
        unit: points in the unit cube, ``(N, d)``.
        weights: normalised importance weights, ``(N,)``.
        ess: importance effective sample size (the same for every parameter).
    """
    theta = space.from_unit(unit)
    mean, sd, _ = weighted_moments(theta, weights)
    out = []
    for j, p in enumerate(space.free):
        q = weighted_quantile(theta[:, j], weights, [0.05, 0.5, 0.95])
        # the one shared NaN object: a dataclass compares its fields as a tuple, which checks
        # identity before equality, so equal tables still compare equal (nan == nan is False)
        out.append(ParameterSummary(p.name, p.unit, float(mean[j]), float(sd[j]), float(q[0]), float(q[1]),
                                    float(q[2]), np.nan, float(ess)))
    return out


def correlations(space: ParameterSpace, theta: Array, top: int = 3, threshold: float = 0.3,
                 weights: Array | None = None) -> tuple[Array, list[str], list[tuple[str, str, float]]]:
    """Correlation matrix in sampled coordinates and the strongest pairs (|r| >= threshold).

    Args:
        theta: draws in user units, ``(N, d)``.
        weights: normalised importance weights ``(N,)``, or None for equal weights.

    Returns:
        ``(matrix (d, d), labels, [(name_i, name_j, r), ...])`` strongest first.
    """
    x, labels = sampled_coordinates(space, theta)
    if x.shape[1] < 2:
        return np.ones((1, 1)), labels, []
    if weights is None:
        r = np.corrcoef(x, rowvar=False)
    else:
        r = weighted_moments(x, weights)[2]
    pairs = [(space.free_names[i], space.free_names[j], float(r[i, j]))
             for i in range(r.shape[0]) for j in range(i + 1, r.shape[0])]
    pairs = [pq for pq in sorted(pairs, key=lambda t: -abs(t[2])) if abs(pq[2]) >= threshold]
    return r, labels, pairs[:top]


def warnings_for(summary: Sequence[ParameterSummary], chains: Sequence[Chains], warn: bool = True,
                 prefix: str = "", stacklevel: int = 2) -> list[str]:
    """Plain-language warnings about the convergence and sampling quality of the emcee chains.

    The one place these conditions are turned into words and into warnings: an R-hat above
    :data:`RHAT_WARN`, the autocorrelation stopping rule not met and a median acceptance
    fraction outside 0.1-0.8 give a :class:`~smcbayes.errors.ConvergenceWarning`, fewer than
    :data:`ESS_WARN` effective samples an :class:`~smcbayes.errors.UnreliablePosteriorWarning`.

    Args:
        summary: the emulator's parameter summaries (R-hat, ESS).
        chains: the ensembles they come from (stopping rule, acceptance).
        warn: also emit each message with :func:`warnings.warn` (``False``: only return them).
        prefix: put before every message, e.g. ``"emulator chains (proposal of the
            correction): "`` when the chains are not the reported posterior.
        stacklevel: passed to :func:`warnings.warn` (2: the caller of this function).
    """
    out: list[tuple[str, type[Warning]]] = []
    for s in summary:
        if not np.isfinite(s.r_hat) or s.r_hat > RHAT_WARN:
            out.append((f"{s.name}: R-hat {s.r_hat:.3f} > {RHAT_WARN}: the walkers disagree; "
                        "run longer (--steps) or refine the emulator (--refine)", ConvergenceWarning))
        if s.ess < ESS_WARN:
            out.append((f"{s.name}: only {s.ess:.0f} effective samples (< {ESS_WARN:.0f}); "
                        "quantiles are rough, run longer (--steps)", UnreliablePosteriorWarning))
    if not all(c.converged for c in chains):
        out.append(("the autocorrelation-time stopping rule was not met within --steps "
                    "(chains shorter than 50 autocorrelation times)", ConvergenceWarning))
    acc = np.concatenate([c.acceptance for c in chains])
    if np.median(acc) < 0.1 or np.median(acc) > 0.8:
        out.append((f"median acceptance fraction {np.median(acc):.2f} is outside 0.1-0.8",
                    ConvergenceWarning))
    if warn:
        for msg, kind in out:
            warnings.warn(prefix + msg, kind, stacklevel=stacklevel)
    return [prefix + msg for msg, _ in out]
