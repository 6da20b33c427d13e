"""Out-of-sample residuals for the error model of the predictive bands: refits that leave
one configuration, or a group of them, out.

Residuals at the calibrated point understate the error on a configuration the fit has not
seen: the calibration has bent its parameters towards every training curve, and with a
handful of curves and several weakly identified parameters it bends far.  Prediction
intervals built from leave-one-out residuals are the jackknife (Barber, Candes, Ramdas &
Tibshirani 2021, "Predictive inference with the jackknife+", Ann. Statist. 49:486-507):
they keep close to their coverage on new cases where the fit is stable, though without the
jackknife+'s guarantee, since the band is centred on the full fit's prediction, not on
each refit's.  Refitting the calibration once per configuration
would cost a calibration each; here the refit without configuration ``k`` is one
Levenberg-Marquardt step from the calibrated point on the other configurations' force
residuals, with the force sensitivities the stage computes for N_eff anyway (the
linearised influence of leaving a case out; Cook & Weisberg 1982, "Residuals and
Influence in Regression", ch. 3), followed by a line search on the forward model: the step
is taken at the scale among :data:`SCALES` whose force MSE on the other configurations is
lowest, so a misleading linearisation never makes the refit worse than the calibrated
point (scale 0 keeps it).  Configuration ``k``'s residuals at its refit point are then
out-of-sample residuals.

Leaving a whole group out (every trial at one closing speed, or of one charge) gives the
residuals of trials predicted across a gap in the training set, as a trial at a new speed
or with a new charge is: the cross-validation that matches the prediction task (leave-
group-out, Roberts et al. 2017, "Cross-validation strategies for data with temporal,
spatial, hierarchical, or phylogenetic structure", Ecography 40:913-929).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import LossSpec
from smcbayes.data.dataset import Measurement
from smcbayes.data.loss import force_pair
from smcbayes.forward.parameters import ParameterSpace
from smcbayes.posterior.discrepancy import ResidualCurve, residual_curve
from smcbayes.simulation.objective import Simulator

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

SCALES = (0.0, 0.25, 0.5, 1.0)
"""Line-search scales of each leave-out step."""
MAX_STEP = 0.25
"""Largest move of one parameter in one step (unit-cube coordinates): beyond it the
linearisation says little."""
DAMPING = 1e-3
"""Levenberg-Marquardt damping, relative to the diagonal of the Gauss-Newton matrix."""


@dataclass(frozen=True)
class LocalFit:
    """The loss's local picture at the calibrated point, one entry per training configuration.

    Attributes:
        config_ids: training configuration ids, ``K`` of them.
        u0: the calibrated point in unit-cube coordinates ``(d,)``.
        residuals_kN: measured minus simulated force on each configuration's loss grid
            (at its own contact offset where it has one), ``K`` arrays ``(N_k,)``.
        sensitivities: d simulated force / d u on the same grids, ``K`` arrays ``(N_k, d)``
            (kN per unit of the unit cube).
        usable: false where a perturbed run failed (the sensitivities are then unreliable).
    """

    config_ids: tuple[str, ...]
    u0: Array
    residuals_kN: tuple[Array, ...]
    sensitivities: tuple[Array, ...]
    usable: bool = True


Groups = Sequence[Sequence[int]]
"""Sets of training configurations (indices into :attr:`LocalFit.config_ids`) left out
together; one refit per set."""


def singletons(k: int) -> list[tuple[int, ...]]:
    """The leave-one-out groups of ``k`` configurations."""
    return [(i,) for i in range(k)]


def leave_out_steps(fit: LocalFit, groups: Groups | None = None) -> Array:
    """Damped Gauss-Newton steps ``(G, d)`` (unit cube) that refit all configurations but
    those of each group (default: one group per configuration, leave-one-out).

    Each configuration weighs ``1 / N_k``, as in the loss (the mean over configurations of
    each one's mean squared force error).  A step longer than :data:`MAX_STEP` in any
    coordinate is shortened along its direction.
    """
    d = fit.u0.size
    grams = [s.T @ s / max(len(r), 1) for r, s in zip(fit.residuals_kN, fit.sensitivities, strict=True)]
    grads = [s.T @ r / max(len(r), 1) for r, s in zip(fit.residuals_kN, fit.sensitivities, strict=True)]
    h_all, g_all = np.sum(grams, axis=0), np.sum(grads, axis=0)
    groups = singletons(len(grams)) if groups is None else groups
    steps = np.zeros((len(groups), d))
    for k, group in enumerate(groups):
        h = h_all - sum((grams[i] for i in group), np.zeros((d, d)))
        g = g_all - sum((grads[i] for i in group), np.zeros(d))
        diag = np.diag(h).copy()
        scale = float(np.max(diag)) if np.max(diag) > 0 else 1.0
        damped = h + DAMPING * np.diag(np.maximum(diag, 1e-9 * scale))
        step = np.linalg.lstsq(damped, g, rcond=None)[0]
        longest = float(np.max(np.abs(step))) if step.size else 0.0
        steps[k] = step if longest <= MAX_STEP else step * (MAX_STEP / longest)
    return steps


def candidate_rows(u0: Array, steps: Array) -> Array:
    """Rows ``(1 + G * S, d)``: ``u0`` first, then, step-major (one step per group),
    ``u0 + scale * step`` for the nonzero :data:`SCALES`, clipped to the cube."""
    scales = np.asarray([s for s in SCALES if s > 0])
    moved = u0[None, None, :] + scales[None, :, None] * steps[:, None, :]
    return np.vstack([u0[None, :], np.clip(moved, 0.0, 1.0).reshape(-1, u0.size)])


def pick_rows(mse: Mapping[str, Array], config_ids: Sequence[str], groups: Groups | None = None) -> list[int]:
    """For each group, the candidate row (index into :func:`candidate_rows`) with the lowest
    mean force MSE over the configurations outside the group (row 0, the calibrated point,
    wins ties).

    Args:
        mse: per configuration, the force MSE (kN^2) of every candidate row ``(1 + G * S,)``
            (NaN or inf where a run failed).
        config_ids: the ``K`` configurations the group indices refer to.
        groups: the groups in the order of :func:`candidate_rows`'s steps (default: one per
            configuration).
    """
    ids = list(config_ids)
    groups = singletons(len(ids)) if groups is None else groups
    s = sum(1 for x in SCALES if x > 0)
    picks = []
    for k, group in enumerate(groups):
        own = np.concatenate(([0], 1 + k * s + np.arange(s)))
        others = [np.asarray(mse[c], dtype=float)[own] for i, c in enumerate(ids) if i not in group]
        if not others:
            picks.append(0)
            continue
        total = np.mean(others, axis=0)
        total = np.where(np.isfinite(total), total, np.inf)
        picks.append(int(own[np.argmin(total)]))
    return picks


def scale_of(row: int) -> float:
    """The step scale of candidate row ``row`` of :func:`candidate_rows`."""
    moved = [x for x in SCALES if x > 0]
    return 0.0 if row == 0 else moved[(row - 1) % len(moved)]


def leave_out_residuals(model: Simulator, space: ParameterSpace, fit: LocalFit,
                        measurements: Mapping[str, Measurement], loss: LossSpec,
                        groups: Groups | None = None) -> tuple[list[list[ResidualCurve]], int]:
    """Residual curves of each group's configurations at the refit that left the group out.

    One batch: every candidate row of :func:`candidate_rows` on every configuration of
    ``fit`` (``(1 + S G) K`` forward runs for ``G`` groups, ``S = 3`` nonzero
    :data:`SCALES`).  The residuals are read at the measured times, a closing that ended at
    the force limit continued there, as
    :func:`~smcbayes.posterior.discrepancy.training_residuals` does at the calibrated point;
    a configuration whose refit run failed is left out.

    Args:
        groups: configurations left out together (default: one group per configuration).

    Returns:
        per group, the curves of its configurations; and the forward runs made.
    """
    ids = list(fit.config_ids)
    groups = singletons(len(ids)) if groups is None else groups
    rows = candidate_rows(fit.u0, leave_out_steps(fit, groups))
    results = model.simulate(space.from_unit(rows), ids)
    mse, delays = {}, {}
    for cid in ids:
        pair = force_pair(results[cid], measurements[cid], loss)
        err = np.mean((pair.sim_kN - pair.meas_kN) ** 2, axis=1)
        mse[cid] = np.where(pair.ok, err, np.inf)
        speed = measurements[cid].speed_mm_s
        delays[cid] = pair.offset_mm / speed if speed else np.zeros_like(pair.offset_mm)
    picks = pick_rows(mse, ids, groups)
    out = []
    for group, row in zip(groups, picks, strict=True):
        curves = []
        for cid in (ids[i] for i in group):
            force = measurements[cid].force
            if force is not None and bool(np.asarray(results[cid].ok)[row]):
                # each trial at its own contact offset at its refit point: the residual
                # left once the trial's own offset is known; the bands draw offsets separately
                curves.append(residual_curve(cid, results[cid], row, force.time_s, force.values,
                                             float(delays[cid][row]), measurements[cid].force_limit_kN))
        out.append(curves)
    logger.info("leave-out refits of %d group(s): step scales %s", len(groups), [scale_of(p) for p in picks])
    return out, rows.shape[0] * len(ids)
