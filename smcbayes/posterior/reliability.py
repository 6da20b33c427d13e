"""Whether a posterior can be trusted, in plain reasons (``posterior/summary.json``'s
``reliable``).

A posterior is reported unreliable when its own diagnostics fail: the importance weights
(Pareto k-hat > 0.7, Vehtari et al. 2024, "Pareto smoothed importance sampling", JMLR 25)
or, without a correction, the emulator chains (R-hat > 1.05, Vehtari et al. 2021,
"Rank-normalization, folding, and localization", Bayesian Analysis 16) and the emulator's
error at posterior draws (above 1 nat the emulated likelihood misplaces mass) and the
emulator's spread (the posteriors of GP sample functions move a quantile by more than
:data:`~smcbayes.posterior.spread.SPREAD_MAX` of its range, :mod:`smcbayes.posterior.spread`;
for the curve emulator, also when a sample function's posterior rests on too few points of
the emulated posterior's sample to measure it, :mod:`smcbayes.posterior.curve_spread`).  Two
degenerate cases are named as well: a posterior that is the prior (the data do not inform
the parameters) and a loss that vanishes at the best point (noise-free data: the
likelihood -(N_eff/2) log L has a spike there, and no sampler or emulator can resolve it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from smcbayes.forward.parameters import ParameterSpace
from smcbayes.posterior.correct import K_HAT_WARN, draws_advice
from smcbayes.posterior.curve_progress import CONFIRMATIONS, QUANTILE_SHIFT
from smcbayes.posterior.curve_spread import SPREAD_MIN_ESS
from smcbayes.posterior.spread import SPREAD_MAX, share_words

R_HAT_MAX = 1.05
CHECK_MAX_NATS = 1.0
PRIOR_SHARE = 0.8
"""A 90 % interval wider than this share of its search range does not narrow the prior."""
VANISHING_LOSS_KN2 = 1e-8
"""A best loss below this (kN^2) is a curve reproduced to round-off: noise-free data."""
UNSEEN_NOTE = ("the emulator's checks look only where its posterior lies, so a region it wrongly "
               "rates as poor goes unseen (on the measured thesis trials every seed missed a tail "
               "holding 6-9 % of the corrected posterior); the built-in model is cheap: on a copy of "
               "the run directory, smcbayes posterior COPY --correct-draws 60000 draws the posterior "
               "corrected by the forward model to compare (minutes; its verdict says whether it settled)")
"""The note on a reliable posterior of the emulator alone where the simulator is cheap."""
MARGIN_SE = 3.0
"""A spread within this many of its standard errors below :data:`SPREAD_MAX` is a marginal
pass.  Three, not two, as the bootstrap over the supports ran low on the one run where it
was checked: on the final emulator and importance sample of a run on the nine measured
thesis trials, ten readings on twelve supports had a standard deviation of 0.013 where
their bootstrap standard errors averaged 0.008 (0.017 against 0.012 on four supports,
sharing supports with those).  Three of them are then about two of a fresh reading's."""
NOISE_FREE_REASON = ("the training curves are noise-free simulator output: the loss vanishes at the "
                     "truth, so the likelihood is a spike there and the posterior is degenerate "
                     "(only the calibrated point means something); calibrate against measured or "
                     "noisy synthetic curves (smcbayes synth --noise-kN 5)")


def _past(value: float | None, bound: float) -> str:
    """``value`` in two significant digits, in four decimals where two would print it as the
    ``bound`` it is compared with (a spread of 0.1002 read "0.1 (> 0.1)"); "not measured"
    for ``None``."""
    if value is None:
        return "not measured"
    short = f"{value:.2g}"
    return f"{value:.4f}" if float(short) == float(f"{bound:.2g}") and value != bound else short


def _interval_share(space: ParameterSpace, row: Mapping[str, Any]) -> float:
    """Width of the 90 % interval as a share of the search range (log10 where searched so)."""
    p = next(q for q in space.free if q.name == row["name"])
    lo, hi, a, b = p.lower, p.upper, row["q05"], row["q95"]
    if p.log:
        if min(lo, a) <= 0:
            return math.nan
        lo, hi, a, b = (math.log10(v) for v in (lo, hi, a, b))
    return (b - a) / (hi - lo) if hi > lo else math.nan


