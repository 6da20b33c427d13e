"""Posterior predictive bands: posterior draws through the forward model plus an error term.

For each configuration, the draws' force and ram-displacement curves are resampled on a
common time grid and summarised by their 5/25/50/75/95 % quantiles ("model" bands:
parameter uncertainty only).  The *predictive* bands add the error of the model against
the press: with a :class:`~smcbayes.posterior.discrepancy.PhaseDiscrepancy` (learnt from
the training residuals) an error drawn from the distribution of the point's phase of the
closing, otherwise white Gaussian noise of one standard deviation per configuration.  Where
each trial has a contact offset of its own (profiled by the loss or measured from its end
state, ``[loss] contact``), every draw is also taken at each training trial's offset (its
closing delayed by offset / set speed), so both bands carry the trial-to-trial scatter
of the contact that a new trial's unknown offset brings.  Predictive draws are clipped to
``[0, F_limit]``: the press neither pulls nor exceeds its force limit during the closing.

The predictive mean curve (the mean of the predictive draws: parameter uncertainty, the
contact scatter and the error model's bias where the training residuals lean to one side)
is the point prediction: under squared error the mean of the predictive distribution is
the optimal point forecast (Gneiting 2011, "Making and evaluating point forecasts", JASA
106:746), where the model's median curve keeps the model's own bias and a steep end of
closing at one timing.

Scores against a measured curve, at its points inside the band grid: coverage of the 50 %
and 90 % bands; RMSE of the model's median curve and of the predictive mean; the CRPS
(the mean over the points of the continuous ranked probability score, computed from 50
predictive quantiles as twice their mean pinball loss; Gneiting & Raftery 2007,
"Strictly proper scoring rules, prediction, and estimation", JASA 102:359, eq. 21); and
the 90 % interval score, width plus 2/alpha times the distance by which the measurement
falls outside (same paper, eq. 43).  The last two reward sharp bands and punish missed
points, so they are read beside the coverage.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.nodes import interp_rows
from smcbayes.posterior.discrepancy import (
    GRID_REACH,
    PhaseDiscrepancy,
    delayed_travel_mm,
    remaining_travel_mm,
)
from smcbayes.simulation.objective import Simulator

Array = NDArray[np.float64]
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
CRPS_LEVELS = (np.arange(50) + 0.5) / 50
PREDICTIVE_SAMPLES = 2000
"""Predictive draws per grid point (posterior draws times error draws per posterior draw)."""


@dataclass(frozen=True)
class Band:
    """Bands of one configuration.

    Attributes:
        config_id: configuration id.
        time_s: common time grid, ``(T,)``.
        force_kN, displacement_mm: model quantiles, ``(5, T)`` (5/25/50/75/95 %).
        force_pred_kN: predictive quantiles of force (model plus error), ``(5, T)``.
        force_pred_mean_kN: predictive mean force, the point prediction, ``(T,)`` (None
            when every draw failed).
        noise_kN: the white-noise standard deviation (kN) without an error model; with one,
            the mean half-width of its central 90 % interval over the grid.
        measured: measured ``(time_s, force_kN)`` or None.
        coverage50, coverage90: share of measured points inside the predictive bands (NaN
            without data).
        draws: number of successful draws.
        rmse_median_kN: RMSE of the model's median curve against the measurement (kN).
        rmse_mean_kN: RMSE of the predictive mean curve (model plus error) (kN).
        crps_kN: mean CRPS of the predictive distribution at the measured points (kN).
        interval_score90_kN: mean 90 % interval score at the measured points (kN).
        error_model: ``"discrepancy"`` or ``"white noise"``.
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
    rmse_median_kN: float = float("nan")
    rmse_mean_kN: float = float("nan")
    crps_kN: float = float("nan")
    interval_score90_kN: float = float("nan")
    error_model: str = "white noise"
    force_pred_mean_kN: Array | None = None


