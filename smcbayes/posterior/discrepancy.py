"""Model discrepancy of the force curves, learnt from the training residuals.

The predictive distribution of a measured force is the simulated force of a posterior
draw plus a model-discrepancy term, in the spirit of Kennedy & O'Hagan (2001, "Bayesian
calibration of computer models", J. R. Stat. Soc. B 63:425-464): measurement = simulator
at the calibrated parameters + discrepancy + noise.  Here the discrepancy and the noise
are one empirical error term whose distribution depends on where in the closing a point
lies, not one white-noise variance per configuration.  The coordinate is the *remaining
ram travel to the simulated end of closing* (mm),

    d(t) = D_s (1 - t / t_s),

with ``t_s`` the simulated switch to force control and ``D_s`` the simulated ram travel at
that time (``D_s / t_s`` is the mean closing speed; ``d < 0`` after the simulated switch).
It lines up the part of the curve where the model errs most, the end of closing, whose
force the model raises almost vertically while the press raises it over the last 1-3 s,
across charges and speeds.

Fit (:func:`fit_discrepancy`): the residuals ``measured - simulated`` (kN) of the training
configurations (at the calibrated point, or each at a refit that left it out:
:mod:`smcbayes.posterior.crossfit`), at the measured times (a closing that ended at the
force limit continued there, as the press holds it), are pooled into bins of
``d`` (quantile edges, split at ``d = 0``, merged until each bin holds enough points of
enough configurations); each bin keeps the weighted quantiles of its residuals, every
configuration weighing the same.  Prediction (:meth:`PhaseDiscrepancy.sample`): a draw
of the error at any point is the inverse CDF of the point's bin at a uniform number (mixed
linearly with the neighbouring bin's between their centres),
so the bands are wide where the training residuals are large and skewed where they are
one-sided; predictive draws are then clipped to ``[0, F_limit]``.  Using the empirical
quantiles, not a Gaussian with the bin's variance, is a split-conformal style choice
(Lei et al. 2018, "Distribution-free predictive inference for regression", JASA 113:1094):
on data like the training data the bands keep their nominal coverage whatever the
residuals' shape.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.data.dataset import END_NEAR_LIMIT
from smcbayes.forward.result import SimulationResult
from smcbayes.simulation.objective import Simulator

Array = NDArray[np.float64]

LEVELS = 201
"""Quantile levels stored per bin (0, 0.005, ..., 1)."""
MAX_BINS = 12
"""Most bins of the remaining-travel coordinate."""
MIN_POINTS = 40
"""Fewest residual points per bin."""
MIN_CONFIGS = 2
"""Fewest configurations contributing to each bin (when the fit has that many)."""
GRID_REACH = 1.1
"""A band's time grid reaches this multiple of the latest simulated switch (further when its
measured closing ends later); a training closing that ended at the force limit is continued
there to this multiple of its later end of closing, simulated or measured."""


@dataclass(frozen=True)
class ResidualCurve:
    """Residuals of one training configuration at one parameter point (the calibrated point or
    a refit that left the configuration out).

    Attributes:
        config_id: configuration id.
        time_s: measured times ``(N,)`` (s), continued past the end of a closing that ended
            at the force limit (:func:`held_at_limit`).
        residual_kN: measured minus simulated force ``(N,)``.
        switch_s: simulated time of the switch to force control (s).
        travel_mm: simulated ram travel at the switch (mm).
        held: the measured closing ended at the force limit and continues there, past the
            simulated switch too: beyond ``time_s[-1]`` both curves sit at the limit and the
            residual is 0 (:func:`fit_discrepancy` pads it so down to the pooled curves'
            furthest remaining travel).
    """

    config_id: str
    time_s: Array
    residual_kN: Array
    switch_s: float
    travel_mm: float
    held: bool = False


def remaining_travel_mm(time_s: Array, switch_s: Array | float, travel_mm: Array | float) -> Array:
    """``d = D_s (1 - t / t_s)`` (mm); broadcasts ``(..., 1)`` switch data against ``(..., T)`` times."""
    ts = np.maximum(np.asarray(switch_s, dtype=float), 1e-9)
    return np.asarray(travel_mm, dtype=float) * (1.0 - np.asarray(time_s, dtype=float) / ts)


def weighted_quantiles(values: Array, weights: Array, levels: Array) -> Array:
    """Quantiles of a weighted sample (piecewise-linear inverse of the weighted CDF)."""
    order = np.argsort(values)
    v, w = values[order], weights[order]
    cdf = (np.cumsum(w) - 0.5 * w) / np.sum(w)
    return np.interp(levels, cdf, v)


@dataclass(frozen=True)
class PhaseDiscrepancy:
    """Empirical error distribution per bin of remaining travel.

    Attributes:
        edges_mm: inner bin edges ``(B - 1,)`` in increasing order (outer bins are open).
        quantiles_kN: residual quantiles ``(B, LEVELS)`` at levels ``linspace(0, 1, LEVELS)``.
        points: residual points per bin ``(B,)``.
        configs: configurations contributing to each bin ``(B,)``.
        centres_mm: median remaining travel of each bin's points ``(B,)``.
    """

    edges_mm: Array
    quantiles_kN: Array
    points: NDArray[np.int64]
    configs: NDArray[np.int64]
    centres_mm: Array

    @property
    def bins(self) -> int:
        """Number of bins."""
        return int(self.quantiles_kN.shape[0])

    def bin_of(self, d_mm: Array) -> NDArray[np.int64]:
        """Bin index of each remaining-travel value (same shape)."""
        return np.searchsorted(self.edges_mm, d_mm, side="right").astype(np.int64)

    def quantile(self, d_mm: Array, u: Array) -> Array:
        """Error (kN) at level ``u`` in ``[0, 1]`` for remaining travel ``d_mm`` (broadcast).

        Between the centres of two neighbouring bins the quantile functions are mixed
        linearly in ``d`` (no mixing across the switch, ``d = 0``, nor beyond the outer
        centres), so the bands change smoothly along the closing.
        """
        d = np.asarray(d_mm, dtype=float)
        b = self.bin_of(d)
        c = self.centres_mm
        nb = np.where(d > c[b], b + 1, b - 1)
        inner = (nb >= 0) & (nb < self.bins)
        nb = np.clip(nb, 0, self.bins - 1)
        between = np.minimum(b, nb)
        split = (self.edges_mm[np.minimum(between, max(self.bins - 2, 0))] == 0.0) if self.bins > 1 else inner
        span = np.where(inner, np.abs(c[nb] - c[b]), 1.0)
        w = np.where(inner & ~split, np.abs(d - c[b]) / np.maximum(span, 1e-12), 0.0)
        pos = np.clip(np.asarray(u, dtype=float), 0.0, 1.0) * (LEVELS - 1)
        lo = np.minimum(pos.astype(np.int64), LEVELS - 2)
        frac = pos - lo
        q = self.quantiles_kN

        def at(k: NDArray[np.int64]) -> Array:
            return q[k, lo] * (1.0 - frac) + q[k, lo + 1] * frac

        return (1.0 - w) * at(b) + w * at(nb)

    def sample(self, d_mm: Array, rng: np.random.Generator) -> Array:
        """Independent error draws (kN), one per element of ``d_mm``."""
        return self.quantile(d_mm, rng.random(np.shape(d_mm)))

    def scale_kN(self, d_mm: Array) -> Array:
        """Half-width of the central 90 % error interval (kN) at ``d_mm``."""
        return 0.5 * (self.quantile(d_mm, np.full(np.shape(d_mm), 0.95))
                      - self.quantile(d_mm, np.full(np.shape(d_mm), 0.05)))

    def as_dict(self) -> dict[str, Any]:
        """Summary for ``summary.json``: bins with their range, counts and 5/50/95 % errors."""
        lo = np.concatenate(([-np.inf], self.edges_mm))
        hi = np.concatenate((self.edges_mm, [np.inf]))
        at = {p: self.quantiles_kN[:, round(p * (LEVELS - 1))] for p in (0.05, 0.5, 0.95)}
        return {"kind": "empirical residual quantiles by remaining closing travel",
                "coordinate": "remaining ram travel to the simulated end of closing (mm)",
                "bins": [{"from_mm": None if not np.isfinite(a) else float(a),
                          "to_mm": None if not np.isfinite(b) else float(b),
                          "centre_mm": float(m), "points": int(n), "configurations": int(c),
                          "q05_kN": float(at[0.05][i]), "q50_kN": float(at[0.5][i]),
                          "q95_kN": float(at[0.95][i])}
                         for i, (a, b, m, n, c) in enumerate(zip(lo, hi, self.centres_mm, self.points,
                                                                 self.configs, strict=True))]}


def _edges(d: Array, owner: Array, n_configs: int) -> Array:
    """Quantile edges of ``d`` split at 0, merged until every bin is populated enough."""
    need_c = min(MIN_CONFIGS, n_configs)
    cand: list[float] = [0.0] if np.any(d < 0) and np.any(d >= 0) else []
    for side in (d[d < 0], d[d >= 0]):
        k = max(1, min(MAX_BINS // 2, side.size // MIN_POINTS))
        if side.size and k > 1:
            cand.extend(np.quantile(side, np.linspace(0, 1, k + 1)[1:-1]).tolist())
    edges = np.unique(np.asarray(cand, dtype=float))
    while edges.size:
        b = np.searchsorted(edges, d, side="right")
        counts = np.bincount(b, minlength=edges.size + 1)
        configs = np.array([np.unique(owner[b == i]).size for i in range(edges.size + 1)])
        bad = np.flatnonzero((counts < MIN_POINTS) | (configs < need_c))
        if bad.size == 0:
            break
        i = int(bad[np.argmin(counts[bad])])
        # merge the thin bin with its smaller neighbour by removing the edge between them
        if i == 0:
            j = 0
        elif i == edges.size:
            j = edges.size - 1
        else:
            j = i - 1 if counts[i - 1] <= counts[i + 1] else i
        edges = np.delete(edges, j)
    return edges


def _zero_pad(d_mm: Array, furthest_mm: float) -> Array:
    """Remaining travels (mm) from past the last of ``d_mm`` ``(N,)`` down to ``furthest_mm``
    at the curve's median spacing, ``(M,)`` (empty when nothing is left to cover)."""
    last = float(np.min(d_mm))
    step = float(np.median(np.abs(np.diff(d_mm)))) if d_mm.size > 1 else 0.0
    if not step > 0 or furthest_mm >= last:
        return np.empty(0)
    return last - step * np.arange(1, int(np.floor((last - furthest_mm) / step)) + 1)


