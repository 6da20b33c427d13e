"""Posterior summaries: sampled coordinates, component stacking, pooled and weighted
summaries, correlations, warnings and the InferenceData layout, against hand computations."""

from __future__ import annotations

import csv
import json
from dataclasses import asdict
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.posterior.report import _tables, write_table
from smcbayes.posterior.sampler import Chains
from smcbayes.posterior.summary import (
    ParameterSummary,
    correlations,
    sampled_coordinates,
    stack_components,
    summarise,
    summarise_weighted,
    to_inference_data,
    warnings_for,
)
from smcbayes.run.runlog import write_json

# n (linear, 0.2-0.6) and tau_c (log, 0.005-1 MPa) free
SPACE = ParameterSpace(BASE_PARAMETERS, {"tau_star_Pa": 1e4, "B_Pa_s": 1e4, "m": 1.5})


def chains(samples: np.ndarray, acceptance: float = 0.3, converged: bool = True) -> Chains:
    """Chains of one component from samples ``(draws, walkers, d)``."""
    draws, walkers, d = samples.shape
    logp = -np.sum((samples - 0.5) ** 2, axis=2)
    return Chains(samples, logp, np.full(walkers, acceptance), np.ones(d), draws, 0, 1, converged)


def iid(rng: np.random.Generator, draws: int, walkers: int, centre=(0.5, 0.5), sd=0.05) -> np.ndarray:
    return np.asarray(centre) + sd * rng.standard_normal((draws, walkers, 2))


def test_sampled_coordinates_take_log10_of_log_searched_parameters() -> None:
    theta = np.array([[0.3, 0.01], [0.5, 0.1]])
    x, labels = sampled_coordinates(SPACE, theta)
    np.testing.assert_allclose(x, [[0.3, -2.0], [0.5, -1.0]])
    assert labels == ["n", "log10 tau_c_MPa"]


def test_stack_components_truncates_to_the_shortest_and_keeps_the_last_draws() -> None:
    """(draws, walkers, d) of each component -> (all walkers, common draws, d)."""
    a = np.arange(5 * 2 * 2, dtype=float).reshape(5, 2, 2)
    b = 100.0 + np.arange(3 * 4 * 2, dtype=float).reshape(3, 4, 2)
    samples, logp = stack_components([chains(a), chains(b)])
    assert samples.shape == (6, 3, 2) and logp.shape == (6, 3)
    np.testing.assert_array_equal(samples[0], a[2:, 0])  # walker 0 of the first: its last 3 draws
    np.testing.assert_array_equal(samples[1], a[2:, 1])
    np.testing.assert_array_equal(samples[2], b[:, 0])
    np.testing.assert_array_equal(samples[5], b[:, 3])
    np.testing.assert_array_equal(logp[0], chains(a).log_prob[2:, 0])


def test_summarise_pools_components_in_user_units() -> None:
    """Mean, sd and quantiles are those of all draws pooled, mapped to user units."""
    rng = np.random.default_rng(0)
    comps = [chains(iid(rng, 400, 8, (0.3, 0.4))), chains(iid(rng, 400, 8, (0.6, 0.5)))]
    out = summarise(SPACE, comps)
    unit, _ = stack_components(comps)
    theta = SPACE.from_unit(unit.reshape(-1, 2))
    assert [s.name for s in out] == ["n", "tau_c_MPa"] and out[1].unit == "MPa"
    for j, s in enumerate(out):
        assert s.mean == pytest.approx(theta[:, j].mean())
        assert s.sd == pytest.approx(theta[:, j].std())
        q = np.quantile(theta[:, j], [0.05, 0.5, 0.95])
        assert (s.q05, s.q50, s.q95) == pytest.approx(tuple(q))
    # n is linear on 0.2-0.6: the pooled mean of the unit means 0.3 and 0.6 is 0.45 -> 0.38
    assert out[0].mean == pytest.approx(0.2 + 0.4 * 0.45, abs=0.005)
    # the components differ on purpose, yet each is converged: R-hat is within-component
    assert all(s.r_hat < 1.02 for s in out)


