"""Forward selection of an effect set by the held-out score.

The single-effect ranking (:func:`smcbayes.diagnose.run.which_effect`) names the best
effect; an effect that only helps together with another one (the press frame's compliance
once the charge is compressible) ranks low there.  Forward selection (stepwise regression
in the sense of Efroymson 1960, with the held-out score of the diagnosis as the criterion):
start from the selected best effect, re-calibrate every remaining candidate *together with*
the selected set, score each against the selected set on the held-out configurations
(Diebold-Mariano comparison and the penalised score of
:func:`smcbayes.diagnose.which.score_row`, the penalty counting only the parameters the step
adds), add the best if its score reaches ``min_score`` and its Diebold-Mariano z reaches
:data:`MIN_Z` (among significant candidates within ``min_score`` of the best score, the one
with the largest evidence on all trials, :func:`smcbayes.diagnose.which.choose`), and stop
when none does or the set holds ``max_effects``.  Before each step
the selected set is re-calibrated once more from its own optimum, with the candidates' budget,
so that a candidate is compared with an equally searched set (Diebold & Mariano 1995,
"Comparing predictive accuracy", J. Bus. Econ. Stat. 13).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from smcbayes.diagnose.fit import DiagnosisContext, Fit, FitSettings, refit
from smcbayes.diagnose.which import all_trial_evidence, choose, extra_parameters, held_out_test, score_row

logger = logging.getLogger(__name__)

MIN_Z = 2.0
"""Diebold-Mariano z a step must reach besides the penalised score: once the set fits to the
noise, a small loss ratio over many correlated held-out points can pass the score alone."""


def step_row(ctx: DiagnosisContext, current: Fit, cand: Fit, holdout: Sequence[str], n_eff_fit: float,
             n_eff_ho: float, min_score: float) -> dict[str, Any]:
    """``cand`` scored against ``current`` on ``holdout``; the penalty counts the parameters
    ``cand`` adds to ``current`` only."""
    test = held_out_test(ctx, current, cand, holdout)
    row = score_row(ctx, current, cand, test, n_eff_fit, n_eff_ho, min_score)
    added = extra_parameters(ctx, cand.effects) - extra_parameters(ctx, current.effects)
    ratio = test.loss_base_kN2 / test.loss_kN2 if test.loss_kN2 > 0 else np.inf
    score = 0.5 * n_eff_ho * np.log(ratio) - 0.5 * added * np.log(max(n_eff_fit, 1.0))
    evidence = all_trial_evidence(n_eff_fit, n_eff_ho, (current.loss, cand.loss),
                                  (test.loss_base_kN2, test.loss_kN2), added)
    row.update(extra_parameters=added, score=float(score), evidence=evidence,
               significant=bool(np.isfinite(score) and score >= min_score and row["dm_z"] >= MIN_Z))
    return row


def forward_selection(ctx: DiagnosisContext, first: Fit, candidates: Sequence[str], fit_ids: Sequence[str],
                      holdout: Sequence[str], fit: FitSettings, rng: np.random.Generator,
                      evidence: tuple[float, float], min_score: float, max_effects: int,
                      log: Callable[[str], None]) -> tuple[list[str], list[dict[str, Any]], dict[str, Fit]]:
    """Grow the effect set from ``first`` (the fit of the best single effect).

    Args:
        first: fit of the selected best single effect.
        candidates: the other effects, in their single-effect rank order.
        evidence: ``(n_eff_fit, n_eff_holdout)`` of the diagnosis.
        max_effects: largest set size.

    Returns:
        The selected effects, one row per step (the effect added or ``None``, the held-out
        losses before and after, score, significance, every candidate's score) and the fits
        of the grown sets by name (``"a+b"``).
    """
    selected, current = list(first.effects), first
    steps: list[dict[str, Any]] = []
    fits: dict[str, Fit] = {}
    remaining = [c for c in candidates if c not in selected]
    while len(selected) < max_effects and remaining:
        # the selected set gets the same extra search from its own optimum as each candidate
        # does, so that a candidate cannot win by the second search alone
        again = refit(ctx, tuple(selected), fit_ids, ctx.start(tuple(selected), current.params), fit, rng,
                      desc=f"selection: {'+'.join(selected)} again")
        current = again if again.loss < current.loss else current
        tried = []
        for name in remaining:
            extra = (*selected, name)
            start = ctx.start(extra, current.params)
            cand = refit(ctx, extra, fit_ids, start, fit, rng, desc=f"selection: {'+'.join(extra)}")
            tried.append((step_row(ctx, current, cand, holdout, *evidence, min_score), cand))
            log(f"selection: {'+'.join(extra)}: held-out loss {tried[-1][0]['holdout_loss_kN2']:.4g} vs "
                f"{tried[-1][0]['holdout_loss_base_kN2']:.4g} kN^2, score {tried[-1][0]['score']:.3g}")
        best = max(tried, key=lambda rc: rc[0]["score"] if np.isfinite(rc[0]["score"]) else -np.inf)
        chosen = choose([r for r, _ in tried], min_score)
        row, cand = next((rc for rc in tried if rc[0] is chosen), best)
        added = cand.effects[-1]
        # the best-scoring candidate's last effect when a near-tie went to another one
        over = None if row is best[0] else best[1].effects[-1]
        steps.append({"added": added if row["significant"] else None, "best_candidate": added,
                      "holdout_loss_before_kN2": row["holdout_loss_base_kN2"],
                      "holdout_loss_after_kN2": row["holdout_loss_kN2"],
                      "holdout_shrink_pct": row["holdout_shrink_pct"], "score": row["score"],
                      "dm_z": row["dm_z"], "significant": row["significant"], "chosen_over": over,
                      "candidates": {r["effect"]: r["score"] for r, _ in tried},
                      "evidence": {r["effect"]: r["evidence"] for r, _ in tried}})
        if not row["significant"]:
            break
        selected.append(added)
        fits["+".join(cand.effects)] = current = cand
        remaining.remove(added)
    return selected, steps, fits