def _emulator_sample_reasons(corr: Mapping[str, Any]) -> list[str]:
    """Why an importance sample of the emulated posterior (no forward run) is not to be trusted."""
    if not corr.get("k_hat", math.inf) <= K_HAT_WARN:
        return [f"the importance sampling of the emulated posterior is unreliable (Pareto k-hat "
                f"{corr['k_hat']:.2f} > {K_HAT_WARN}): the emulated posterior has regions its proposals "
                "miss; raise --refine"]
    if not corr.get("settled", False):
        return [f"the importance sampling of the emulated posterior did not settle (ESS "
                f"{float(corr.get('ess') or 0.0):.0f}); raise --refine"]
    return []


def chains_r_hat(info: Mapping[str, Any]) -> float:
    """The largest R-hat of the emcee chains of a posterior summary ``info``; NaN when there
    is none or when any parameter's is missing or NaN (so that it reads as not converged,
    whatever the parameters' order).

    Read from the chains' own table (``emulator_parameters``): an importance-weighted
    ``parameters`` table has none (null).  A summary without that table (written by hand,
    or before the stage kept it) has its chains' R-hat in ``parameters``.
    """
    rows = info.get("emulator_parameters") or info.get("parameters") or []
    values = [p.get("r_hat") for p in rows]
    if not values or any(v is None or not math.isfinite(v) for v in values):
        return math.nan
    return float(max(values))


def _sampling_reasons(info: Mapping[str, Any]) -> list[str]:
    corr = info.get("correction") or {}
    emulated = corr.get("target") == "emulator"
    if corr.get("enabled") and not emulated:
        if not corr.get("k_hat", math.inf) <= K_HAT_WARN:
            return [f"the importance weights are unreliable (Pareto k-hat {corr['k_hat']:.2f} > "
                    f"{K_HAT_WARN}): the emulated posterior misses part of the exact one; raise "
                    "--correct-draws or --refine"]
        if not corr.get("settled", False):
            ess = float(corr.get("ess") or 0.0)
            # summaries written before the estimate of the draws needed, and an infinite
            # target (written as null), give the plain remedy
            target = corr.get("ess_target")
            target = math.inf if target is None else target
            advice = draws_advice(ess, target, corr.get("draws_needed"), len(corr.get("history") or []))
            of = f" of {target:.0f}" if math.isfinite(target) else ""
            return [f"the importance correction did not settle (ESS {ess:.0f}{of}); {advice}"]
        return []
    out = _emulator_sample_reasons(corr) if corr.get("enabled") else []
    active = info.get("active_learning") or {}
    if active.get("enabled") and not active.get("converged"):
        out.append(_budget_reason(active))
    r_hat = chains_r_hat(info)
    # an importance sample of the emulated posterior is judged by its weights, not the chains'
    if not emulated and not r_hat <= R_HAT_MAX:
        out.append(f"the emulator chains did not converge (R-hat {r_hat:.2f} > {R_HAT_MAX}); run "
                   "longer (--steps)")
    check = (info.get("emulator_check") or {}).get("mean_abs_error", math.nan)
    if not check <= CHECK_MAX_NATS:
        # a check of 1.02 would read "1 nats off (> 1.0)" in two digits
        out.append(f"the emulator is {_past(check, CHECK_MAX_NATS)} nats off at posterior draws "
                   f"(> {CHECK_MAX_NATS}) and nothing corrects it; use the correction (--correct-draws) "
                   "or --refine")
    # a validated active learning stops at the same point with a larger budget, unless only
    # the budget's end let it stop: by counting rounds from before a failed confirmation, or
    # by confirming at all after its last allowed failed confirmation
    failed = sum(1 for c in active.get("confirmations") or [] if not c.get("passed"))
    same_point = (bool(active.get("converged")) and not active.get("validated_at_budget_end")
                  and failed < CONFIRMATIONS)
    spread = info.get("emulator_spread")
    if spread and not spread["max_quantile_shift"] <= SPREAD_MAX:
        worst = max(spread["per_parameter"], key=spread["per_parameter"].get)
        remedy = ("use the correction (--correct-draws) where the simulator is cheap, or lower "
                  "refine_tolerance_nats in the project's [posterior] table" if same_point
                  else "raise --refine or use the correction (--correct-draws)")
        which = ("a GP sample function" if spread.get("shift_level", 1.0) >= 1.0
                 else share_words(spread, "GP sample function "))
        out.append(f"the emulator's own uncertainty moves the posterior: with {which} instead of its mean "
                   f"a 5/50/95 % quantile of {worst} moves by "
                   f"{_past(spread['max_quantile_shift'], SPREAD_MAX)} of its range or more "
                   f"(> {SPREAD_MAX}{_standard_error(spread)}), so a tail or an arm of the posterior is not "
                   f"pinned down yet; {remedy}")
    thin = _thin_functions(spread or {})
    if thin:
        remedy = ("lower refine_tolerance_nats in the project's [posterior] table" if same_point
                  else "raise --refine")
        out.append(f"{thin}: such a posterior lies mostly where that sample has no points, so the spread is "
                   f"larger than measured; {remedy}")
    return out


