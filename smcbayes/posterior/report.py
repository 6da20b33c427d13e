"""Outputs of the posterior stage: InferenceData, tables, emulator check, bands, figures."""

from __future__ import annotations

import csv
import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from smcbayes.posterior.context import RunContext, true_log_loss
from smcbayes.posterior.correct import K_HAT_WARN
from smcbayes.posterior.crossfit import LocalFit
from smcbayes.posterior.error_models import BandErrorModels, band_error_models
from smcbayes.posterior.extrapolation import extrapolation_notes
from smcbayes.posterior.likelihood import EmulatedPosterior
from smcbayes.posterior.plots import bands_plot, corner_plot, correlation_plot, learning_plot
from smcbayes.posterior.predictive import QUANTILES, Band, predictive_bands
from smcbayes.posterior.refine import check_emulator
from smcbayes.posterior.shape import shape_notes
from smcbayes.posterior.summary import (
    correlations,
    stack_components,
    summarise,
    summarise_weighted,
    to_inference_data,
    warnings_for,
)

logger = logging.getLogger(__name__)


def band_width90(band: Band) -> float:
    """Mean width (kN) of the 90 % predictive band over the measured closing (the whole
    band grid without a measurement): its sharpness, to be read beside its coverage."""
    end = band.measured[0][-1] if band.measured is not None else band.time_s[-1]
    inside = band.time_s <= end
    return float(np.mean(band.force_pred_kN[4][inside] - band.force_pred_kN[0][inside]))


def band_record(band: Band, role: str) -> dict[str, Any]:
    """The ``bands`` entry of one configuration in the summary: coverage beside sharpness."""
    return {"coverage50": band.coverage50, "coverage90": band.coverage90, "noise_kN": band.noise_kN,
            "width90_kN": band_width90(band), "rmse_median_kN": band.rmse_median_kN,
            "rmse_mean_kN": band.rmse_mean_kN, "crps_kN": band.crps_kN,
            "interval_score90_kN": band.interval_score90_kN,
            "error_model": band.error_model, "draws": band.draws, "role": role}


def extrapolation_warning(cid: str, why: Sequence[str], source: str) -> str:
    """The warning of a band configuration outside the training set, with its error model's residuals."""
    if source.startswith("leave-group-out"):
        return (f"{cid}: {'; '.join(why)}: its band extrapolates from the training trials; its error "
                f"model is learnt from {source.split(': ', 1)[-1]}, and it may still under-cover")
    return f"{cid}: {'; '.join(why)}: its band extrapolates from the training trials and may under-cover"


