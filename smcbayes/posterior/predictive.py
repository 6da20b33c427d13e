"""Posterior predictive bands: posterior draws through the forward model.

For each configuration, the draws' force and ram-displacement curves are resampled on a
common time grid and summarised by their 5/25/50/75/95 % quantiles ("model" bands:
parameter uncertainty only).  The *predictive* bands add the measurement error: white
Gaussian noise with the per-configuration variance estimated by the mean squared error of
the best calibrated point (for configurations without data, the mean over the training
configurations).  Coverage is the share of measured points inside the predictive 50 % and
90 % bands.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.simulation.objective import Simulator

Array = NDArray[np.float64]
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)


@dataclass(frozen=True)
class Band:
    """Bands of one configuration.

    Attributes:
        config_id: configuration id.
        time_s: common time grid, ``(T,)``.
        force_kN, displacement_mm: model quantiles, ``(5, T)`` (5/25/50/75/95 %).
        force_pred_kN: predictive quantiles of force (with noise), ``(5, T)``.
        noise_kN: the noise standard deviation used.
        measured: measured ``(time_s, force_kN)`` or None.
        coverage50, coverage90: share of measured points inside the predictive bands (NaN
            without data).
        draws: number of successful draws.
    """

    config_id: str
    time_s: Array
    force_kN: Array
    displacement_mm: Array
    force_pred_kN: Array
    noise_kN: float
    measured: tuple[Array, Array] | None
    coverage50: float
    coverage90: float
    draws: int


def _curves_on_grid(time: Array, values: Array, grid: Array) -> Array:
    """Row-wise interpolation of ``(D, T)`` curves onto ``grid`` ``(G,)``, holding ends."""
    return np.stack([np.interp(grid, t, v) for t, v in zip(time, values, strict=True)])


def predictive_bands(model: Simulator, theta: Array, config_ids: Sequence[str],
                     measured: Mapping[str, tuple[Array, Array]], noise_kN: Mapping[str, float],
                     rng: np.random.Generator, grid_points: int = 300) -> dict[str, Band]:
    """Bands on ``config_ids`` from posterior draws ``theta`` ``(D, d)`` (user units)."""
    results = model.simulate(theta, config_ids)
    fallback = float(np.mean(list(noise_kN.values()))) if noise_kN else 0.0
    bands = {}
    for cid, res in results.items():
        ok = res.ok
        t_end = np.nanmax(res.switch_time_s[ok]) * 1.1 if np.any(ok) else 1.0
        if cid in measured:
            t_end = max(t_end, measured[cid][0][-1] * 1.02)
        grid = np.linspace(0.0, t_end, grid_points)
        sigma = float(noise_kN.get(cid, fallback))
        if not np.any(ok):  # every draw failed on this configuration: an empty band, said by draws = 0
            nan = np.full((len(QUANTILES), grid_points), np.nan)
            bands[cid] = Band(cid, grid, nan, nan.copy(), nan.copy(), sigma, measured.get(cid),
                              float("nan"), float("nan"), 0)
            continue
        force = _curves_on_grid(res.time_s[ok], res.force_kN[ok], grid)
        disp = _curves_on_grid(res.time_s[ok], res.displacement_mm[ok], grid)
        noisy = force + sigma * rng.standard_normal(force.shape)
        pred = np.quantile(noisy, QUANTILES, axis=0)
        cov50 = cov90 = float("nan")
        if cid in measured:
            tm, fm = measured[cid]
            inside = (tm <= grid[-1])
            lo90, lo50, hi50, hi90 = (np.interp(tm[inside], grid, pred[i]) for i in (0, 1, 3, 4))
            f = fm[inside]
            cov90 = float(np.mean((f >= lo90) & (f <= hi90)))
            cov50 = float(np.mean((f >= lo50) & (f <= hi50)))
        bands[cid] = Band(cid, grid, np.quantile(force, QUANTILES, axis=0),
                          np.quantile(disp, QUANTILES, axis=0), pred, sigma,
                          measured.get(cid), cov50, cov90, int(ok.sum()))
    return bands
