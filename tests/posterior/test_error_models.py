"""Each band configuration takes the error model of its gap to the training set.

Synthetic residual curves: the leave-one-out residuals are small, those of the training
trials left out as a group (the fastest ones, predicted from the slower) are large, so a
configuration beyond the fitted speeds gets the wider model, one inside the training set
keeps the leave-one-out model, and a group with too few usable curves falls back to it.
"""

from __future__ import annotations

import numpy as np

from smcbayes.posterior.discrepancy import ResidualCurve, fit_discrepancy
from smcbayes.posterior.error_models import LOO, assemble

T_END, TRAVEL = 10.0, 5.0  # s, mm


def residuals(rng: np.random.Generator, ids: list[str], sd_kN: float) -> list[ResidualCurve]:
    t = np.linspace(0.0, T_END, 300)
    return [ResidualCurve(cid, t, sd_kN * rng.standard_normal(t.size), T_END, TRAVEL) for cid in ids]


def test_a_configuration_beyond_the_training_set_takes_its_group_model() -> None:
    rng = np.random.default_rng(0)
    base = fit_discrepancy(residuals(rng, ["a", "b", "c", "d"], 10.0))
    fast, lone = (2, 3), (1,)
    curves = {fast: residuals(rng, ["c", "d"], 80.0), lone: residuals(rng, ["b"], 80.0)}
    plans = {"inside": ([], ""), "faster": ([fast], "the 0.7 mm/s trials predicted from the slower ones"),
             "thin": ([lone], "each training charge predicted from the others")}
    models = assemble(base, plans, curves, runs=12)
    assert models.models["inside"] is base and models.sources["inside"] == LOO
    assert models.models["thin"] is base and models.sources["thin"] == LOO  # one usable curve only
    wide = models.models["faster"]
    assert wide is not None and wide is not base
    assert models.sources["faster"] == ("leave-group-out refits: the 0.7 mm/s trials predicted from the "
                                        "slower ones")
    d = np.linspace(0.5, 4.5, 9)
    assert np.all(wide.scale_kN(d) > 4 * base.scale_kN(d))
    summary = models.summary()
    assert summary is not None and summary["residuals"] == LOO and models.runs == 12
    assert [e["configurations"] for e in summary["extrapolation"]] == [["faster"]]