def _curves_on_grid(time: Array, values: Array, grid: Array) -> Array:
    """Row-wise interpolation of ``(D, T)`` curves onto ``grid`` ``(G,)``, holding ends."""
    return np.stack([np.interp(grid, t, v) for t, v in zip(time, values, strict=True)])


def _predictive_draws(force: Array, grid: Array, switch_s: Array, travel_mm: Array, sigma: float,
                      discrepancy: PhaseDiscrepancy | None, limit_kN: float,
                      rng: np.random.Generator) -> tuple[Array, float]:
    """Predictive force draws ``(D * K, G)`` clipped to ``[0, limit_kN]`` and the error scale.

    Args:
        force: model force of the ``D`` draws on ``grid``, ``(D, G)`` (kN).
        switch_s, travel_mm: each draw's switch time and ram travel there, ``(D,)``.
    """
    k = max(1, -(-PREDICTIVE_SAMPLES // force.shape[0]))
    base = np.repeat(force, k, axis=0)
    if discrepancy is None:
        err, scale = sigma * rng.standard_normal(base.shape), sigma
    else:
        d = remaining_travel_mm(grid[None, :], np.repeat(switch_s, k)[:, None],
                                np.repeat(travel_mm, k)[:, None])
        err = discrepancy.sample(d, rng)
        scale = float(np.mean(discrepancy.scale_kN(d)))
    return np.clip(base + err, 0.0, limit_kN), scale


def _scores(grid: Array, median: Array, qpred: Array, levels: Array,
            measured: tuple[Array, Array], mean: Array) -> dict[str, float]:
    """Coverage, median and mean RMSE, CRPS and interval score at the measured points (see
    module doc).

    Args:
        median: the model's median force on ``grid`` ``(G,)``.
        qpred: predictive quantiles ``(L, G)`` at ``levels`` ``(L,)``, the five band levels first.
        mean: the predictive mean force on ``grid`` ``(G,)``.
    """
    tm, fm = measured
    inside = tm <= grid[-1]
    t, f = tm[inside], fm[inside]
    q = np.stack([np.interp(t, grid, row) for row in qpred])  # (L, N)
    lo90, lo50, hi50, hi90 = q[0], q[1], q[3], q[4]
    pin = [np.maximum(a * (f - row), (a - 1) * (f - row)) for a, row in zip(levels[5:], q[5:], strict=True)]
    alpha = 0.1
    interval = (hi90 - lo90) + (2 / alpha) * (np.maximum(lo90 - f, 0) + np.maximum(f - hi90, 0))
    return {"coverage90": float(np.mean((f >= lo90) & (f <= hi90))),
            "coverage50": float(np.mean((f >= lo50) & (f <= hi50))),
            "rmse_median_kN": float(np.sqrt(np.mean((np.interp(t, grid, median) - f) ** 2))),
            "rmse_mean_kN": float(np.sqrt(np.mean((np.interp(t, grid, mean) - f) ** 2))),
            "crps_kN": float(2 * np.mean(pin)), "interval_score90_kN": float(np.mean(interval))}


def _delayed(grid: Array, force: Array, disp: Array, switch_s: Array, travel_mm: Array,
             delays_s: Array) -> tuple[Array, Array, Array, Array]:
    """Every draw's curves ``(D, G)`` at every contact delay ``(S,)``: ``(D * S, G)`` curves
    (draw-major), each ``F(t - delay)`` on ``grid`` (the value at 0 before it), with its
    switch time delayed alike and its travel to the switch lengthened by the delay
    (:func:`~smcbayes.posterior.discrepancy.delayed_travel_mm`)."""
    s = delays_s.size
    delays = np.tile(delays_s, force.shape[0])
    shifted = grid[None, :] - delays[:, None]
    rows = np.repeat(np.arange(force.shape[0]), s)
    base = np.broadcast_to(grid, (rows.size, grid.size))
    return (interp_rows(shifted, base, force[rows]), interp_rows(shifted, base, disp[rows]),
            np.repeat(switch_s, s) + delays, delayed_travel_mm(travel_mm[rows], switch_s[rows], delays))


def predictive_bands(model: Simulator, theta: Array, config_ids: Sequence[str],
                     measured: Mapping[str, tuple[Array, Array]], noise_kN: Mapping[str, float],
                     rng: np.random.Generator, grid_points: int = 300,
                     discrepancy: PhaseDiscrepancy | Mapping[str, PhaseDiscrepancy | None] | None = None,
                     force_limit_kN: Mapping[str, float] | None = None,
                     delays_s: Mapping[str, Array] | None = None) -> dict[str, Band]:
    """Bands on ``config_ids`` from posterior draws ``theta`` ``(D, d)`` (user units).

    Args:
        noise_kN: white-noise sd per configuration, used without ``discrepancy`` (for
            configurations not listed, the mean of the others).
        discrepancy: the error model (replaces the white noise), one for every
            configuration or one per configuration (a configuration mapped to None, or not
            listed, takes the white noise).
        force_limit_kN: upper clip per configuration (default: no upper clip).
        delays_s: per configuration, the delays (s) of its closing to mix over (contact
            offsets over its set speed): every draw is taken at each of them, so the model
            and predictive bands carry the trial-to-trial scatter of the contact.
    """
    results = model.simulate(theta, config_ids)
    fallback = float(np.mean(list(noise_kN.values()))) if noise_kN else 0.0
    levels = np.concatenate((QUANTILES, CRPS_LEVELS))
    bands = {}
    for cid, res in results.items():
        disc = discrepancy.get(cid) if isinstance(discrepancy, Mapping) else discrepancy
        kind = "white noise" if disc is None else "discrepancy"
        ok = res.ok
        late = float(np.max(delays_s.get(cid, 0.0), initial=0.0)) if delays_s is not None else 0.0
        t_end = (np.nanmax(res.switch_time_s[ok]) + late) * GRID_REACH if np.any(ok) else 1.0
        if cid in measured:
            t_end = max(t_end, measured[cid][0][-1] * 1.02)
        grid = np.linspace(0.0, t_end, grid_points)
        sigma = float(noise_kN.get(cid, fallback))
        if not np.any(ok):  # every draw failed on this configuration: an empty band, said by draws = 0
            nan = np.full((len(QUANTILES), grid_points), np.nan)
            bands[cid] = Band(cid, grid, nan, nan.copy(), nan.copy(), sigma, measured.get(cid),
                              float("nan"), float("nan"), 0, error_model=kind)
            continue
        force = _curves_on_grid(res.time_s[ok], res.force_kN[ok], grid)
        disp = _curves_on_grid(res.time_s[ok], res.displacement_mm[ok], grid)
        switch = res.switch_time_s[ok]
        travel = np.array([np.interp(s, t, v) for s, t, v in zip(switch, res.time_s[ok],
                                                                 res.displacement_mm[ok], strict=True)])
        if delays_s is not None and np.size(delays_s.get(cid, ())):
            force, disp, switch, travel = _delayed(grid, force, disp, switch, travel,
                                                   np.asarray(delays_s[cid], dtype=float))
        limit = float((force_limit_kN or {}).get(cid, np.inf))
        draws, scale = _predictive_draws(force, grid, switch, travel, sigma, disc, limit, rng)
        qpred = np.quantile(draws, levels, axis=0)
        mean = draws.mean(axis=0)
        model_q = np.quantile(force, QUANTILES, axis=0)
        scores = (_scores(grid, model_q[2], qpred, levels, measured[cid], mean) if cid in measured
                  else {"coverage50": float("nan"), "coverage90": float("nan")})
        bands[cid] = Band(cid, grid, model_q, np.quantile(disp, QUANTILES, axis=0), qpred[:5], scale,
                          measured.get(cid), draws=int(ok.sum()), error_model=kind,
                          force_pred_mean_kN=mean, **scores)
    return bands