def _standard_error(spread: Mapping[str, Any]) -> str:
    """``"; standard error 0.008"`` for a spread record with one, else empty."""
    se = spread.get("max_quantile_shift_se")
    return "" if se is None else f"; standard error {se:.3f}"


def marginal_spread_note(spread: Mapping[str, Any]) -> str:
    """A note when the spread ``spread`` (an ``emulator_spread`` record) passes
    :data:`SPREAD_MAX` by less than :data:`MARGIN_SE` of its standard error over the
    supports (the curve emulator's reported spread has one); empty otherwise.

    The standard error covers only the draw of the supports, for the emulator and importance
    sample the stage ended with; another seed also learns another emulator."""
    shift, se = spread.get("max_quantile_shift"), spread.get("max_quantile_shift_se")
    if shift is None or se is None or not shift <= SPREAD_MAX < shift + MARGIN_SE * se:
        return ""
    per = spread.get("per_parameter") or {}
    worst = max(per, key=per.get) if per else None
    which, read = (f" of {worst}", f"{worst}'s quantiles") if worst else ("", "the quantiles")
    return (f"a marginal pass: the emulator's spread, the move of a 5/50/95 % quantile{which} by "
            f"{shift:.3f} of its range, lies within {MARGIN_SE:g} standard errors ({se:.3f} each, over its "
            f"supports) of its bound {SPREAD_MAX}; another draw of its supports may read it above the "
            f"bound, and another seed, learning another emulator, varies more; read {read} with this "
            "in mind")


def _thin_functions(spread: dict[str, Any]) -> str:
    """Which GP sample functions' posteriors rest on fewer than :data:`SPREAD_MIN_ESS`
    effective points, in words, when more of them do than the spread's level leaves out
    (any one when the spread is the largest move; the spread's level and the count need not
    leave out the same functions); empty otherwise."""
    ess = np.asarray(spread.get("function_ess") or [], dtype=float)
    count = int(np.count_nonzero(ess < SPREAD_MIN_ESS))
    # the tolerance: 1 - 0.9 is a little below 0.1 in floating point
    if count == 0 or count <= (1.0 - spread.get("shift_level", 1.0)) * len(ess) + 1e-9:
        return ""
    where = f"effective points of the emulated posterior's sample (< {SPREAD_MIN_ESS})"
    if spread.get("shift_level", 1.0) >= 1.0:
        return f"a GP sample function's posterior rests on {np.min(ess):.0f} {where}"
    return (f"{count} of {len(ess)} GP sample functions' posteriors, more than {share_words(spread)}, "
            f"rest on {np.min(ess):.0f}-{np.max(ess[ess < SPREAD_MIN_ESS]):.0f} {where}")


def _budget_reason(active: dict[str, Any]) -> str:
    """Why an active learning that spent its budget did not stop by itself."""
    runs = active.get("evaluations")
    spread = active.get("spread")
    if spread is not None and spread > SPREAD_MAX:
        return (f"the active learning spent its {runs} forward runs while GP sample functions still moved "
                f"a quantile of the posterior by {_past(spread, SPREAD_MAX)} of its range (> {SPREAD_MAX}) "
                f"after {active.get('spread_checks')} measurement(s); raise --refine")
    if active.get("kind") == "curves":
        return _curve_budget_reason(active)
    err, shift = active.get("error_nats"), active.get("quantile_shift")
    words = "not measured" if err is None else f"{err:.2g} nats"
    moved = ("the quantiles' move between its last rounds not measured" if shift is None
             else f"quantiles still moving by {shift:.2g} of their range")
    return (f"the active learning spent its {runs} forward runs before the emulator was validated "
            f"where the posterior lies (last out-of-sample error {words}, {moved}); raise --refine")


