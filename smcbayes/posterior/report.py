"""Outputs of the posterior stage: InferenceData, tables, emulator check, bands, figures."""

from __future__ import annotations

import csv
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from smcbayes.posterior.likelihood import EmulatedPosterior
from smcbayes.posterior.predictive import predictive_bands
from smcbayes.posterior.refine import check_emulator
from smcbayes.posterior.summary import (
    correlations,
    stack_components,
    summarise,
    to_inference_data,
    warnings_for,
)


def _draws(ctx: Any, chains: list, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    unit, _ = stack_components(chains)
    flat = unit.reshape(-1, unit.shape[-1])
    theta_all = ctx.space.from_unit(flat)
    pick = rng.choice(flat.shape[0], size=min(count, flat.shape[0]), replace=False)
    return theta_all, flat[pick]


def write_table(path: Path, rows: list) -> None:
    """The posterior summary as CSV."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["parameter", "unit", "mean", "sd", "q05", "q50", "q95", "r_hat", "ess"])
        for s in rows:
            w.writerow([s.name, s.unit] + [f"{v:.6g}" for v in (s.mean, s.sd, s.q05, s.q50, s.q95, s.r_hat, s.ess)])


def write_outputs(ctx: Any, emul: EmulatedPosterior, chains: list, budget: dict[str, Any],
                  settings: Any, rng: np.random.Generator, out_dir: Path) -> dict[str, Any]:
    """Write NetCDF, tables and figures; returns the summary dictionary."""
    from smcbayes.commands.common import measured_force
    from smcbayes.posterior.plots import bands_plot, corner_plot, correlation_plot
    from smcbayes.posterior.stage import true_log_loss

    space = ctx.space
    table = summarise(space, chains)
    warns = warnings_for(table, chains)
    theta_all, draw_unit = _draws(ctx, chains, settings.draws, rng)
    matrix, labels, pairs = correlations(space, theta_all)
    idata = to_inference_data(space, chains, {"n_eff": budget["n_eff_total"],
                                              "functions": emul.functions})
    idata.to_netcdf(str(out_dir / "posterior.nc"))
    write_table(out_dir / "summary.csv", table)
    check = check_emulator(draw_unit, lambda u: emul.log_loss(u),
                           lambda u: true_log_loss(ctx, space.from_unit(u)), emul.n_eff)
    p = ctx.problem
    val_ids = p.model.ids("validation")
    band_ids = val_ids or p.train_ids
    measured = measured_force(p.project, band_ids)
    noise = {cid: float(np.sqrt(v)) for cid, v in budget["mse_kN2"].items()}
    bands = predictive_bands(p.model, space.from_unit(draw_unit), band_ids, measured, noise, rng)
    fig = out_dir / "figures"
    corner_plot(space, theta_all[rng.choice(theta_all.shape[0], min(20000, theta_all.shape[0]), replace=False)],
                fig / "corner", p.truth)
    if space.dim > 1:
        correlation_plot(matrix, labels, fig / "correlations")
    kind = "validation" if val_ids else "training (no validation configuration)"
    bands_plot(bands, fig / "bands", f"posterior predictive bands on {kind} configurations")
    return {
        "parameters": [asdict(s) for s in table], "warnings": warns,
        "correlation": {"labels": labels, "matrix": matrix.tolist(),
                        "strongest": [{"a": a, "b": b, "r": r} for a, b, r in pairs]},
        "effective_points": budget, "emulator_check": check.as_dict(),
        "sampler": [{"steps": c.steps, "burn": c.burn, "thin": c.thin, "converged": c.converged,
                     "tau_max": float(np.max(c.tau)), "acceptance_median": float(np.median(c.acceptance))}
                    for c in chains],
        "bands": {cid: {"coverage50": b.coverage50, "coverage90": b.coverage90, "noise_kN": b.noise_kN,
                        "draws": b.draws, "role": "validation" if val_ids else "train"}
                  for cid, b in bands.items()},
        "truth": p.truth,
    }