def fit_discrepancy(curves: Sequence[ResidualCurve]) -> PhaseDiscrepancy | None:
    """The error model from the training residuals; ``None`` without any finite residual.

    A held curve (:attr:`ResidualCurve.held`) is padded with zero residuals down to the
    furthest remaining travel any curve reaches, so the far bins past the switch hold every
    trial that ended at the limit, not only the latest ones.
    """
    used = [c for c in curves if np.any(np.isfinite(c.residual_kN))
             and np.isfinite(c.switch_s) and np.isfinite(c.travel_mm)]
    if not used:
        return None
    ds = [remaining_travel_mm(c.time_s[np.isfinite(c.residual_kN)], c.switch_s, c.travel_mm) for c in used]
    rs = [c.residual_kN[np.isfinite(c.residual_kN)] for c in used]
    furthest = min(float(np.min(x)) for x in ds)
    for k, c in enumerate(used):
        if c.held:
            pad = _zero_pad(ds[k], furthest)
            ds[k], rs[k] = np.concatenate((ds[k], pad)), np.concatenate((rs[k], np.zeros(pad.size)))
    ws = [np.full(x.size, 1.0 / x.size) for x in ds]
    owner = [np.full(x.size, k) for k, x in enumerate(ds)]
    d, r, w, who = (np.concatenate(a) for a in (ds, rs, ws, owner))
    edges = _edges(d, who, len(ds))
    b = np.searchsorted(edges, d, side="right")
    levels = np.linspace(0.0, 1.0, LEVELS)
    q = np.stack([weighted_quantiles(r[b == i], w[b == i], levels) for i in range(edges.size + 1)])
    points = np.bincount(b, minlength=edges.size + 1).astype(np.int64)
    configs = np.array([np.unique(who[b == i]).size for i in range(edges.size + 1)], dtype=np.int64)
    centres = np.array([np.median(d[b == i]) for i in range(edges.size + 1)])
    return PhaseDiscrepancy(edges, q, points, configs, centres)


