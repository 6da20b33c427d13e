"""Where a force loss comes from: per phase, and split into timing shift, amplitude, shape.

Both work on the loss's common grid (:func:`smcbayes.data.loss.force_pair`), so the parts
add up to the force MSE e_k^F of the same configuration.

Definitions (per configuration and parameter row, s = simulated, m = measured force on the
grid of N points, MSE(a, b) = mean((a - b)^2)):

* **timing shift**: the time shift delta (s) minimising MSE(s(t - delta), m(t)) over
  shifts of up to ``max_shift_fraction`` of the window (whole grid steps, ends held);
  ``shift_kN2 = MSE(s, m) - MSE(s_delta, m)``;
* **amplitude**: the least-squares scale a of the shifted curve, a = <s_delta, m> /
  <s_delta, s_delta>; ``amplitude_kN2 = MSE(s_delta, m) - MSE(a s_delta, m)``;
* **shape**: what neither explains, ``shape_kN2 = MSE(a s_delta, m)``.

Each step minimises over a family that contains the identity (delta = 0, a = 1), so all three
parts are >= 0 and ``shift + amplitude + shape = e_k^F`` exactly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.config.specs import LossSpec
from smcbayes.data.dataset import Dataset
from smcbayes.data.loss import given_force_pair
from smcbayes.forward.result import PHASE_NAMES, SimulationResult

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ForceBreakdown:
    """Breakdown of the force error of ``P`` rows on ``K`` configurations.

    Attributes:
        ids: configurations, order of axis 1.
        phases: phase names, order of the last axis of the phase arrays.
        phase_mse_kN2: mean squared error over the grid points of each phase, ``(P, K, 4)``;
            NaN where a phase has no grid point.
        phase_share: share of the configuration's squared error in each phase, ``(P, K, 4)``.
        shift_s: lag of the simulated curve, -delta (s): positive when it runs late;
            shape ``(P, K)``.
        shift_kN2, amplitude_kN2, shape_kN2: the error split, each ``(P, K)``.
        amplitude_factor: the least-squares scale a, ``(P, K)``.
    """

    ids: list[str]
    phases: tuple[str, ...]
    phase_mse_kN2: Array
    phase_share: Array
    shift_s: Array
    shift_kN2: Array
    amplitude_kN2: Array
    shape_kN2: Array
    amplitude_factor: Array


def split_error(sim: Array, meas: Array, dt_s: Array, max_shift_fraction: float = 0.2,
                steps: int = 41) -> tuple[Array, Array, Array, Array, Array]:
    """Split the MSE of ``sim`` vs ``meas`` (both ``(P, N)``) into shift, amplitude, shape.

    Args:
        sim, meas: curves on a uniform grid, shape ``(P, N)``.
        dt_s: grid spacing per row (s), shape ``(P,)``.
        max_shift_fraction: largest shift tried, as a share of the window.
        steps: number of shifts tried (odd, so that 0 is among them).

    Returns:
        ``(lag_s, shift_kN2, amplitude_kN2, shape_kN2, factor)``, each ``(P,)``; lag_s = -delta
        is positive when the simulated curve runs late.
    """
    P, N = sim.shape
    kmax = max(1, int(max_shift_fraction * (N - 1)))
    ks = np.unique(np.round(np.linspace(-kmax, kmax, steps | 1)).astype(int))
    idx = np.clip(np.arange(N)[None, :] - ks[:, None], 0, N - 1)        # (S, N)
    shifted = sim[:, idx]                                               # (P, S, N)
    mse = np.mean((shifted - meas[:, None, :]) ** 2, axis=2)            # (P, S)
    best = np.argmin(mse, axis=1)
    s_best = shifted[np.arange(P), best]                                # (P, N)
    total = np.mean((sim - meas) ** 2, axis=1)
    after_shift = mse[np.arange(P), best]
    ss = np.sum(s_best * s_best, axis=1)
    a = np.where(ss > 0, np.sum(s_best * meas, axis=1) / np.where(ss > 0, ss, 1.0), 1.0)
    shape = np.mean((a[:, None] * s_best - meas) ** 2, axis=1)
    return -ks[best] * dt_s, total - after_shift, after_shift - shape, shape, a


def force_breakdown(results: Mapping[str, SimulationResult], dataset: Dataset,
                    spec: LossSpec = LossSpec(), ids: Sequence[str] | None = None,
                    offsets_mm: Mapping[str, float | Sequence[float]] | None = None) -> ForceBreakdown:
    """Per-phase errors and the shift/amplitude/shape split of the force curves (each
    configuration at, or averaged over, its entry of ``offsets_mm`` (mm) where given, as
    in :func:`smcbayes.data.loss.evaluate_loss`)."""
    ids = dataset.ids("train") if ids is None else list(ids)
    P = next(iter(results.values())).rows
    K, F = len(ids), len(PHASE_NAMES)
    pm, share = np.full((P, K, F), np.nan), np.full((P, K, F), np.nan)
    parts = np.full((5, P, K), np.nan)
    for k, cid in enumerate(ids):
        pair = given_force_pair(results[cid], dataset[cid], spec, (offsets_mm or {}).get(cid))
        sq = (pair.sim_kN - pair.meas_kN) ** 2
        total = np.sum(sq, axis=1)
        for f in range(F):
            mask = pair.phase == f
            count = mask.sum(axis=1)
            sse = np.sum(np.where(mask, sq, 0.0), axis=1)
            pm[:, k, f] = np.where(count > 0, sse / np.maximum(count, 1), np.nan)
            share[:, k, f] = np.where(total > 0, sse / np.where(total > 0, total, 1.0), 0.0)
        dt = pair.time_s[:, 1] - pair.time_s[:, 0]
        split = split_error(pair.sim_kN, pair.meas_kN, dt)
        for i, arr in enumerate(split):
            parts[i, :, k] = np.where(pair.ok, arr, np.nan)
        pm[~pair.ok, k] = np.nan
        share[~pair.ok, k] = np.nan
    return ForceBreakdown(ids, PHASE_NAMES, pm, share, *parts)
