"""How far the gap shrinks: base vs base + effect(s) on fitting and held-out configurations.

Per model and configuration: the force MSE (kN^2), its RMSE (kN) overall and per phase
(contact, flow, mould full, force control; the phases of each model's own simulation);
per set (fitting, held-out): the loss and the percentage shrink ``100 (1 - L_after/L_before)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from smcbayes.data.breakdown import force_breakdown
from smcbayes.diagnose.fit import DiagnosisContext, Fit
from smcbayes.forward.result import PHASE_NAMES


def model_table(ctx: DiagnosisContext, fit: Fit, ids: Sequence[str]) -> dict[str, dict]:
    """Per configuration: MSE, RMSE and per-phase RMSE of ``fit`` (kN^2, kN)."""
    results = ctx.simulate(fit.effects, fit.theta, ids)
    bd = force_breakdown(results, ctx.dataset, ctx.project.loss, ids)
    out = {}
    for k, cid in enumerate(ids):
        mse = float(bd.shift_kN2[0, k] + bd.amplitude_kN2[0, k] + bd.shape_kN2[0, k])
        pm = bd.phase_mse_kN2[0, k]
        phases = {p: (float(np.sqrt(pm[i])) if np.isfinite(pm[i]) else None)
                  for i, p in enumerate(PHASE_NAMES)}
        out[cid] = {"mse_kN2": mse, "rmse_kN": float(np.sqrt(mse)) if np.isfinite(mse) else None,
                    "phase_rmse_kN": phases}
    return out


def shrink_summary(ctx: DiagnosisContext, fits: dict[str, Fit], fit_ids: Sequence[str],
                   holdout_ids: Sequence[str]) -> dict:
    """Tables of every model in ``fits`` (label -> fit; the first is the reference ``base``)."""
    labels = list(fits)
    sets = {"fit": list(fit_ids), "holdout": list(holdout_ids)}
    models: dict[str, dict] = {}
    for label, fit in fits.items():
        entry: dict = {"effects": list(fit.effects), "params": fit.params}
        for name, ids in sets.items():
            table = model_table(ctx, fit, ids)
            mses = [v["mse_kN2"] for v in table.values()]
            entry[name] = {"loss_kN2": float(np.mean(mses)), "per_config": table}
        models[label] = entry
    ref = models[labels[0]]
    for label in labels[1:]:
        for name in sets:
            before, after = ref[name]["loss_kN2"], models[label][name]["loss_kN2"]
            shrink = 100.0 * (1.0 - after / before) if before > 0 else 0.0
            models[label][name]["shrink_pct"] = shrink
            for cid, row in models[label][name]["per_config"].items():
                b = ref[name]["per_config"][cid]["mse_kN2"]
                row["shrink_pct"] = 100.0 * (1.0 - row["mse_kN2"] / b) if b > 0 else 0.0
    return {"reference": labels[0], "sets": sets, "models": models}