def residual_curve(config_id: str, res: SimulationResult, row: int, time_s: Array,
                   force_kN: Array, delay_s: float = 0.0, limit_kN: float | None = None) -> ResidualCurve:
    """Residuals of row ``row`` of one configuration's simulation result at the measured
    ``time_s`` ``(N,)`` with measured ``force_kN`` ``(N,)`` (the simulated force held at its
    last value beyond its record), the simulated closing delayed by ``delay_s`` (a contact
    offset over the set speed; :func:`smcbayes.data.loss.force_pair`).

    With the press's force limit ``limit_kN`` (kN), a measured closing that ended at the
    limit continues at it (:func:`held_at_limit`) to :data:`GRID_REACH` times its later end
    of closing, simulated or measured, and the curve is marked ``held``: the residuals past
    either end of closing are then those of every trial, not only of the trials still
    closing.
    """
    t, f, disp = res.time_s[row] + delay_s, res.force_kN[row], res.displacement_mm[row]
    ts = float(res.switch_time_s[row]) + delay_s
    tm, fm = np.asarray(time_s, float), np.asarray(force_kN, float)
    held = False
    if limit_kN is not None and np.isfinite(ts) and tm.size >= 2:
        n = tm.size
        tm, fm = held_at_limit(tm, fm, limit_kN, GRID_REACH * max(ts, float(tm[-1])))
        held = tm.size > n
    return ResidualCurve(config_id, tm, fm - np.interp(tm, t, f),
                         ts, delayed_travel_mm(float(np.interp(ts, t, disp)), ts - delay_s, delay_s), held)


