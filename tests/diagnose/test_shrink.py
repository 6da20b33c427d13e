"""How far the gap shrinks: per-configuration tables and shrink percentages against the
loss and the residuals computed here from the same simulations."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from smcbayes.data.loss import force_pair
from smcbayes.diagnose.fit import DiagnosisContext, Fit
from smcbayes.diagnose.shrink import model_table, shrink_summary
from smcbayes.forward.result import PHASE_NAMES

FIT_IDS, HOLD_IDS = ["60-bar-03", "60-bar-11"], ["60-bar-07"]


def fit_at(ctx: DiagnosisContext, **change: float) -> Fit:
    """Base-model fit at the context's base parameters with ``change`` applied."""
    theta = ctx.start((), {**ctx.base_params, **change})
    params = dict(zip(ctx.model().space.free_names, theta[0], strict=True))
    return Fit((), params, theta, float("nan"), 0)


def test_model_table_is_the_force_mse_and_its_phase_split(
        synthetic_ctx: Callable[[str | None], DiagnosisContext]) -> None:
    """MSE = e^F of the loss; phase RMSE = RMS residual over the grid points of each phase."""
    ctx = synthetic_ctx(None)
    fit = fit_at(ctx, n=0.3)
    ids = FIT_IDS + HOLD_IDS
    table = model_table(ctx, fit, ids)
    assert list(table) == ids
    expected = ctx.losses((), fit.theta, ids)[0]
    results = ctx.simulate((), fit.theta, ids)
    for k, cid in enumerate(ids):
        row = table[cid]
        assert row["mse_kN2"] == pytest.approx(expected[k], rel=1e-9)
        assert row["rmse_kN"] == pytest.approx(np.sqrt(expected[k]), rel=1e-9)
        pair = force_pair(results[cid], ctx.dataset[cid], ctx.project.loss)
        resid = (pair.sim_kN - pair.meas_kN)[0]
        assert set(row["phase_rmse_kN"]) == set(PHASE_NAMES)
        for code, phase in enumerate(PHASE_NAMES):
            mask = pair.phase[0] == code
            got = row["phase_rmse_kN"][phase]
            if mask.any():
                assert got == pytest.approx(np.sqrt(np.mean(resid[mask] ** 2)), rel=1e-9)
            else:
                assert got is None


def test_shrink_summary_percentages(synthetic_ctx: Callable[[str | None], DiagnosisContext]) -> None:
    """Set loss = mean per-configuration MSE; shrink = 100 (1 - after / before) against the
    first model, per set and per configuration; an identical model shrinks nothing."""
    ctx = synthetic_ctx(None)
    worse = fit_at(ctx, n=0.3)       # the reference, away from the truth
    better = fit_at(ctx)             # at the truth of the synthetic data
    out = shrink_summary(ctx, {"base": worse, "effect": better, "same": worse}, FIT_IDS, HOLD_IDS)
    assert out["reference"] == "base" and out["sets"] == {"fit": FIT_IDS, "holdout": HOLD_IDS}
    models = out["models"]
    assert "shrink_pct" not in models["base"]["fit"]
    assert models["effect"]["params"] == better.params and models["effect"]["effects"] == []
    for name, ids in (("fit", FIT_IDS), ("holdout", HOLD_IDS)):
        before = ctx.losses((), worse.theta, ids)[0]
        after = ctx.losses((), better.theta, ids)[0]
        assert models["base"][name]["loss_kN2"] == pytest.approx(np.mean(before), rel=1e-9)
        assert models["effect"][name]["loss_kN2"] == pytest.approx(np.mean(after), rel=1e-9)
        assert models["effect"][name]["shrink_pct"] == pytest.approx(
            100 * (1 - np.mean(after) / np.mean(before)), rel=1e-9)
        assert models["effect"][name]["shrink_pct"] > 50.0  # the truth fits far better
        for k, cid in enumerate(ids):
            row = models["effect"][name]["per_config"][cid]
            assert row["shrink_pct"] == pytest.approx(100 * (1 - after[k] / before[k]), rel=1e-9)
        assert models["same"][name]["shrink_pct"] == pytest.approx(0.0, abs=1e-12)