def test_summarise_reports_the_worst_component_r_hat() -> None:
    """One component whose walkers sit in two places gives a large R-hat; the other does not
    dilute it."""
    rng = np.random.default_rng(1)
    good = iid(rng, 300, 8)
    split = iid(rng, 300, 8, sd=0.01)
    split[:, :4, 0] += 0.3  # half the walkers elsewhere in n
    out = summarise(SPACE, [chains(good), chains(split)])
    assert out[0].r_hat > 1.3
    assert out[1].r_hat < 1.05  # tau_c is mixed in both
    single = summarise(SPACE, [chains(good)])
    assert single[0].r_hat < 1.05


def test_summarise_keeps_a_components_nan_r_hat_and_warns() -> None:
    """Walkers that never moved give arviz a NaN R-hat: it stays NaN in the pooled table,
    whichever component it comes from, and the warnings say the walkers disagree."""
    import warnings as warn_module

    rng = np.random.default_rng(2)
    stuck = iid(rng, 300, 8)
    stuck[:, :, 0] = 0.4  # n never moved
    for comps in ([chains(iid(rng, 300, 8)), chains(stuck)], [chains(stuck), chains(iid(rng, 300, 8))]):
        with warn_module.catch_warnings():
            warn_module.simplefilter("ignore")
            out = summarise(SPACE, comps)
        assert np.isnan(out[0].r_hat) and np.isfinite(out[1].r_hat)
        assert any(m.startswith("n: R-hat nan") for m in warnings_for(out, comps, warn=False))


def test_summarise_ess_grows_with_the_draws_of_every_component() -> None:
    """Independent draws: ESS about the number of draws of the components."""
    rng = np.random.default_rng(2)
    one = summarise(SPACE, [chains(iid(rng, 250, 8))])
    assert one[0].ess == pytest.approx(2000, rel=0.2)
    two = summarise(SPACE, [chains(iid(rng, 250, 8)), chains(iid(rng, 250, 8))])
    assert two[0].ess > one[0].ess


def test_summarise_ess_is_summed_over_components() -> None:
    """The pooled draws come from independent components: their ESS adds up."""
    rng = np.random.default_rng(3)
    long = chains(iid(rng, 500, 8))
    short = chains(iid(rng, 500, 8)[:, :2])  # 2 walkers: a quarter of the draws
    out = summarise(SPACE, [long, short])
    total = summarise(SPACE, [long])[0].ess + summarise(SPACE, [short])[0].ess
    assert out[0].ess == pytest.approx(total, rel=1e-9)


def test_summarise_weighted_hand_computed() -> None:
    """Weighted mean/sd and midpoint-rule quantiles on four points."""
    unit = np.array([[0.0, 0.5], [0.25, 0.5], [0.5, 0.5], [1.0, 0.5]])
    w = np.array([0.1, 0.2, 0.3, 0.4])
    out = summarise_weighted(SPACE, unit, w, 123.0)
    n = 0.2 + 0.4 * unit[:, 0]  # 0.2, 0.3, 0.4, 0.6
    mean = float(w @ n)
    assert out[0].mean == pytest.approx(mean)
    assert out[0].sd == pytest.approx(np.sqrt(w @ (n - mean) ** 2))
    # cdf at the sorted points: 0.05, 0.2, 0.45, 0.8 -> median between 0.4 and 0.6
    assert out[0].q50 == pytest.approx(0.4 + (0.5 - 0.45) / (0.8 - 0.45) * 0.2)
    assert out[0].q05 == pytest.approx(0.2)
    assert out[0].q95 == pytest.approx(0.6)
    # tau_c at unit 0.5 of log10 0.005..1: the geometric midpoint, no spread
    assert out[1].mean == pytest.approx(np.sqrt(0.005 * 1.0))
    assert out[1].sd == pytest.approx(0.0, abs=1e-12)
    # no chain made the weighted sample: no R-hat, the importance ESS for every parameter
    assert np.isnan(out[0].r_hat) and np.isnan(out[1].r_hat) and (out[0].ess, out[1].ess) == (123.0, 123.0)


def test_summarise_weighted_equal_weights_is_the_plain_summary() -> None:
    rng = np.random.default_rng(4)
    unit = rng.random((3000, 2))
    out = summarise_weighted(SPACE, unit, np.full(3000, 1 / 3000), 3000.0)
    theta = SPACE.from_unit(unit)
    for j in range(2):
        assert out[j].mean == pytest.approx(theta[:, j].mean())
        assert out[j].sd == pytest.approx(theta[:, j].std())
        assert out[j].q50 == pytest.approx(np.median(theta[:, j]), rel=1e-3)


