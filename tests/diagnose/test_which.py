"""Which effect: the ranking follows the withheld effect; no effect on clean data."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from smcbayes.diagnose.fit import refit
from smcbayes.diagnose.run import DiagnoseSettings, check_holdout, default_holdout, diagnose
from smcbayes.diagnose.which import signature
from smcbayes.errors import ConfigError

from .conftest import TINY

CANDIDATES = ("compressibility", "heating", "press_compliance")


def run(ctx, seed: int = 0) -> dict:
    settings = DiagnoseSettings(candidates=CANDIDATES, seed=seed, fit=TINY, figures=False)
    return diagnose(ctx, settings, None, log=lambda _: None)


@pytest.mark.parametrize("effect", ["compressibility", "press_compliance"])
def test_withheld_effect_is_named(synthetic_ctx, effect: str) -> None:
    """Swapping the effect in the data swaps the answer (computed, not templated)."""
    summary = run(synthetic_ctx(effect))
    assert summary["decision"]["best"] == effect
    top = summary["ranking"][0]
    assert top["effect"] == effect and top["significant"]
    assert top["holdout_shrink_pct"] > 50.0
    assert effect in summary["decision"]["statement"]
    assert summary["holdout"] == ["60-bar-07"]
    # every row's evidence on all trials is its held-out score plus the fitting trials'
    # log-likelihood ratio (the penalty counted once)
    for r in summary["ranking"]:
        fit = 0.5 * r["n_eff_fit"] * np.log(r["fit_loss_base_kN2"] / r["fit_loss_kN2"])
        assert r["evidence"] == pytest.approx(r["score"] + fit, rel=1e-9, abs=1e-9)


def test_withheld_effect_is_named_with_contact_offsets_profiled(synthetic_ctx) -> None:
    """The thesis project profiles each trial's contact offset: the compliance, whose
    signature is partly a delay, is still named over the offsets."""
    ctx = synthetic_ctx("press_compliance")
    loss = ctx.project.loss.model_copy(update={"contact_offset_mm": 0.3})
    # fresh model and runner caches: the shared context's runners hold the nominal loss
    profiled = replace(ctx, project=ctx.project.model_copy(update={"loss": loss}), _models={}, _runners={})
    prof, nominal = (c.losses((), c.start(()), c.ids)[0] for c in (profiled, ctx))
    # the offset grid holds 0, so the profile is never worse and here better somewhere
    assert np.all(prof <= nominal + 1e-9) and np.any(prof < nominal)
    summary = run(profiled)
    assert summary["decision"]["best"] == "press_compliance"
    assert summary["ranking"][0]["holdout_shrink_pct"] > 50.0


def test_no_effect_data_are_not_attributed(synthetic_ctx) -> None:
    summary = run(synthetic_ctx(None))
    assert summary["decision"]["best"] is None
    assert summary["decision"]["statement"].startswith("no effect explains the gap beyond noise")
    assert not any(r["significant"] for r in summary["ranking"])


def test_same_seed_same_ranking(synthetic_ctx) -> None:
    ctx = synthetic_ctx("press_compliance")
    settings = DiagnoseSettings(candidates=("press_compliance", "heating"), seed=3, fit=TINY,
                                figures=False)
    a = diagnose(ctx, settings, None, log=lambda _: None)
    b = diagnose(ctx, settings, None, log=lambda _: None)
    assert [r["effect"] for r in a["ranking"]] == [r["effect"] for r in b["ranking"]]
    assert [r["score"] for r in a["ranking"]] == [r["score"] for r in b["ranking"]]


def test_signature_separates_a_present_effect_from_an_absent_one(synthetic_ctx) -> None:
    ctx = synthetic_ctx("compressibility")
    rng = np.random.default_rng(0)
    base = refit(ctx, (), ctx.ids, ctx.start(()), TINY, rng)
    present = signature(ctx, "compressibility", base, ctx.ids, rng)
    absent = signature(ctx, "curing", base, ctx.ids, rng)
    assert present.absorbable_share > 0.5 > absent.absorbable_share
    assert present.sensitivity_kN > 0 and present.most_sensitive


def test_holdout_default_and_validation(synthetic_ctx) -> None:
    ctx = synthetic_ctx(None)
    assert default_holdout(ctx) == ["60-bar-07"]
    with pytest.raises(ConfigError, match="did you mean '60-bar-07'"):
        check_holdout(ctx, ["60-bar-7"])
    with pytest.raises(ConfigError, match="keep at least one"):
        check_holdout(ctx, list(ctx.ids))


def test_pair_is_fitted_and_reported(synthetic_ctx) -> None:
    ctx = synthetic_ctx("press_compliance")
    settings = DiagnoseSettings(candidates=("press_compliance", "heating"), pair=True, fit=TINY,
                                figures=False)
    summary = diagnose(ctx, settings, None, log=lambda _: None)
    pair = "press_compliance+heating"
    row = next(r for r in summary["ranking"] if r["effect"] == pair)
    assert row["extra_parameters"] == 1 + 3
    assert set(row["params"]) >= {"k_press_kN_mm", "T_start_C"}
    assert pair in summary["shrink"]["models"]
    # the decision names single effects only
    assert summary["decision"]["best"] == "press_compliance"