def write_table(path: Path, rows: list) -> None:
    """The posterior summary as CSV; a NaN (the R-hat of an importance-weighted sample) is
    an empty cell."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["parameter", "unit", "mean", "sd", "q05", "q50", "q95", "r_hat", "ess"])
        for s in rows:
            values = (s.mean, s.sd, s.q05, s.q50, s.q95, s.r_hat, s.ess)
            w.writerow([s.name, s.unit] + ["" if v != v else f"{v:.6g}" for v in values])


def write_band_curves(bands: Mapping[str, Band], folder: Path) -> None:
    """One CSV per configuration, ``folder/<id>.csv``, on the band's time grid (s): the
    model's and the predictive force quantiles (5/25/50/75/95 %) and the predictive mean
    (the point prediction), in kN; a configuration whose draws all failed has empty cells."""
    folder.mkdir(parents=True, exist_ok=True)
    pct = [f"q{round(100 * q):02d}" for q in QUANTILES]
    header = (["time_s"] + [f"force_{p}_kN" for p in pct] + [f"force_pred_{p}_kN" for p in pct]
              + ["force_pred_mean_kN"])
    for cid, b in bands.items():
        mean = b.force_pred_mean_kN if b.force_pred_mean_kN is not None else np.full(b.time_s.size, np.nan)
        cols = np.vstack([b.time_s[None, :], b.force_kN, b.force_pred_kN, mean[None, :]])
        with (folder / f"{cid}.csv").open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            w.writerows([["" if v != v else f"{v:.6g}" for v in row] for row in cols.T])


def correction_info(corrected: Any, settings: Any) -> dict[str, Any]:
    """The ``correction`` block of the summary."""
    if corrected is None:
        return {"enabled": False, "draws": 0, "evaluations": 0}
    emulated = corrected.target == "emulator"  # sampled on the emulator: no forward run
    draws = int(sum(h["draws"] for h in corrected.history)) if emulated else settings.correct_draws
    return {"enabled": True, "draws": draws, "evaluations": 0 if emulated else corrected.evaluations,
            "k_hat": corrected.k_hat, "ess": corrected.ess, "reliable": bool(corrected.k_hat <= K_HAT_WARN),
            "settled": corrected.settled, "ess_target": corrected.ess_target, "ess_aim": corrected.ess_aim,
            "draws_needed": corrected.draws_needed, "points": int(corrected.unit.shape[0]),
            "target": corrected.target, "history": corrected.history}


def _tables(ctx: RunContext, chains: list, corrected: Any, rng: np.random.Generator) -> dict[str, Any]:
    """Raw (emulator) and reported (corrected if available) summaries, correlations, draws."""
    space = ctx.space
    raw = summarise(space, chains)
    unit, _ = stack_components(chains)
    flat = unit.reshape(-1, unit.shape[-1])
    out = {"raw": raw, "raw_corr": correlations(space, space.from_unit(flat))}
    if corrected is None:
        out.update(table=raw, corr=out["raw_corr"], unit=flat, resampled=None)
        return out
    # no R-hat: the chains only seeded the proposal, their own R-hat stays in ``raw``
    table = summarise_weighted(space, corrected.unit, corrected.weights, corrected.ess)
    keep = corrected.weights > 0
    corr = correlations(space, space.from_unit(corrected.unit[keep]), weights=corrected.weights[keep])
    resampled = corrected.resample(max(4000, corrected.unit.shape[0]), rng)
    out.update(table=table, corr=corr, unit=resampled, resampled=resampled)
    return out


def _corr_block(corr: tuple) -> dict[str, Any]:
    matrix, labels, pairs = corr
    return {"labels": labels, "matrix": matrix.tolist(),
            "strongest": [{"a": a, "b": b, "r": r} for a, b, r in pairs]}


def _bands_and_figures(ctx: RunContext, t: dict[str, Any], budget: dict[str, Any], settings: Any,
                       rng: np.random.Generator, out_dir: Path,
                       fit: LocalFit | None = None) -> tuple[dict, int, list[str], BandErrorModels]:
    """Predictive bands from the reported draws, corner, correlation and band figures.

    The bands' error term is the discrepancy model learnt from out-of-sample training
    residuals (:mod:`smcbayes.posterior.error_models`: leave-one-out refits, or leave-group-out
    ones for a configuration outside the training set), or the
    per-configuration white noise when no residual is usable.

    Returns the bands, the forward runs they took, the validation ids and the error models.
    """
    space, p, unit = ctx.space, ctx.problem, t["unit"]
    draw_unit = unit[rng.choice(unit.shape[0], size=min(settings.draws, unit.shape[0]), replace=False)]
    val_ids = p.model.ids("validation")
    band_ids = val_ids or p.train_ids
    measured = p.measured_force(band_ids)
    noise = {cid: float(np.sqrt(v)) for cid, v in budget["mse_kN2"].items()}
    errors = band_error_models(ctx, fit, band_ids)
    limits = {cid: float(p.project.get(cid).press.force_limit_kN) for cid in band_ids}
    offsets = np.asarray(list(errors.offsets_mm.values()), dtype=float)
    delays = ({cid: offsets / p.project.get(cid).press.speed_mm_s for cid in band_ids} if offsets.size
              else None)
    bands = predictive_bands(ctx.runner, space.from_unit(draw_unit), band_ids, measured, noise, rng,
                             discrepancy=errors.models, force_limit_kN=limits, delays_s=delays)
    fig = out_dir / "figures"
    corner_unit = unit[rng.choice(unit.shape[0], min(20000, unit.shape[0]), replace=False)]
    corner_plot(space, space.from_unit(corner_unit), fig / "corner", p.truth)
    if space.dim > 1:
        correlation_plot(t["corr"][0], t["corr"][1], fig / "correlations")
    kind = "validation" if val_ids else "training (no validation configuration)"
    bands_plot(bands, fig / "bands", f"posterior predictive bands on {kind} configurations")
    write_band_curves(bands, out_dir / "bands")
    runs = int(draw_unit.shape[0]) * len(band_ids) + errors.runs
    return bands, runs, val_ids, errors


def _chain_warnings(raw: list, chains: list, corrected: Any) -> tuple[list[str], list[str]]:
    """The emcee chains' convergence warnings and the notes on them that are not warnings.

    The chains are the reported posterior only without importance weights (``corrected``
    None): then their warnings are raised.  Otherwise they only shaped the proposal: their
    words are named as the proposal's and not raised, kept as warnings while the importance
    sample has not settled, and as notes once it has (the reported numbers are the
    weights', whose ESS and k-hat judge them)."""
    warns = warnings_for(raw, chains, warn=corrected is None)
    if corrected is None:
        return warns, []
    of = "the importance sampling on the emulator" if corrected.target == "emulator" else "the correction"
    named = [f"emulator chains (proposal of {of}): {w}" for w in warns]
    return ([], named) if corrected.settled else (named, [])


def learning_figures(active: Mapping[str, Any], out_dir: Path) -> list[Path]:
    """The curve emulator's rounds (``refine.jsonl``) drawn as ``figures/learning``
    (:func:`~smcbayes.posterior.plots.learning_figure`); none for the log-loss emulator or
    a learning without rounds, whose figure of an earlier run is removed."""
    stem = out_dir / "figures" / "learning"
    if active.get("kind") != "curves" or not active.get("rounds"):
        for old in (stem.with_suffix(".png"), stem.with_suffix(".svg")):
            old.unlink(missing_ok=True)
        return []
    with (out_dir / "refine.jsonl").open(encoding="utf-8") as fh:
        rounds = [json.loads(line) for line in fh]
    return learning_plot(rounds, active, stem)


def write_outputs(ctx: RunContext, emul: EmulatedPosterior, chains: list, budget: dict[str, Any],
                  settings: Any, rng: np.random.Generator, out_dir: Path,
                  corrected: Any = None, fit: LocalFit | None = None) -> dict[str, Any]:
    """Write NetCDF, tables and figures; returns the summary dictionary.

    With ``corrected`` (an importance-corrected sample) the reported posterior (table,
    correlations, NetCDF ``posterior`` group, corner plot, predictive bands) is the
    corrected one and the emulator's is kept alongside (``emulator_parameters``,
    ``emulator_correlation``, ``summary_emulator.csv``, NetCDF ``emulator_posterior``); the
    corrected table's R-hat is NaN (``null`` in JSON), the chains' is in the emulator's table.
    """
    space = ctx.space
    t = _tables(ctx, chains, corrected, rng)
    warns, proposal_notes = _chain_warnings(t["raw"], chains, corrected)
    emulated = corrected is not None and corrected.target == "emulator"
    warns += [] if corrected is None else list(corrected.warnings)
    warns += [w for w in [ctx.stale_calibration_runs] if w is not None]
    attrs = {"n_eff": budget["n_eff_total"], "functions": emul.functions,
             "pooled_functions": len(chains) - emul.components,
             "method": "emulator" if corrected is None else "emulator, importance sampled" if
             corrected.target == "emulator" else "emulator + importance correction"}
    if corrected is not None:
        attrs.update(k_hat=corrected.k_hat, importance_ess=corrected.ess,
                     correction_evaluations=0 if emulated else corrected.evaluations)
    to_inference_data(space, chains, attrs,
                      corrected, t["resampled"]).to_netcdf(str(out_dir / "posterior.nc"))
    write_table(out_dir / "summary.csv", t["table"])
    if corrected is not None:
        write_table(out_dir / "summary_emulator.csv", t["raw"])
    # the check judges the emulator that was sampled (the GP mean, or the requested mixture),
    # not the pooled sample functions, whose disagreement the spread measures
    # (an emulated posterior sampled by importance: at its own equal-weight resample, which
    # holds mass the chains under-sample)
    emu = t["resampled"] if emulated else stack_components(chains[:emul.components])[0].reshape(-1, space.dim)
    check_unit = emu[rng.choice(emu.shape[0], size=min(settings.draws, emu.shape[0]), replace=False)]
    check = check_emulator(check_unit, lambda u: emul.log_loss(u),
                           lambda u: true_log_loss(ctx, space.from_unit(u)), emul.n_eff)
    bands, band_runs, val_ids, errors = _bands_and_figures(ctx, t, budget, settings, rng, out_dir, fit)
    corr_info = correction_info(corrected, settings)
    notes = extrapolation_notes(ctx.problem.project, ctx.problem.train_ids, list(bands))
    warns += [extrapolation_warning(cid, why, errors.sources.get(cid, ""))
              for cid, why in notes.items() if why]
    return {
        "method": attrs["method"],
        "parameters": [asdict(s) for s in t["table"]], "warnings": warns, "proposal_notes": proposal_notes,
        "correlation": _corr_block(t["corr"]),
        "emulator_parameters": [asdict(s) for s in t["raw"]],
        "emulator_correlation": _corr_block(t["raw_corr"]),
        "correction": corr_info,
        "forward_evaluations": {"correction": corr_info["evaluations"], "emulator_check": check.points,
                                "bands": band_runs},
        "effective_points": budget, "emulator_check": check.as_dict(),
        "sampler": [{"steps": c.steps, "burn": c.burn, "thin": c.thin, "converged": c.converged,
                     "tau_max": float(np.max(c.tau)), "acceptance_median": float(np.median(c.acceptance))}
                    for c in chains],
        "bands": {cid: {**band_record(b, "validation" if val_ids else "train"), "extrapolates": notes[cid],
                        "error_residuals": errors.sources.get(cid)} for cid, b in bands.items()},
        "discrepancy": errors.summary(),
        "truth": ctx.problem.truth,
        "shape": shape_notes(space, t["unit"]),
    }
