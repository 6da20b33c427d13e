"""The whole diagnosis of a calibration: where, which effect, how far it shrinks; on disk.

Outputs in ``DIR``: ``summary.json`` (machine-readable: settings, where, signatures,
ranking, decision, shrink tables), ``ranking.csv`` and ``figures/`` (``heatmap``,
``phase_rmse``, ``before_after``; PNG and SVG).
"""

from __future__ import annotations

import csv
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from smcbayes.config import DiagnoseSpec
from smcbayes.diagnose.figures import before_after, heat_map, phase_bars
from smcbayes.diagnose.fit import DiagnosisContext, Fit, FitSettings, refit
from smcbayes.diagnose.select import forward_selection
from smcbayes.diagnose.shrink import shrink_summary
from smcbayes.diagnose.where import WhereReport, analyse
from smcbayes.diagnose.which import (
    HeldOutTest,
    Signature,
    choose,
    held_out_test,
    n_eff_of,
    score_row,
    signature,
)
from smcbayes.errors import ConfigError, closest
from smcbayes.forward.effects import available, check_names

logger = logging.getLogger(__name__)

RANKING_COLUMNS = ("rank", "effect", "extra_parameters", "sensitivity_kN", "most_sensitive",
                   "absorbable_share", "fit_loss_kN2", "holdout_loss_kN2", "holdout_loss_base_kN2",
                   "holdout_shrink_pct", "n_eff_holdout", "dm_z", "delta_bic_fit", "score",
                   "evidence", "significant")


_DEFAULTS = DiagnoseSpec()


@dataclass(frozen=True)
class DiagnoseSettings:
    """Settings of a diagnosis.

    Attributes:
        candidates: effects to try (not already on in the calibration).
        holdout: held-out configurations (default: :func:`default_holdout`).
        pair: also re-calibrate two effects together: the named one and the best other
            (:func:`pair_members`).
        seed: random seed (same seed, same ranking).
        fit: budget of each re-calibration.
        min_score: penalised held-out score needed to name an effect (a log Bayes factor).
        figures: write the figures.
    """

    candidates: tuple[str, ...]
    holdout: tuple[str, ...] | None = None
    pair: bool = _DEFAULTS.pair
    seed: int = _DEFAULTS.seed
    fit: FitSettings = field(default_factory=FitSettings)
    min_score: float = _DEFAULTS.min_score
    max_effects: int = _DEFAULTS.max_effects
    figures: bool = True


def candidate_effects(chosen: Sequence[str] | None, already_on: Sequence[str],
                      source: str = "effects") -> tuple[str, ...]:
    """The effects to try: ``chosen`` validated (``None``: every registered effect not
    already on in the calibration).

    Raises:
        ConfigError: an unknown or repeated name, one already on, or nothing left to try.
    """
    if chosen is None:
        names = tuple(n for n in sorted(available()) if n not in already_on)
    else:
        names = check_names(chosen, source)
    on = [n for n in names if n in already_on]
    if on:
        raise ConfigError(f"{source}: '{on[0]}' is already on in the calibration; drop it")
    if not names:
        raise ConfigError("no candidate effect to try: every available effect is already on")
    return names


def settings_for(spec: DiagnoseSpec, already_on: Sequence[str], figures: bool = True) -> DiagnoseSettings:
    """The diagnosis's settings from its ``[diagnose]`` table (validated; raises
    :class:`ConfigError` before any forward run)."""
    fit = FitSettings(population=spec.population, generations=spec.generations, restarts=spec.restarts)
    fit.check()
    return DiagnoseSettings(candidates=candidate_effects(spec.effects, already_on),
                            holdout=None if spec.holdout is None else tuple(spec.holdout),
                            pair=spec.pair, seed=spec.seed, fit=fit, min_score=spec.min_score,
                            max_effects=spec.max_effects, figures=figures)