def held_at_limit(time_s: Array, force_kN: Array, limit_kN: float, until_s: float) -> tuple[Array, Array]:
    """A measured closing force ``force_kN`` ``(N,)`` at ``time_s`` ``(N,)`` continued at
    ``limit_kN`` (kN) from its end to ``until_s`` (s) at its median sampling step (the last
    point at ``until_s``), ``(N + M,)`` each, when it ended at the switch to force control
    (it reaches :data:`~smcbayes.data.dataset.END_NEAR_LIMIT` of the limit; the press then
    holds the limit); otherwise, or with nothing to add, the curve as given.

    The force files of a closing stop at the limit, so without this the residuals after
    the simulated end of closing would be those of the trials still closing alone: all
    below the limit, and an error model learnt from them would pull every prediction past
    the simulated switch below the limit, whatever the time.
    """
    t, f = np.asarray(time_s, float), np.asarray(force_kN, float)
    if t.size < 2 or not f[-1] >= END_NEAR_LIMIT * limit_kN or until_s <= t[-1]:
        return t, f
    step = float(np.median(np.diff(t)))
    if not step > 0:
        return t, f
    extra = t[-1] + step * np.arange(1, int(np.floor((until_s - t[-1]) / step)) + 1)
    if extra.size == 0 or extra[-1] < until_s:
        extra = np.append(extra, until_s)
    return np.concatenate((t, extra)), np.concatenate((f, np.full(extra.size, float(limit_kN))))


def delayed_travel_mm(travel_mm: Array | float, switch_s: Array | float, delay_s: Array | float) -> Array:
    """The ram travel to the switch of a closing delayed by ``delay_s`` (s), from the
    undelayed ``travel_mm`` and ``switch_s``: the delay adds its time at the mean closing
    speed, so the remaining travel ``d = D (1 - t / t_s)`` of the delayed closing is the
    undelayed one shifted in time, not stretched."""
    speed = np.asarray(travel_mm, dtype=float) / np.maximum(np.asarray(switch_s, dtype=float), 1e-9)
    return np.asarray(travel_mm, dtype=float) + speed * np.asarray(delay_s, dtype=float)


def training_residuals(model: Simulator, theta: Array, config_ids: Sequence[str],
                       measured: Mapping[str, tuple[Array, Array]],
                       delays_s: Mapping[str, float] | None = None,
                       limits_kN: Mapping[str, float] | None = None) -> list[ResidualCurve]:
    """Residuals of ``config_ids`` at one parameter vector ``theta`` ``(1, d)`` (user units).

    The simulated force is read at the measured times (held at its last value beyond the
    simulated record), each configuration's closing delayed by its ``delays_s`` entry (s;
    default none) and its measured closing continued at its ``limits_kN`` entry (kN; see
    :func:`residual_curve`); a configuration whose run fails is left out.
    """
    ids = [c for c in config_ids if c in measured]
    if not ids:
        return []
    results = model.simulate(np.atleast_2d(theta), ids)
    delays, limits = delays_s or {}, limits_kN or {}
    return [residual_curve(cid, results[cid], 0, *measured[cid], delay_s=delays.get(cid, 0.0),
                           limit_kN=limits.get(cid)) for cid in ids if bool(np.asarray(results[cid].ok)[0])]