def _curve_budget_reason(active: dict[str, Any]) -> str:
    """Why the curve emulator's active learning was not validated: its last rounds' errors
    and quantile moves, each of which must be within its bound, their spreads, whose mean
    must be, and the posterior's drift over them, when it was measured."""
    def words(values: list[float | None], unit: str) -> str:
        return ", ".join("not measured" if v is None else f"{v:.2g}{unit}" for v in values) or "none"

    errors, shifts = active.get("last_errors_nats") or [], active.get("last_quantile_shifts") or []
    spreads = active.get("last_spreads") or []
    spread_words = ("" if not spreads else f"; their sample functions moving a quantile by "
                    f"{words(spreads, '')}, their mean to be at most {SPREAD_MAX}")
    drift = active.get("drift")
    if drift is not None:
        spread_words += (f"; the posterior's quantiles moving by {drift:.2g} over those rounds, to be "
                         f"at most {QUANTILE_SHIFT}")
    failed = [c for c in active.get("confirmations") or [] if not c.get("passed")]
    # rounds that validated but whose reported posterior did not confirm them
    confirm_words = ("" if not failed else f"; when its rounds last passed, after "
                     f"{failed[-1]['forward_runs']} forward runs, the reported posterior's sample "
                     f"functions moved a quantile by {_past(failed[-1]['spread'], SPREAD_MAX)} "
                     f"(> {SPREAD_MAX})")
    # the budget's own last confirmation asked for nothing more: only those before it count
    if len([c for c in failed if c["forward_runs"] < active.get("evaluations", 0)]) >= CONFIRMATIONS:
        confirm_words += (f"; after {CONFIRMATIONS} failed confirmations it asked for none until its "
                          "budget's end")
    return (f"the active learning spent its {active.get('evaluations')} forward runs before the emulator was "
            f"validated where the posterior lies (its last rounds' errors at fresh posterior draws "
            f"{words(errors, ' nats')}, each to be within {active.get('tolerance_nats', math.nan):.2g}; "
            f"their quantile moves {words(shifts, '')}, each to be at most {QUANTILE_SHIFT} of the range"
            f"{spread_words}{confirm_words}); raise --refine")


def assess(info: Mapping[str, Any], space: ParameterSpace, best_loss_kN2: float | None,
           noise_free: bool = False, cheap: bool = False) -> dict[str, Any]:
    """``{"reliable": bool, "reasons": [...], "notes": [...]}`` for a posterior summary ``info``.

    ``reasons`` make the posterior unreliable; ``notes`` (``info["shape"]``, from
    :func:`smcbayes.posterior.shape.shape_notes`, and a spread within :data:`MARGIN_SE`
    standard errors below its bound) say how to read one that may be right, and
    a reliable posterior of the emulator alone from a ``cheap`` simulator (the built-in
    model) gets :data:`UNSEEN_NOTE`.  ``noise_free`` says the training curves are simulator
    output without noise (a truth check, or ``smcbayes synth`` with every noise term 0).
    """
    reasons = _sampling_reasons(info)
    shares = [_interval_share(space, row) for row in info.get("parameters") or []]
    if shares and all(s > PRIOR_SHARE for s in shares):
        reasons.append(f"the posterior is the prior: every 90 % interval spans more than "
                       f"{PRIOR_SHARE:.0%} of its search range, so the data do not inform the "
                       "parameters (fix some, or add data that do)")
    if noise_free or (best_loss_kN2 is not None and 0 <= best_loss_kN2 < VANISHING_LOSS_KN2):
        # the failed sampling diagnostics follow from the spike: their remedies would mislead
        reasons = [NOISE_FREE_REASON]
    notes = list(info.get("shape") or [])
    marginal = marginal_spread_note(info.get("emulator_spread") or {})
    if marginal and not reasons:
        notes.append(marginal)
    if cheap and not reasons and not (info.get("forward_evaluations") or {}).get("correction"):
        notes.append(UNSEEN_NOTE)
    return {"reliable": not reasons, "reasons": reasons, "notes": notes}