def test_a_weighted_table_has_no_r_hat_in_csv_and_json_and_the_chains_keep_theirs(tmp_path: Path) -> None:
    """The reported table of an importance sample: R-hat NaN, an empty CSV cell and null in
    ``summary.json``; the chains' table keeps theirs; without importance weights the
    chains' table is the reported one, R-hat included."""
    rng = np.random.default_rng(8)
    comps = [chains(iid(rng, 300, 8))]
    unit = rng.random((500, 2))
    sample = SimpleNamespace(unit=unit, weights=np.full(500, 1 / 500), ess=480.0,
                             resample=lambda n, g: unit[g.integers(0, 500, n)])
    t = _tables(SimpleNamespace(space=SPACE), comps, sample, rng)
    assert all(np.isnan(s.r_hat) and s.ess == 480.0 for s in t["table"])
    assert all(np.isfinite(s.r_hat) for s in t["raw"])
    write_table(tmp_path / "summary.csv", t["table"])
    write_table(tmp_path / "summary_emulator.csv", t["raw"])
    rows = list(csv.DictReader((tmp_path / "summary.csv").open(encoding="utf-8")))
    cells = [(r["parameter"], r["r_hat"], r["ess"]) for r in rows]
    assert cells == [("n", "", "480"), ("tau_c_MPa", "", "480")]
    raw_rows = list(csv.DictReader((tmp_path / "summary_emulator.csv").open(encoding="utf-8")))
    assert [float(r["r_hat"]) for r in raw_rows] == pytest.approx([s.r_hat for s in t["raw"]], rel=1e-5)
    write_json(tmp_path / "summary.json", {"parameters": [asdict(s) for s in t["table"]],
                                           "emulator_parameters": [asdict(s) for s in t["raw"]]})
    text = (tmp_path / "summary.json").read_text(encoding="utf-8")
    info = json.loads(text)
    assert "NaN" not in text and [p["r_hat"] for p in info["parameters"]] == [None, None]
    assert [p["r_hat"] for p in info["emulator_parameters"]] == [s.r_hat for s in t["raw"]]
    plain = _tables(SimpleNamespace(space=SPACE), comps, None, rng)
    assert plain["table"] is plain["raw"] and all(np.isfinite(s.r_hat) for s in plain["table"])


def test_correlations_are_computed_in_sampled_coordinates() -> None:
    """A linear relation between n and log10 tau_c gives r = 1 there, less in raw units."""
    rng = np.random.default_rng(5)
    z = rng.random(2000)
    theta = np.column_stack([0.2 + 0.4 * z, 10 ** (-2.3 + 2.3 * z)])
    r, labels, pairs = correlations(SPACE, theta)
    assert labels == ["n", "log10 tau_c_MPa"]
    assert r[0, 1] == pytest.approx(1.0) and r[0, 0] == pytest.approx(1.0)
    assert np.corrcoef(theta, rowvar=False)[0, 1] < 0.95
    assert pairs == [("n", "tau_c_MPa", pytest.approx(1.0))]


def test_correlations_threshold_top_and_weights() -> None:
    """Pairs strongest first, cut by the threshold and ``top``; integer weights act as
    repeated draws."""
    space = ParameterSpace(BASE_PARAMETERS, {"tau_star_Pa": 1e4})  # n, B, tau_c, m free
    rng = np.random.default_rng(6)
    u = rng.random((2000, 4))
    u[:, 1] = 0.7 * u[:, 0] + 0.3 * u[:, 1]  # B strongly with n (r about 0.92)
    u[:, 3] = 0.4 * u[:, 0] + 0.6 * u[:, 3]  # m with n (0.55) and B (0.51)
    theta = space.from_unit(u)
    r, _, pairs = correlations(space, theta, top=3, threshold=0.3)
    # sampled coordinates are affine in the unit cube: the same correlations
    np.testing.assert_allclose(r, np.corrcoef(u, rowvar=False), atol=1e-10)
    assert [p[:2] for p in pairs] == [("n", "B_Pa_s"), ("n", "m"), ("B_Pa_s", "m")]
    assert pairs[0][2] == pytest.approx(r[0, 1]) and pairs[2][2] == pytest.approx(r[1, 3])
    assert [p[:2] for p in correlations(space, theta, threshold=0.53)[2]] == [("n", "B_Pa_s"), ("n", "m")]
    assert [p[:2] for p in correlations(space, theta, top=1)[2]] == [("n", "B_Pa_s")]
    counts = rng.integers(1, 4, size=2000)
    rep = np.repeat(theta, counts, axis=0)
    r_rep = correlations(space, rep)[0]
    r_w = correlations(space, theta, weights=counts / counts.sum())[0]
    np.testing.assert_allclose(r_w, r_rep, atol=1e-10)
    assert not np.allclose(r_w, r)