def default_holdout(ctx: DiagnosisContext) -> list[str]:
    """One configuration of each group (same charge shape and coverage) of >= 2 configurations.

    A group of three or more gives its middle speed: an effect fitted on the other speeds
    must predict a new one without extrapolating beyond the fitted speed range.  A group of
    two gives its faster and its slower member in turn (groups in sorted order), so that
    both speeds are fitted and both are tested; holding out one configuration alone would
    let a single trial's scatter choose the effect.  Without any such group, the middle of
    the sorted ids is held out.
    """
    groups: dict[tuple[str, float], list[tuple[float, str]]] = {}
    for cid in ctx.ids:
        spec = ctx.project.get(cid)
        groups.setdefault((spec.charge.shape, spec.charge.coverage_pct), []).append(
            (spec.press.speed_mm_s, cid))
    out, pairs = [], 0
    for key in sorted(groups):
        members = sorted(groups[key])
        if len(members) >= 3:
            out.append(members[len(members) // 2][1])
        elif len(members) == 2:
            out.append(members[(pairs + 1) % 2][1])
            pairs += 1
    if not out:
        out = [sorted(ctx.ids)[len(ctx.ids) // 2]]
    return [c for c in ctx.ids if c in out]


def check_holdout(ctx: DiagnosisContext, holdout: Sequence[str]) -> list[str]:
    """Validated held-out ids; at least one held out and one left to fit."""
    for cid in holdout:
        if cid not in ctx.ids:
            raise ConfigError(f"--holdout: '{cid}' is not a configuration with measurements"
                              f"{closest(cid, ctx.ids)}; choose from {', '.join(ctx.ids)}")
    fit_ids = [c for c in ctx.ids if c not in holdout]
    if not holdout or not fit_ids:
        raise ConfigError("--holdout: hold out at least one configuration and keep at least one "
                          f"to fit (configurations with data: {', '.join(ctx.ids)})")
    return [c for c in ctx.ids if c in holdout]


def _rank(rows: list[dict[str, Any]], sigs: dict[str, Signature]) -> list[dict[str, Any]]:
    """``rows`` best score first, numbered, with each effect's signature numbers."""
    rows = sorted(rows, key=lambda r: -r["score"] if np.isfinite(r["score"]) else np.inf)
    for i, r in enumerate(rows, 1):
        r["rank"] = i
        s = sigs.get(r["effect"])
        r["sensitivity_kN"] = s.sensitivity_kN if s else None
        r["most_sensitive"] = s.most_sensitive if s else None
        r["absorbable_share"] = s.absorbable_share if s else None
    return rows


def which_effect(ctx: DiagnosisContext, settings: DiagnoseSettings, fit_ids: list[str],
                 holdout: list[str], rng: np.random.Generator,
                 log: Callable[[str], None]
                 ) -> tuple[Fit, dict[str, Fit], list[dict[str, Any]], dict[str, Any]]:
    """Re-fit the base and every candidate; rank them; returns base, fits, rows, evidence.

    ``log`` receives one line per finished re-calibration; the progress of each (batched
    forward calls done / total) goes through :class:`smcbayes.progress.Progress`, named
    after the effect and its place among the re-calibrations.
    """
    steps = 1 + len(settings.candidates) + int(settings.pair and len(settings.candidates) >= 2)
    # twice the generations: an effect must not win because the base search stopped early
    base_fit = replace(settings.fit, generations=2 * settings.fit.generations)
    base = refit(ctx, (), fit_ids, ctx.start(()), base_fit, rng, desc=f"diagnosis: base model (1/{steps})")
    log(f"base model re-fitted on {len(fit_ids)} configuration(s): loss {base.loss:.4g} kN^2")
    sigs, fits, tests = {}, {}, {}
    for k, name in enumerate(settings.candidates, 2):
        t0 = time.perf_counter()
        sigs[name] = signature(ctx, name, base, fit_ids, rng)
        start = ctx.start((name,), base.params)
        fits[name] = refit(ctx, (name,), fit_ids, start, settings.fit, rng,
                           desc=f"diagnosis: {name} ({k}/{steps})")
        tests[name] = held_out_test(ctx, base, fits[name], holdout)
        log(f"{name}: absorbable {100 * sigs[name].absorbable_share:.0f} %, held-out loss "
            f"{tests[name].loss_kN2:.4g} vs {tests[name].loss_base_kN2:.4g} kN^2, "
            f"z {tests[name].z:.2f} ({time.perf_counter() - t0:.0f} s)")
    n_eff_fit, n_eff_ho = common_n_eff(ctx, base, fits, tests, fit_ids, holdout)
    rows = _rank([score_row(ctx, base, fits[n], tests[n], n_eff_fit, n_eff_ho, settings.min_score)
                  for n in settings.candidates], sigs)
    if settings.pair and len(rows) >= 2:
        a, b = pair_members(rows, settings.min_score)
        start = ctx.start((a, b), {**fits[a].params, **fits[b].params})
        fits[f"{a}+{b}"] = refit(ctx, (a, b), fit_ids, start, settings.fit, rng,
                                 desc=f"diagnosis: {a}+{b} ({steps}/{steps})")
        test = held_out_test(ctx, base, fits[f"{a}+{b}"], holdout)
        pair_row = score_row(ctx, base, fits[f"{a}+{b}"], test, n_eff_fit, n_eff_ho,
                             settings.min_score)
        rows = _rank(rows + [pair_row], sigs)
        log(f"pair {a}+{b}: held-out loss {test.loss_kN2:.4g} kN^2, z {test.z:.2f}")
    evidence = {"n_eff_fit": n_eff_fit, "n_eff_holdout": n_eff_ho,
                "signatures": {k: asdict(v) for k, v in sigs.items()}}
    return base, fits, rows, evidence


def pair_members(rows: list[dict[str, Any]], min_score: float) -> tuple[str, str]:
    """The two effects ``--pair`` re-calibrates together: the one the decision names
    (:func:`choose`, so a near-tie broken by the evidence is kept in the pair) and the
    best-scoring other; the two best-scoring when none is named.  ``rows``: ranked single
    effects, at least two."""
    if len(rows) < 2:
        raise ValueError(f"a pair needs two candidate effects, got {len(rows)}")
    named = choose(rows, min_score) or rows[0]
    other = next(r for r in rows if r is not named)
    return named["effect"], other["effect"]


def common_n_eff(ctx: DiagnosisContext, base: Fit, fits: dict[str, Fit], tests: dict[str, HeldOutTest],
                 fit_ids: list[str], holdout: list[str]) -> tuple[float, float]:
    """N_eff on the fitting and held-out sets, each from the best model there (see which)."""
    def finite(x: float) -> float:
        return x if np.isfinite(x) else np.inf

    best_fit = min([base, *fits.values()], key=lambda f: finite(f.loss))
    base_ho = next(iter(tests.values())).loss_base_kN2
    name = min(tests, key=lambda n: finite(tests[n].loss_kN2))
    best_ho = fits[name] if finite(tests[name].loss_kN2) < finite(base_ho) else base
    return n_eff_of(ctx, best_fit, fit_ids), n_eff_of(ctx, best_ho, holdout, held_out=True)


def decide(rows: list[dict[str, Any]], min_score: float) -> dict[str, Any]:
    """The decision: the top-ranked single effect if significant, else none; a near-tie on
    the held-out trials is broken by the evidence on all trials (:func:`choose`)."""
    singles = [r for r in rows if "+" not in r["effect"]]
    top = singles[0] if singles else None
    named = choose(singles, min_score)
    if top is None or named is None:
        why = ("no candidate" if top is None else
               f"the best candidate, {top['effect']}, improves the held-out loss by "
               f"{top['holdout_shrink_pct']:.1f} %, penalised score {top['score']:.3g} "
               f"< {min_score:g}")
        return {"best": None, "statement": f"no effect explains the gap beyond noise: {why}"}
    tie = ("" if named is top else
           f"; its held-out score is within {min_score:g} of {top['effect']}'s ({top['score']:.3g}), "
           f"and on all trials its evidence is larger ({named['evidence']:.3g} against "
           f"{top['evidence']:.3g}: it fits the fitting trials better)")
    return {"best": named["effect"],
            "statement": (f"{named['effect']} explains the gap: held-out loss "
                          f"{named['holdout_loss_base_kN2']:.4g} -> "
                          f"{named['holdout_loss_kN2']:.4g} kN^2 "
                          f"({named['holdout_shrink_pct']:.1f} % shrink, z = {named['dm_z']:.1f}, "
                          f"penalised score {named['score']:.3g}){tie}")}


INERT_SHRINK_PCT = 1.0
"""Held-out change (%, either way) below which an effect whose parameters do not move the
curves is left out of the forward selection."""
INERT_ABSORBABLE = 0.01
"""Absorbable share (:class:`~smcbayes.diagnose.which.Signature`, either sign) below which
an effect's parameters do not move the curves."""


def inert(row: dict[str, Any]) -> bool:
    """Whether a single-effect ranking row shows an effect whose parameters do not move the
    curves: its absorbable share and the change of the held-out loss its re-calibration made
    are both about zero (below :data:`INERT_ABSORBABLE` and :data:`INERT_SHRINK_PCT` in
    size).  Such an effect is not tried again in combination (each trial costs a full
    re-calibration).  An effect that moves the curves but, alone, the wrong way (a negative
    share: the linearised step overshoots; a held-out loss that grows) is tried: the frame's
    compliance delays the rise of a rigid charge that is already too late, but shapes the
    end of the closing once the charge is compressible."""
    share, shrink = row.get("absorbable_share"), row.get("holdout_shrink_pct")
    return (share is not None and shrink is not None and np.isfinite(shrink)
            and abs(share) < INERT_ABSORBABLE and abs(shrink) < INERT_SHRINK_PCT)


def _select(ctx: DiagnosisContext, settings: DiagnoseSettings, decision: dict[str, Any],
            rows: list[dict[str, Any]], fits: dict[str, Fit], ids: tuple[list[str], list[str]],
            evidence: dict[str, Any], rng: np.random.Generator,
            log: Callable[[str], None]
            ) -> tuple[list[str], list[dict[str, Any]], dict[str, Fit], list[str]]:
    """The effect set: empty without a significant single effect, else grown from it by
    :func:`~smcbayes.diagnose.select.forward_selection` up to ``settings.max_effects``;
    also the effects left out of the selection as :func:`inert`."""
    best = decision["best"]
    if best is None:
        return [], [], {}, []
    singles = [r for r in rows if "+" not in r["effect"] and r["effect"] != best]
    others = [r["effect"] for r in singles if not inert(r)]
    left_out = [r["effect"] for r in singles if inert(r)]
    if left_out:
        log(f"selection: {', '.join(left_out)} not tried (alone, their parameters could not move the "
            f"curves along the gap and the held-out loss changed by less than {INERT_SHRINK_PCT:g} %)")
    selected, steps, grown = forward_selection(
        ctx, fits[best], others, ids[0], ids[1], settings.fit, rng,
        (evidence["n_eff_fit"], evidence["n_eff_holdout"]), settings.min_score, settings.max_effects, log)
    if len(selected) > 1:
        log(f"selected effect set: {' + '.join(selected)}")
    return selected, steps, grown, left_out


def diagnose(ctx: DiagnosisContext, settings: DiagnoseSettings, out: Path | None,
             log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run the diagnosis; write ``out`` (if given) and return the summary dictionary.

    ``log`` receives a line per step (where, each re-calibration, the decision); by default
    they go to this module's logger at INFO level.
    """
    log = log or logger.info
    if out is not None and ctx.run is not None:
        ctx.keep_runs_in(out)
    rng = np.random.default_rng(settings.seed)
    holdout = check_holdout(ctx, settings.holdout or default_holdout(ctx))
    fit_ids = [c for c in ctx.ids if c not in holdout]
    t0 = time.perf_counter()
    base0 = Fit((), ctx.base_params, ctx.start(()), float("nan"), 0)
    where = analyse(ctx, (), base0.theta, ctx.ids)
    log(f"where: {where.verdict}")
    base, fits, rows, evidence = which_effect(ctx, settings, fit_ids, holdout, rng, log)
    decision = decide(rows, settings.min_score)
    log(decision["statement"])
    selected, steps, grown, left_out = _select(ctx, settings, decision, rows, fits, (fit_ids, holdout),
                                               evidence, rng, log)
    shown = {"base": base}
    pick = decision["best"] or (rows[0]["effect"] if rows else None)
    if pick is not None:
        shown[pick] = fits[pick]
    if len(selected) > 1:
        shown["+".join(selected)] = grown["+".join(selected)]
    pair = next((r["effect"] for r in rows if "+" in r["effect"]), None)
    if pair is not None:  # the same set as the selection's is shown as the selection fitted it
        shown.setdefault(pair, fits[pair])
    shrink = shrink_summary(ctx, shown, fit_ids, holdout)
    summary = {"holdout": holdout, "fit_configurations": fit_ids, "seed": settings.seed,
               "candidates": list(settings.candidates), "fit_settings": asdict(settings.fit),
               "min_score": settings.min_score, "where": where.to_json(), "ranking": rows,
               "decision": decision, "selected_effects": selected,
               "selection": {"max_effects": settings.max_effects, "steps": steps, "left_out": left_out},
               "shrink": shrink, **evidence,
               "base_calibrated_params": ctx.base_params, "truth": ctx.truth,
               "simulator_runs": ctx.forward_runs, "forward_runs_reused": ctx.forward_runs_reused,
               "forward_runs_made": ctx.forward_runs - ctx.forward_runs_reused,
               "seconds": time.perf_counter() - t0}
    if out is not None:
        write_outputs(ctx, summary, where, shown, out, settings.figures)
    return summary


def write_outputs(ctx: DiagnosisContext, summary: dict[str, Any], where: WhereReport, shown: dict[str, Fit],
                  out: Path, with_figures: bool = True) -> None:
    """summary.json, ranking.csv and (unless ``with_figures`` is off) the figures."""
    out.mkdir(parents=True, exist_ok=True)
    text = json.dumps(summary, indent=2, default=float) + "\n"
    (out / "summary.json").write_text(text, encoding="utf-8")
    with (out / "ranking.csv").open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=RANKING_COLUMNS, extrasaction="ignore")
        w.writeheader()
        w.writerows(summary["ranking"])
    if not with_figures:
        return
    fig_dir = out / "figures"
    heat_map(where, fig_dir / "heatmap")
    phase_bars(summary["shrink"], fig_dir / "phase_rmse")
    before_after(ctx, shown, ctx.ids, summary["holdout"], fig_dir / "before_after")
