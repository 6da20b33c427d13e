"""Which unmodelled effect explains the gap: signature, re-calibration, held-out test.

**Signature** (cheap, before any re-calibration): at the warm start (base optimum, effect
parameters at their defaults) the force residual ``r0`` and its finite-difference Jacobian
``J`` in the unit cube (all free parameters, one batched forward call of ``d + 1`` rows)
give

* ``sensitivity_kN``: the largest RMS change of the force over the comparison windows when
  one effect parameter moves across its whole range (linearised);
* ``absorbable_share``: ``1 - L_pred / L_base``, where ``L_pred`` is the loss after one
  bounded Gauss-Newton step (``min ||r0 - J delta||``, the step kept inside the unit cube)
  and ``L_base`` the base model's loss: the share of the base misfit the effect can absorb.

**Score** (after the warm-started re-calibration on the fitting configurations): the
penalised held-out log-likelihood ratio against the base model re-fitted with the same
optimiser, Gaussian errors with the variance profiled out and ``N_eff`` independent points
(``N / integrated autocorrelation time``, summed over the held-out configurations, of the
residuals of the model with the lowest held-out loss, base included: the one closest to
pure noise; one common value, so that the scores of all candidates are comparable)::

    score = (N_eff_ho / 2) ln(L_ho_base / L_ho_effect) - (k / 2) ln(N_eff_fit)

with ``k`` the effect's extra free parameters (a BIC penalty, ``N_eff_fit`` likewise from the
residuals of the best-fitting model on the fitting configurations).  Candidates are ranked
by it.  The score is a log
Bayes factor in BIC approximation evaluated out of sample.

**Decision** ("no effect explains the gap beyond noise" otherwise): an effect is named only
if the top score reaches ``min_score`` (default 3: a Bayes factor of 20, "strong" evidence
on the Kass-Raftery scale); of the significant candidates within ``min_score`` of the top
score, the one with the largest evidence on all trials is named (:func:`choose`).  Under
noise alone the held-out log ratio fluctuates by about ``sqrt(2 / N_eff_ho)``, i.e. the
score by about ``sqrt(N_eff_ho / 2)`` minus the penalty, so the threshold compares the
improvement with its sampling noise.  Also reported: a
Diebold-Mariano statistic ``z`` on the pointwise differences of squared residuals
``d_i = r_base,i^2 - r_effect,i^2`` with the variance inflated by the autocorrelation time of
``d``; it treats systematic misfit as random and is therefore conservative with few held-out
curves, which is why it is evidence, not the decision rule.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import lsq_linear

from smcbayes.diagnose.fit import (
    DiagnosisContext,
    Fit,
    FitSettings,
    fixed_offset_losses,
    held_out_offsets,
    initial_population,
    residual_stack,
)
from smcbayes.posterior.likelihood import effective_points, integrated_autocorr_time

Array = NDArray[np.float64]

#: Unit-cube step of the finite-difference signature.
FD_STEP = 0.05


@dataclass(frozen=True)
class Signature:
    """Cheap signature of one candidate effect (see the module docstring)."""

    effect: str
    sensitivity_kN: float
    most_sensitive: str
    absorbable_share: float
    predicted_loss_kN2: float


def signature(ctx: DiagnosisContext, effect: str, base: Fit, ids: Sequence[str],
              rng: np.random.Generator, probes: int = 8) -> Signature:
    """Sensitivity and absorbable share of ``effect`` at the base optimum (module docstring).

    The linearisation point is the best of the effect's defaults and ``probes`` Latin-hypercube
    values of its parameters (base parameters at their optimum): an effect's defaults can be
    far from anything the data allow, where one linear step says nothing.
    """
    model = ctx.model([effect])
    space = model.space
    u0 = np.clip(space.to_unit(ctx.start([effect], base.params))[0], 0.0, 1.0)
    cols_e = effect_columns(ctx, (effect,))
    probe = FitSettings(population=probes + 1, lhs_starts=probes, global_starts=0)
    starts = initial_population(u0, cols_e, probe, rng, share=False)
    loss0 = np.mean(ctx.losses([effect], space.from_unit(starts), ids), axis=1)
    u0 = starts[int(np.nanargmin(np.where(np.isfinite(loss0), loss0, np.inf)))]
    d = u0.size
    steps = np.where(u0 + FD_STEP <= 1.0, FD_STEP, -FD_STEP)
    rows = np.vstack([u0, u0 + np.diag(steps)])
    res, _ = residual_stack(ctx, [effect], space.from_unit(rows), ids)
    K = len(ids)
    r0 = np.concatenate([res[c][0] / np.sqrt(res[c].shape[1] * K) for c in ids])
    cols = np.column_stack([
        np.concatenate([-(res[c][j + 1] - res[c][0]) / steps[j] / np.sqrt(res[c].shape[1] * K)
                        for c in ids]) for j in range(d)])
    ok = np.all(np.isfinite(cols), axis=0)
    r0 = np.nan_to_num(r0)
    sol = lsq_linear(cols[:, ok], r0, bounds=(-u0[ok], 1.0 - u0[ok])) if ok.any() else None
    left = r0 - cols[:, ok] @ sol.x if sol is not None else r0
    pred = float(np.sum(left**2))
    # RMS over all points of one column = sqrt(sum of squares * K) after the 1/sqrt(N K) scaling
    rms = [float(np.sqrt(np.sum(np.nan_to_num(cols[:, j]) ** 2) * K)) for j in cols_e]
    j_best = int(np.argmax(rms)) if rms else 0
    names = [space.free_names[j] for j in cols_e]
    return Signature(effect, rms[j_best] if rms else 0.0, names[j_best] if rms else "",
                     1.0 - pred / base.loss if base.loss > 0 else 0.0, pred)


def effect_columns(ctx: DiagnosisContext, extra: Sequence[str]) -> list[int]:
    """Columns of the free parameters that ``extra`` adds to the base model."""
    base = set(ctx.model(()).space.names)
    return [i for i, n in enumerate(ctx.model(extra).space.free_names) if n not in base]


@dataclass(frozen=True)
class HeldOutTest:
    """Held-out comparison of a candidate with the base model.

    Attributes:
        loss_base_kN2, loss_kN2: held-out loss of base and candidate (kN^2).
        z: Diebold-Mariano statistic of the improvement (positive: candidate better).
    """

    loss_base_kN2: float
    loss_kN2: float
    z: float


def held_out_test(ctx: DiagnosisContext, base: Fit, cand: Fit, ids: Sequence[str]) -> HeldOutTest:
    """Diebold-Mariano comparison of ``cand`` against ``base`` on the held-out ``ids``
    (where each trial has a contact offset, each model's held-out trials by their curves
    averaged over its fitting trials' offsets)."""
    off_b = held_out_offsets(ctx, base.effects, base.theta, ids)
    off_c = held_out_offsets(ctx, cand.effects, cand.theta, ids)
    _, ends_b = residual_stack(ctx, base.effects, base.theta, ids, offsets_mm=off_b)
    _, ends_c = residual_stack(ctx, cand.effects, cand.theta, ids, offsets_mm=off_c)
    ends = {c: max(ends_b[c], ends_c[c]) for c in ids}
    rb, _ = residual_stack(ctx, base.effects, base.theta, ids, ends, off_b)
    rc, _ = residual_stack(ctx, cand.effects, cand.theta, ids, ends, off_c)
    means, variances = [], []
    for c in ids:
        a, b = rb[c][0], rc[c][0]
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            return HeldOutTest(np.nan, np.nan, -np.inf)
        dlt = a**2 - b**2
        means.append(float(np.mean(dlt)))
        variances.append(float(np.var(dlt)) * integrated_autocorr_time(dlt) / dlt.size)
    K = len(ids)
    diff = float(np.mean(means))
    se = float(np.sqrt(np.sum(variances))) / K
    z = diff / se if se > 0 else (np.inf if diff > 0 else 0.0)
    lb, lc = (float(np.mean(ctx.losses(f.effects, f.theta, ids)[0] if off is None
                            else fixed_offset_losses(ctx, f.effects, f.theta, ids, off)[0]))
              for f, off in ((base, off_b), (cand, off_c)))
    return HeldOutTest(lb, lc, z)


def n_eff_of(ctx: DiagnosisContext, fit: Fit, ids: Sequence[str], held_out: bool = False) -> float:
    """Effective independent points of ``fit``'s force residuals on ``ids`` (summed); held-out
    trials' curves averaged over the fitting trials' contact offsets where each trial has one."""
    offsets = held_out_offsets(ctx, fit.effects, fit.theta, ids) if held_out else None
    res, _ = residual_stack(ctx, fit.effects, fit.theta, ids, offsets_mm=offsets)
    _, n_eff = effective_points([np.nan_to_num(res[c][0]) for c in ids])
    return float(np.sum(n_eff))


def extra_parameters(ctx: DiagnosisContext, extra: Sequence[str]) -> int:
    """Free parameters the candidate adds to the base model."""
    return ctx.model(extra).space.dim - ctx.model(()).space.dim


def score_row(ctx: DiagnosisContext, base: Fit, cand: Fit, test: HeldOutTest,
              n_eff_fit: float, n_eff_ho: float, min_score: float) -> dict:
    """One ranking row: losses, evidence and the decision of one candidate."""
    k = extra_parameters(ctx, cand.effects)
    ratio = test.loss_base_kN2 / test.loss_kN2 if test.loss_kN2 > 0 else np.inf
    score = 0.5 * n_eff_ho * np.log(ratio) - 0.5 * k * np.log(max(n_eff_fit, 1.0))
    dbic = n_eff_fit * np.log(cand.loss / base.loss) + k * np.log(max(n_eff_fit, 1.0))
    return {
        "effect": "+".join(cand.effects), "extra_parameters": k,
        "fit_loss_kN2": cand.loss, "fit_loss_base_kN2": base.loss,
        "holdout_loss_kN2": test.loss_kN2, "holdout_loss_base_kN2": test.loss_base_kN2,
        "holdout_shrink_pct": 100.0 * (1.0 - test.loss_kN2 / test.loss_base_kN2),
        "dm_z": float(test.z), "delta_bic_fit": float(dbic), "score": float(score),
        "evidence": all_trial_evidence(n_eff_fit, n_eff_ho, (base.loss, cand.loss),
                                       (test.loss_base_kN2, test.loss_kN2), k),
        "n_eff_holdout": n_eff_ho, "n_eff_fit": n_eff_fit,
        "significant": bool(np.isfinite(score) and score >= min_score),
        "params": {n: v for n, v in cand.params.items() if n not in ctx.model(()).space.names},
        "evaluations": cand.evaluations,
    }


def all_trial_evidence(n_eff_fit: float, n_eff_ho: float, fit_losses_kN2: tuple[float, float],
                       holdout_losses_kN2: tuple[float, float], k: int) -> float:
    """Log Bayes factor of a candidate against its base on the fitting *and* held-out trials.

    By the chain rule p(D_fit, D_ho) = p(D_fit) p(D_ho | D_fit) (Dawid 1984, "The
    prequential approach", J. R. Stat. Soc. A 147): the fitting trials' evidence in BIC
    approximation, (N_fit / 2) ln(L_fit,base / L_fit) - (k / 2) ln N_fit, plus the held-out
    trials' log-likelihood ratio at the fitted parameters, (N_ho / 2) ln(L_ho,base / L_ho).
    The held-out score alone ranks the candidates; this breaks near-ties between them
    (:func:`choose`).  NaN where a loss is not positive and finite.

    Args:
        n_eff_fit, n_eff_ho: effective independent points on the fitting and held-out trials.
        fit_losses_kN2, holdout_losses_kN2: ``(base, candidate)`` losses (kN^2).
        k: free parameters the candidate adds to its base.
    """
    losses = np.array([*fit_losses_kN2, *holdout_losses_kN2], dtype=float)
    if not np.all(np.isfinite(losses) & (losses > 0)):
        return float("nan")
    fb, fc, hb, hc = losses
    return float(0.5 * n_eff_fit * np.log(fb / fc) + 0.5 * n_eff_ho * np.log(hb / hc)
                 - 0.5 * k * np.log(max(n_eff_fit, 1.0)))


def choose(rows: Sequence[dict[str, Any]], min_score: float) -> dict[str, Any] | None:
    """The candidate to name among ranking rows (``score``, ``significant``, ``evidence``).

    ``None`` unless the best-scoring row is significant (the window below does not rescue
    a top row that fails its own test).  The held-out trials decide unless they cannot:
    the significant rows whose score lies within ``min_score`` of the best (a held-out
    Bayes factor below exp(min_score) between them) are not told apart by the held-out
    trials, and among them the one with the largest :func:`all_trial_evidence` is named;
    the best-scoring row itself when its evidence is not finite (nothing to compare it
    with).  With a few held-out trials an effect that only shifts the timing can match the
    held-out score of one that also fits the fitting trials' shape, at a fitting loss
    several times larger; that effect then extrapolates worst to a new charge.
    """
    scored = [r for r in rows if np.isfinite(r["score"])]
    if not scored:
        return None
    top = max(scored, key=lambda r: r["score"])
    if not top["significant"]:
        return None
    if not np.isfinite(top["evidence"]):
        return top
    near = [r for r in scored if r["significant"] and r["score"] >= top["score"] - min_score
            and np.isfinite(r["evidence"])]
    return max(near, key=lambda r: r["evidence"])
