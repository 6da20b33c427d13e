"""The predictive bands' error models, one per band configuration.

A band configuration that the training set spans takes the error model learnt from the
leave-one-configuration-out residuals (:mod:`smcbayes.posterior.crossfit`); one that lies
outside it (a new speed or charge: :mod:`smcbayes.posterior.extrapolation`) takes the one
learnt from leave-group-out residuals that put training trials across the same kind of gap.
Every refit runs in one batch of the forward model.  Where each trial has a contact offset
of its own (profiled by the loss or measured from its end state), the residuals are taken
at each trial's own offset and the training trials' offsets at the calibrated point are
kept for the bands to mix over.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from smcbayes.data.loss import contact_offsets_mm
from smcbayes.posterior.context import RunContext
from smcbayes.posterior.crossfit import LocalFit, leave_out_residuals, singletons
from smcbayes.posterior.discrepancy import (
    PhaseDiscrepancy,
    ResidualCurve,
    fit_discrepancy,
    training_residuals,
)
from smcbayes.posterior.extrapolation import Group, leave_out_groups

logger = logging.getLogger(__name__)

LOO = "leave-one-configuration-out refits"
"""Residual source of the error model of configurations inside the training set."""


@dataclass(frozen=True)
class BandErrorModels:
    """Error models of the band configurations.

    Attributes:
        models: per band configuration, its error model (None: white noise).
        sources: per band configuration, the residuals its model was learnt from, in words.
        base: the model learnt from the leave-one-out residuals (or those at the calibrated
            point), the one of configurations inside the training set.
        base_source: its residuals, in words.
        runs: forward runs made for the residuals (and the contact offsets).
        extra: summary blocks of the leave-group-out models (with the configurations using each).
        offsets_mm: each training configuration's contact offset at the calibrated point
            (mm; empty at the nominal contact): the scatter a new trial's bands mix over.
    """

    models: dict[str, PhaseDiscrepancy | None]
    sources: dict[str, str]
    base: PhaseDiscrepancy | None
    base_source: str
    runs: int
    extra: list[dict[str, Any]] = field(default_factory=list)
    offsets_mm: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, Any] | None:
        """The ``discrepancy`` block of ``posterior/summary.json``."""
        if self.base is None:
            return None
        out = {**self.base.as_dict(), "residuals": self.base_source, "extrapolation": self.extra}
        if self.offsets_mm:
            out["contact_offsets_mm"] = self.offsets_mm
        return out


def training_offsets_mm(ctx: RunContext) -> dict[str, float]:
    """Each training configuration's contact offset (mm) at the calibrated point, where each
    trial has one (``[loss] contact``, profiled or measured from its end state; else empty)."""
    p = ctx.problem
    if not p.project.loss.per_trial_contact:
        return {}
    results = ctx.runner.simulate(np.atleast_2d(ctx.best_theta), p.train_ids)
    return contact_offsets_mm(results, p.dataset, p.project.loss, p.train_ids)


def _group_plans(ctx: RunContext, band_ids: Sequence[str]) -> dict[str, tuple[list[Group], str]]:
    p = ctx.problem
    return {cid: leave_out_groups(p.project, p.train_ids, cid) for cid in band_ids}


def _pooled(per_group: Sequence[Sequence[ResidualCurve]]) -> list[ResidualCurve]:
    return [c for curves in per_group for c in curves]


def band_error_models(ctx: RunContext, fit: LocalFit | None, band_ids: Sequence[str]) -> BandErrorModels:
    """The error model of every band configuration and the runs its residuals took.

    Leave-one-out and leave-group-out residuals where the local fit is usable and there are
    at least two training configurations; a leave-group-out model needs residuals of two
    configurations, else the configuration keeps the leave-one-out model.  Without usable
    refits, the residuals at the calibrated point serve every configuration (one run per
    training configuration, counted beside any refits already made).
    """
    p = ctx.problem
    offsets = training_offsets_mm(ctx)
    runs = len(p.train_ids) if p.project.loss.per_trial_contact else 0
    if fit is not None and not fit.usable:
        logger.info("a perturbed run at the best point failed: the bands' error model uses the "
                    "residuals at the calibrated point")
    if fit is not None and fit.usable and len(fit.config_ids) >= 2:
        plans = _group_plans(ctx, band_ids)
        extra = list(dict.fromkeys(g for gs, _ in plans.values() for g in gs))
        k = len(fit.config_ids)
        per_group, refit_runs = leave_out_residuals(ctx.runner, ctx.space, fit, p.dataset.measurements,
                                                    p.project.loss, singletons(k) + extra)
        runs += refit_runs
        loo = _pooled(per_group[:k])
        if len(loo) >= 2:
            models = assemble(fit_discrepancy(loo), plans, dict(zip(extra, per_group[k:], strict=True)), runs)
            return replace(models, offsets_mm=offsets)
        logger.warning("only %d leave-one-out refit(s) ran; the bands' error model uses the residuals "
                       "at the calibrated point, which understate the error on an unseen trial", len(loo))
    delays = {c: o / p.dataset.measurements[c].speed_mm_s for c, o in offsets.items()
              if p.dataset.measurements[c].speed_mm_s}
    limits = {c: m.force_limit_kN for c, m in p.dataset.measurements.items()}
    curves = training_residuals(ctx.runner, ctx.best_theta, p.train_ids, p.measured_force(p.train_ids),
                                delays, limits)
    base = fit_discrepancy(curves)
    return BandErrorModels({cid: base for cid in band_ids}, {cid: "calibrated point" for cid in band_ids},
                           base, "calibrated point", runs + len(p.train_ids), offsets_mm=offsets)


def assemble(base: PhaseDiscrepancy | None, plans: dict[str, tuple[list[Group], str]],
              curves: dict[Group, list[ResidualCurve]], runs: int) -> BandErrorModels:
    """Per band configuration, the leave-group-out model of its gap, or ``base``."""
    models: dict[str, PhaseDiscrepancy | None] = {}
    sources: dict[str, str] = {}
    built: dict[tuple[Group, ...], tuple[PhaseDiscrepancy | None, str]] = {}
    for cid, (groups, words) in plans.items():
        pooled = _pooled([curves[g] for g in groups])
        if groups and len({c.config_id for c in pooled}) >= 2:
            key = tuple(groups)
            if key not in built:
                built[key] = (fit_discrepancy(pooled), f"leave-group-out refits: {words}")
            models[cid], sources[cid] = built[key]
        else:
            models[cid], sources[cid] = base, LOO
    extra = [{**model.as_dict(), "residuals": words,
              "configurations": [c for c in plans if sources[c] == words]}
             for model, words in built.values() if model is not None]
    return BandErrorModels(models, sources, base, LOO, runs, extra)