def test_correlations_of_one_parameter() -> None:
    space = ParameterSpace(BASE_PARAMETERS, {"tau_star_Pa": 1e4, "B_Pa_s": 1e4, "m": 1.5, "n": 0.4})
    r, labels, pairs = correlations(space, np.array([[0.1], [0.2]]))
    assert r.shape == (1, 1) and labels == ["log10 tau_c_MPa"] and pairs == []


def _summary(r_hat: float, ess: float) -> ParameterSummary:
    return ParameterSummary("n", "-", 0.4, 0.1, 0.3, 0.4, 0.5, r_hat, ess)


def test_warnings_name_r_hat_ess_convergence_and_acceptance() -> None:
    rng = np.random.default_rng(7)
    ok = chains(iid(rng, 10, 4))
    assert warnings_for([_summary(1.01, 500.0)], [ok]) == []
    w = warnings_for([_summary(1.2, 500.0)], [ok])
    assert len(w) == 1 and "R-hat 1.200" in w[0]
    assert "R-hat" in warnings_for([_summary(float("nan"), 500.0)], [ok])[0]
    w = warnings_for([_summary(1.0, 150.0)], [ok])
    assert len(w) == 1 and "150 effective samples" in w[0]
    w = warnings_for([_summary(1.0, 500.0)], [ok, chains(iid(rng, 10, 4), converged=False)])
    assert len(w) == 1 and "autocorrelation" in w[0]
    for acc in (0.05, 0.9):
        w = warnings_for([_summary(1.0, 500.0)], [chains(iid(rng, 10, 4), acceptance=acc)])
        assert len(w) == 1 and f"{acc:.2f}" in w[0]


def test_inference_data_without_correction_has_one_chain_per_walker() -> None:
    rng = np.random.default_rng(8)
    comps = [chains(iid(rng, 30, 4)), chains(iid(rng, 20, 6))]
    idata = to_inference_data(SPACE, comps, {"n_eff": np.float64(12.5)})
    n = idata.posterior["n"].values
    assert n.shape == (10, 20)
    unit, logp = stack_components(comps)
    np.testing.assert_allclose(n, SPACE.from_unit(unit.reshape(-1, 2))[:, 0].reshape(10, 20))
    np.testing.assert_allclose(idata.sample_stats["lp"].values, logp)
    assert idata.attrs["n_eff"] == 12.5 and type(idata.attrs["n_eff"]) is float


def test_inference_data_with_correction_holds_resample_weights_and_emulator_chains() -> None:
    """The resample's lp is the exact log target of the very rows it copies."""
    rng = np.random.default_rng(9)
    comps = [chains(iid(rng, 25, 4))]
    unit = rng.random((50, 2))
    corrected = SimpleNamespace(unit=unit, log_target=-np.arange(50.0), log_weight=np.log(np.full(50, 0.02)),
                                iteration=np.repeat(np.arange(5), 10))
    picked = rng.integers(0, 50, size=40)
    idata = to_inference_data(SPACE, comps, {}, corrected=corrected, resampled=unit[picked])
    assert idata.posterior["n"].values.shape == (1, 40)
    np.testing.assert_allclose(idata.posterior["n"].values[0], SPACE.from_unit(unit[picked])[:, 0])
    np.testing.assert_array_equal(idata.sample_stats["lp"].values[0], -picked.astype(float))
    assert idata.emulator_posterior["n"].values.shape == (4, 25)
    np.testing.assert_array_equal(idata.importance["iteration"].values[0], corrected.iteration)
    np.testing.assert_allclose(idata.importance["tau_c_MPa"].values[0], SPACE.from_unit(unit)[:, 1])
