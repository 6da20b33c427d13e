"""The posterior stage end to end on a small synthetic two-parameter problem."""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import arviz as az
import numpy as np
import pytest

from smcbayes.cli import main
from smcbayes.config.settings import ROUND_RUNS_CURVES
from smcbayes.config.specs import LossSpec
from smcbayes.posterior import curve_round
from smcbayes.posterior.active import STABLE_ROUNDS
from smcbayes.posterior.context import load_run
from smcbayes.posterior.correct import CorrectionSettings, ImportanceSample
from smcbayes.posterior.curve_stage import Learned
from smcbayes.posterior.curves import (
    FORCE_FLOOR_KN,
    CurveEmulator,
    CurveFeatures,
    CurveLossUnsupported,
    log_hidden_mass,
    log_posterior,
)
from smcbayes.posterior.spread import SPREAD_MAX
from smcbayes.surrogate.gp import load_surrogate

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Noisy synthetic data at tau_c = 0.01 MPa, m = 1.5; a short calibration."""
    base = tmp_path_factory.mktemp("posterior")
    cfg = ROOT / "configs" / "verify-slip-2d.toml"
    assert main(["synth", str(cfg), "--truth", "tau_c_MPa=0.01", "--truth", "m=1.5",
                 "--noise-kN", "5",
                 "--correlated-kN", "3", "--correlation-s", "0.5", "--seed", "3",
                 "--out", str(base / "data")]) == 0
    assert main(["calibrate", str(base / "data" / "project.toml"), "--out", str(base / "run"),
                 "--budget", "20", "--init", "6", "--seed", "0", "--no-figures"]) == 0
    # the log-loss emulator's path (the curve emulator's has its own tests below)
    assert main(["posterior", str(base / "run"), "--emulator", "loss", "--walkers", "16", "--steps", "1500",
                 "--functions", "4", "--refine", "16", "--round-runs", "10", "--draws", "30",
                 "--correct-draws", "14000", "--seed", "1"]) == 0
    return base / "run"


def test_posterior_contains_truth(run_dir: Path) -> None:
    info = json.loads((run_dir / "posterior" / "summary.json").read_text())
    truth = {"tau_c_MPa": 0.01, "m": 1.5}
    for p in info["parameters"]:
        lo, hi = p["q05"], p["q95"]
        width = hi - lo
        # the 90 % interval (widened by a tenth of its width for the short chains) holds the truth
        assert lo - 0.1 * width <= truth[p["name"]] <= hi + 0.1 * width, p


def test_degenerate_pair_correlation_sign(run_dir: Path) -> None:
    # a later slip onset (larger tau_c) is compensated by faster slip (larger m)
    info = json.loads((run_dir / "posterior" / "summary.json").read_text())
    labels = info["correlation"]["labels"]
    r = np.array(info["correlation"]["matrix"])
    i, j = labels.index("log10 tau_c_MPa"), labels.index("m")
    assert r[i, j] > 0.2


def test_netcdf_opens_with_arviz(run_dir: Path) -> None:
    import arviz as az

    idata = az.from_netcdf(str(run_dir / "posterior" / "posterior.nc"))
    assert set(idata.posterior.data_vars) == {"tau_c_MPa", "m"}
    # the corrected posterior is reported; the emcee chains of the emulator are kept
    assert "acceptance_fraction" in idata.emulator_sample_stats
    assert set(idata.emulator_posterior.data_vars) == {"tau_c_MPa", "m"}
    w = np.exp(idata.importance["log_weight"].values.reshape(-1))
    assert abs(w.sum() - 1.0) < 1e-9
    summary = az.summary(idata)
    assert np.all(np.isfinite(summary["mean"]))


def test_outputs_written(run_dir: Path) -> None:
    out = run_dir / "posterior"
    for name in ("summary.csv", "refine.jsonl", "gp_refined.pt", "figures/corner.png",
                 "figures/correlations.svg", "figures/bands.png"):
        assert (out / name).is_file(), name
    # the round-by-round figure is the curve emulator's
    assert not (out / "figures" / "learning.png").exists()
    info = json.loads((out / "summary.json").read_text())
    assert info["emulator_check"]["points"] > 0
    assert info["effective_points"]["n_eff_total"] > 0
    assert (out / "summary_emulator.csv").is_file()
    # five training configurations: the bands' error model comes from leave-one-out refits
    assert info["discrepancy"]["residuals"] == "leave-one-configuration-out refits"
    # the synthetic closings end at the force limit and are held there: past the simulated
    # switch both curves sit at the limit, so the error there is nil
    past = [b for b in info["discrepancy"]["bins"] if b["to_mm"] is not None and b["to_mm"] <= 0.0]
    assert past and all(abs(b[q]) < 1e-6 for b in past for q in ("q05_kN", "q50_kN", "q95_kN"))
    # the bands' runs: 30 draws on the 5 configurations, and the refits' batch, (1 + 3 K) K
    assert info["forward_evaluations"]["bands"] == 30 * 5 + (1 + 3 * 5) * 5
    # each band's curves as data: quantiles and the predictive mean on the band's grid
    rows = list(csv.reader((out / "bands" / f"{next(iter(info['bands']))}.csv").open(encoding="utf-8")))
    assert rows[0][0] == "time_s" and rows[0][-1] == "force_pred_mean_kN" and len(rows[0]) == 12
    vals = np.array(rows[1:], dtype=float)
    assert len(rows) - 1 == 300 and np.all(np.diff(vals[:, 0]) > 0)
    assert np.all(np.diff(vals[:, 1:6], axis=1) >= -1e-9) and np.all(np.diff(vals[:, 6:11], axis=1) >= -1e-9)
    # the mean of clipped draws lies in [0, force limit], not always inside its own 5-95 % band
    assert np.all(vals[:, -1] >= 0.0) and np.all(vals[:, -1] <= vals[:, 6:11].max() + 1e-9)


def test_the_active_learning_runs_rounds_of_the_size_asked(run_dir: Path) -> None:
    """``--round-runs 10`` with ``--refine 16``: a round of 10 and one of the 6 left of the
    budget (by default a budget of 16 would run rounds of 9 and 7)."""
    log = [json.loads(line) for line in (run_dir / "posterior" / "refine.jsonl").read_text().splitlines()]
    per_round = np.bincount([rec["round"] for rec in log])
    assert per_round[per_round > 0].tolist() == [10, 6]
    settings = json.loads((run_dir / "posterior" / "summary.json").read_text())["settings"]
    assert settings["round_runs"] == 10


def test_correction_is_reported(run_dir: Path) -> None:
    info = json.loads((run_dir / "posterior" / "summary.json").read_text())
    corr = info["correction"]
    assert corr["enabled"] and 0 < corr["evaluations"] <= corr["draws"]
    assert np.isfinite(corr["k_hat"]) and corr["ess"] > 1
    assert info["forward_evaluations"]["correction"] == corr["evaluations"]
    assert info["forward_evaluations"]["total"] >= corr["evaluations"] + info["forward_evaluations"]["refine"]
    assert [p["name"] for p in info["emulator_parameters"]] == [p["name"] for p in info["parameters"]]
    assert "emulator_spread" not in info  # the correction's weights judge a corrected posterior
    # no chain made the corrected sample: no R-hat in its table, the chains' in theirs
    assert all(p["r_hat"] is None and p["ess"] == corr["ess"] for p in info["parameters"])
    assert all(np.isfinite(p["r_hat"]) for p in info["emulator_parameters"])
    table = list(csv.DictReader((run_dir / "posterior" / "summary.csv").open(encoding="utf-8")))
    chains = list(csv.DictReader((run_dir / "posterior" / "summary_emulator.csv").open(encoding="utf-8")))
    assert [r["r_hat"] for r in table] == ["", ""] and all(np.isfinite(float(r["r_hat"])) for r in chains)


def _truth_inside_and_slip_pair_positive(info: dict) -> dict[str, float]:
    """Assert that the 90 % intervals hold the truth and that a later slip onset (larger
    tau_c) goes with faster slip (larger m); returns the truth."""
    truth = {"tau_c_MPa": 0.01, "m": 1.5}
    for p in info["parameters"]:
        assert p["q05"] <= truth[p["name"]] <= p["q95"], p
    labels, r = info["correlation"]["labels"], np.array(info["correlation"]["matrix"])
    assert r[labels.index("log10 tau_c_MPa"), labels.index("m")] > 0.2
    return truth


def test_active_learning_alone_finds_the_posterior(run_dir: Path, tmp_path: Path) -> None:
    """The emulator's path (no correction, an external simulator's default): the truth in
    the 90 % intervals, the slip pair's correlation sign right, every round logged, and the
    stage's verdict consistent with its stopping rule."""
    from smcbayes.posterior.stage import PosteriorSettings, run_posterior

    settings = PosteriorSettings(emulator="loss", walkers=16, steps=1500, refine=90,
                                 draws=20, correct_draws=0,
                                 seed=1)
    info = run_posterior(_fresh_copy(run_dir, tmp_path / "active"), settings)
    truth = _truth_inside_and_slip_pair_positive(info)
    active = info["active_learning"]
    assert not info["correction"]["enabled"] and active["enabled"]
    spread = info["emulator_spread"]
    assert (spread["functions"] >= 2
            and set(spread["per_parameter"]) == set(spread["sampling_noise"]) == set(truth))
    assert 0 <= spread["max_quantile_shift"] == max(spread["per_parameter"].values()) < 1
    # the sample functions' posteriors are pooled with the GP mean's, one component each
    assert spread["pooled"]
    idata = az.from_netcdf(str(tmp_path / "active" / "posterior" / "posterior.nc"))
    assert idata.attrs["pooled_functions"] == spread["functions"]
    assert idata.posterior.sizes["chain"] == (1 + spread["functions"]) * settings.walkers
    # the final spread's own reason (the active learning's budget reason may cite its last spread)
    flagged = any(r.startswith("the emulator's own uncertainty") for r in info["reliability"]["reasons"])
    assert flagged == (spread["max_quantile_shift"] > SPREAD_MAX)
    assert info["forward_evaluations"]["refine"] == active["evaluations"] <= 90
    assert info["forward_evaluations"]["inference"] == active["evaluations"] + 5
    log = [json.loads(line)
           for line in (tmp_path / "active" / "posterior" / "refine.jsonl").read_text().splitlines()]
    assert len(log) == active["evaluations"]
    stats = [rec["round_stats"] for rec in log if "round_stats" in rec]
    assert len(stats) == active["rounds"]
    assert all(set(s["seconds"]) == {"sampling", "forward", "fit"} and min(s["seconds"].values()) >= 0
               for s in stats)
    if active["converged"]:
        assert active["error_nats"] < 1.0 and active["quantile_shift"] <= 0.05
        # every round of the required run below the tolerance is logged
        assert len(stats) >= STABLE_ROUNDS
        assert all(s["error_nats"] < 1.0 for s in stats[-STABLE_ROUNDS:])
    else:
        assert not info["reliable"] and any("active learning" in r for r in info["reliability"]["reasons"])
    # the refined GP works on inputs rotated onto the principal axes of its last refit's draws
    refined, _ = load_surrogate(tmp_path / "active" / "posterior" / "gp_refined.pt")
    assert refined.rotation is not None
    np.testing.assert_allclose(refined.rotation.T @ refined.rotation, np.eye(2), atol=1e-10)


def test_a_large_spread_sends_the_active_learning_where_sample_functions_disagree(
        run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Validated rounds end the active learning only once the emulator's spread is small:
    after a large one, the next round tests draws of the sample functions' posteriors and
    one more validated round measures the spread again."""
    import smcbayes.posterior.active as active
    import smcbayes.posterior.stage as stage
    from smcbayes.posterior.stage import PosteriorSettings, run_posterior

    rng = np.random.default_rng(4)
    disputed = np.column_stack([rng.uniform(0.6, 0.9, 400), rng.uniform(0.1, 0.3, 400)])
    monkeypatch.setattr(active, "_round_error", lambda *args: 0.1)  # every round validated
    monkeypatch.setattr(active, "quantile_shift", lambda previous, draws: (None, 0.0))
    real, spreads = active._spread_settled, iter([0.5, 0.02])

    def settled(*args: object) -> tuple[float, active.SpreadChains]:
        value, chains = next(spreads), real(*args)[1]
        if value > 0.1:  # a large spread hands the next rounds these draws to test
            chains = active.SpreadChains(chains.control, [SimpleNamespace(samples=disputed[:, None])], 10, 0)
        return value, chains

    monkeypatch.setattr(active, "_spread_settled", settled)
    # the stage measures again the functions that ended the active learning, on chains fit to be pooled
    original, ended, repeated = active.spread_chains, [], []

    def recorded(into: list) -> object:
        def measure(*args: object) -> active.SpreadChains:
            into.append(original(*args))
            return into[-1]
        return measure

    monkeypatch.setattr(active, "spread_chains", recorded(ended))
    monkeypatch.setattr(stage, "spread_chains", recorded(repeated))
    folder = _fresh_copy(run_dir, tmp_path / "spread")
    info = run_posterior(folder, PosteriorSettings(emulator="loss", walkers=16,
                                                   steps=300, refine=150, draws=10,
                                                   correct_draws=0, seed=2))
    status = info["active_learning"]
    assert status["converged"] and status["spread_checks"] == 2 and status["spread"] == 0.02
    assert status["rounds"] == STABLE_ROUNDS + 1
    assert len(ended) == 2 and len(repeated) == 1 and repeated[0].seed == ended[-1].seed
    assert repeated[0].steps == 300  # the stage's step budget bounds the pooled chains
    log = [json.loads(line) for line in (folder / "posterior" / "refine.jsonl").read_text().splitlines()]
    flags = [rec["round_stats"]["disputed"] for rec in log if "round_stats" in rec]
    assert flags == [False] * STABLE_ROUNDS + [True]
    space = load_run(folder).space
    last = space.to_unit(np.array([[rec["params"][n] for n in space.free_names]
                                   for rec in log if rec["round"] == STABLE_ROUNDS]))
    tested = sum(bool(np.any(np.all(np.isclose(row, disputed), axis=1))) for row in last)
    assert tested >= len(last) // 3


def test_missing_run_dir_is_input_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["posterior", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calibrate" in err[0]


def test_likelihood_uses_the_smaller_estimate(run_dir: Path) -> None:
    info = json.loads((run_dir / "posterior" / "summary.json").read_text())
    eff = info["effective_points"]
    # correlated residuals: fewer independent points than grid points, but some
    points = 400 * len(eff["config_ids"])
    assert 1.0 < eff["n_eff_sandwich"] < points and 1.0 < eff["n_eff_residual"] < points
    assert eff["n_eff_total"] == min(eff["n_eff_sandwich"], eff["n_eff_residual"])
    # the best point and two central differences per free parameter
    assert info["forward_evaluations"]["residual_budget"] == 2 * 2 + 1


def test_residual_budget_with_a_parameter_on_its_bound(run_dir: Path) -> None:
    from smcbayes.posterior.stage import load_run, residual_budget

    ctx = load_run(run_dir)
    u = ctx.space.to_unit(ctx.best_theta)
    u[0, 0] = 1.0  # one-sided difference for the first parameter
    ctx.best_theta = ctx.space.from_unit(u)
    eff = residual_budget(ctx)
    assert np.isfinite(eff["n_eff_sandwich"]) and eff["n_eff_sandwich"] > 0
    assert eff["n_eff_total"] == min(eff["n_eff_sandwich"], eff["n_eff_residual"])


class _Killed(Exception):
    """Stands for a kill of the process in the middle of a batch."""


def _fresh_copy(run_dir: Path, dest: Path) -> Path:
    import shutil

    shutil.copytree(run_dir, dest, ignore=shutil.ignore_patterns("posterior"))
    return dest


def _stage_result(folder: Path) -> tuple[dict, np.ndarray, list[dict]]:
    import arviz as az

    info = json.loads((folder / "summary.json").read_text())
    for key in ("seconds", "stage_seconds", "forward_runs_reused", "forward_runs_made", "warnings"):
        info.pop(key, None)
    idata = az.from_netcdf(str(folder / "posterior.nc"))
    sample = np.column_stack([idata.posterior[v].values.reshape(-1) for v in ("tau_c_MPa", "m")])
    log = [json.loads(line) for line in (folder / "refine.jsonl").read_text().splitlines()]
    for rec in log:  # wall times differ between runs; everything else must not
        rec.get("round_stats", {}).pop("seconds", None)
    return info, sample, log


def test_killed_and_rerun_posterior_equals_uninterrupted(run_dir: Path, tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    from smcbayes.posterior.stage import PosteriorSettings, run_posterior
    from smcbayes.run.cache import ForwardCache

    settings = PosteriorSettings(emulator="loss", walkers=8, steps=100, functions=1, refine=18, draws=4,
                                 correct_draws=500, seed=4)
    whole = run_posterior(_fresh_copy(run_dir, tmp_path / "whole"), settings)
    # the best point's runs (5 configurations), made for N_eff, are read again for the bands' error model
    assert whole["forward_runs_reused"] == 5

    stores = {"n": 0}
    keep = ForwardCache.store

    def store_then_die(self: ForwardCache, result: object, theta: np.ndarray) -> None:
        stores["n"] += 1
        # 5 configurations: the sensitivities' batch, refinement round 1 (logged), then
        # the middle of round 2
        if stores["n"] == 13:
            raise _Killed
        keep(self, result, theta)  # type: ignore[arg-type]

    broken = _fresh_copy(run_dir, tmp_path / "broken")
    monkeypatch.setattr(ForwardCache, "store", store_then_die)
    with pytest.raises(_Killed):
        run_posterior(broken, settings)
    monkeypatch.setattr(ForwardCache, "store", keep)
    assert len((broken / "posterior" / "refine.jsonl").read_text().splitlines()) == 9
    rerun = run_posterior(broken, settings)

    a, b = _stage_result(tmp_path / "whole" / "posterior"), _stage_result(broken / "posterior")
    assert a[0] == b[0]  # every number of the summary, forward_evaluations included
    np.testing.assert_array_equal(a[1], b[1])
    assert a[2] == b[2]  # the refinement log: no round lost or counted twice
    assert rerun["forward_runs_reused"] > 0
    assert rerun["forward_runs_reused"] + rerun["forward_runs_made"] == whole["forward_runs_made"] + 5


def test_a_truth_check_is_named_degenerate_without_spending_runs(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture) -> None:
    """Noise-free curves of [calibration] truth: exit 0, no active learning, one verdict line."""
    run = tmp_path / "truth-run"
    cfg = ROOT / "configs" / "verify-slip-2d.toml"
    assert main(["calibrate", str(cfg), "--out", str(run), "--fidelity", "1d", "--budget", "6", "--init", "4",
                 "--no-figures"]) == 0
    capsys.readouterr()
    assert main(["posterior", str(run), "--walkers", "8", "--steps", "100", "--draws", "4"]) == 0
    out = capsys.readouterr().out.splitlines()
    verdicts = [line for line in out if line.startswith("reliable:")]
    assert len(verdicts) == 1 and "noise-free" in verdicts[0] and verdicts[0].startswith("reliable: no: ")
    info = json.loads((run / "posterior" / "summary.json").read_text())
    assert info["reliable"] is False and len(info["reliability"]["reasons"]) == 1
    active = info["active_learning"]
    assert (active["enabled"], active["evaluations"]) == (False, 0)
    # the built-in 1-D model's calibration ends with a local search: its evaluations join
    # the emulator's first training set
    assert active["start_points"]["local_search"] > 0
    assert not info["correction"]["enabled"]  # nor an importance correction by default


def test_auto_takes_the_curve_emulator_where_the_loss_allows_it(run_dir: Path,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    """``auto`` takes the curve emulator on noisy curves whose loss it gives; the log-loss
    one, saying why, for a loss it cannot give or noise-free curves; a named emulator stays,
    and the curve emulator named for a loss it cannot give is refused."""
    import logging

    from smcbayes.posterior.stage import _curves_allowed

    ctx = load_run(run_dir)
    assert not ctx.noise_free
    assert (_curves_allowed(ctx, "auto") and _curves_allowed(ctx, "curves")
            and not _curves_allowed(ctx, "loss"))
    profiled = LossSpec(contact="profile", contact_offset_mm=0.3)
    other = SimpleNamespace(noise_free=False, problem=SimpleNamespace(project=SimpleNamespace(loss=profiled)))
    with caplog.at_level(logging.INFO, logger="smcbayes.posterior.stage"):
        assert not _curves_allowed(other, "auto")
        assert not _curves_allowed(SimpleNamespace(noise_free=True, problem=ctx.problem), "auto")
    assert "contact 'profile'" in caplog.text and "noise-free" in caplog.text
    with pytest.raises(CurveLossUnsupported, match="nominal contact"):  # named, it is refused
        _curves_allowed(other, "curves")


def test_the_log_loss_emulator_is_corrected_by_default_only_with_a_fast_simulator(tmp_path: Path) -> None:
    """After the log-loss emulator (asked for, or ``auto`` on a loss the curves cannot give)
    the built-in 1-D model (milliseconds a run) corrects by default; the 2-D solver and an
    external simulator (seconds or minutes a run) do not, unless asked."""
    from types import SimpleNamespace

    from smcbayes.config import PosteriorSpec
    from smcbayes.config.settings import REFINE_CORRECTED
    from smcbayes.posterior.stage import _begin

    def ctx(fast: bool, simulator: str) -> SimpleNamespace:
        run = SimpleNamespace(begin_stage=lambda name, settings: tmp_path)
        profiled = SimpleNamespace(loss=LossSpec(contact="profile", contact_offset_mm=0.3))
        return SimpleNamespace(summary={"simulator": simulator}, noise_free=False, run=run,
                               problem=SimpleNamespace(fast=fast, train_ids=["a"], project=profiled),
                               stale_calibration_runs=None)

    for spec in (PosteriorSpec(emulator="loss"), PosteriorSpec()):
        draws = spec.correction.draws
        native = _begin(ctx(True, "native"), spec)[0]
        assert (native.emulator, native.correct_draws, native.refine) == ("loss", draws, REFINE_CORRECTED)
        assert _begin(ctx(False, "native"), spec)[0].correct_draws == 0  # the 2-D solver
        assert _begin(ctx(False, "external"), spec)[0].correct_draws == 0
    assert _begin(ctx(False, "native"),
                  PosteriorSpec(emulator="loss", correct_draws=50))[0].correct_draws == 50


def test_auto_starts_the_stage_with_the_curve_emulator_and_no_correction(run_dir: Path,
                                                                         tmp_path: Path) -> None:
    """On noisy curves whose loss the curve emulator gives, the default settings start the
    stage with it, its budget and no correction, although the built-in model is fast."""
    from smcbayes.config import PosteriorSpec
    from smcbayes.config.settings import REFINE_CURVES, ROUND_RUNS_CURVES
    from smcbayes.posterior.stage import _begin

    ctx = load_run(_fresh_copy(run_dir, tmp_path / "auto"))
    assert ctx.problem.fast and not ctx.noise_free
    settings, out_dir = _begin(ctx, PosteriorSpec())
    assert (settings.emulator, settings.correct_draws, settings.refine, settings.round_runs) == \
        ("curves", 0, REFINE_CURVES, ROUND_RUNS_CURVES)
    assert out_dir.is_dir()


def _rows(run: Path, count: int, seed: int) -> tuple[CurveFeatures, np.ndarray, np.ndarray, np.ndarray]:
    ctx = load_run(run)
    features = CurveFeatures(ctx.problem)
    u = np.random.default_rng(seed).random((count, ctx.space.dim))
    theta = ctx.space.from_unit(u)
    y, ok = features.of(ctx.runner.simulate(theta, features.ids))
    assert ok.all()
    return features, u, y, ctx.runner.loss(theta)


def test_the_features_give_the_loss_of_the_simulations(run_dir: Path) -> None:
    features, _, y, loss = _rows(run_dir, 8, 0)
    assert y.shape == (8, features.size)
    np.testing.assert_allclose(features.loss(y), loss, rtol=1e-9)


def test_the_features_give_the_loss_with_the_contact_of_the_end_state(thesis_data: Path,
                                                                      tmp_path: Path) -> None:
    """On the measured thesis trials, whose contact each trial's end state places (clipped
    at +-0.4 mm here, so that the clip acts on some), with compressibility: the emulated features
    reproduce the loss."""
    from smcbayes.config import load_project
    from smcbayes.simulation.problem import build_problem

    project = load_project(ROOT / "configs" / "thesis.toml", data_dir=thesis_data)
    project = project.model_copy(update={"loss": project.loss.model_copy(update={"contact_offset_mm": 0.4})})
    problem = build_problem(project, tmp_path, effects=["compressibility"])
    assert problem.project.loss.contact_mode == "end_state"
    features = CurveFeatures(problem)
    theta = problem.space.from_unit(np.random.default_rng(3).random((6, problem.space.dim)))
    y, ok = features.of(problem.runner().simulate(theta, features.ids))
    assert ok.all() and y.shape == (6, features.size) and features.size == 9 * (features.nodes + 2)
    np.testing.assert_allclose(features.loss(y), problem.runner().loss(theta), rtol=1e-9)
    offsets = np.abs(np.array([[m.end_stack_mm for m in features.measured]]) - y[:, -9:])
    assert np.any(offsets > 0.4) and np.any(offsets < 0.4)


@pytest.mark.parametrize("bound_mm", [0.0, 0.4])
def test_the_features_give_the_loss_with_end_state_offsets_of_either_sign(run_dir: Path,
                                                                         bound_mm: float) -> None:
    """The synthetic run's trials given measured end states above and below the simulated
    end heights (so the delays have either sign, and with a bound some are clipped): the
    features reproduce the loss."""
    from smcbayes.simulation.objective import SimulatorObjective

    problem = load_run(run_dir).problem
    spec = problem.project.loss.model_copy(update={"contact": "end_state", "contact_offset_mm": bound_mm})
    u = np.random.default_rng(2).random((6, problem.space.dim))
    theta = problem.space.from_unit(u)
    nominal = CurveFeatures(problem)
    y0, _ = nominal.of(problem.runner().simulate(theta, nominal.ids))
    shifts = dict(zip(nominal.ids, np.linspace(-0.6, 0.6, len(nominal.ids)), strict=True))
    heights = {cid: float(problem.project.configuration[0].charge.stack_height_mm) for cid in nominal.ids}
    measured = {cid: dataclasses.replace(m, end_stack_mm=heights.get(cid, 0.0) + shifts.get(cid, 0.0))
                for cid, m in problem.dataset.measurements.items()}
    dataset = dataclasses.replace(problem.dataset, measurements=measured)
    objective = SimulatorObjective(problem.simulator, dataset, problem.train_ids, spec)
    problem = dataclasses.replace(problem, project=problem.project.model_copy(update={"loss": spec}),
                                  objective=objective)
    features = CurveFeatures(problem)
    y, ok = features.of(problem.runner().simulate(theta, features.ids))
    assert ok.all() and y.shape == (6, features.size)
    np.testing.assert_allclose(features.loss(y), problem.runner().loss(theta), rtol=1e-9)
    offsets = np.array([[m.end_stack_mm for m in features.measured]]) - y[:, -len(features.ids):]
    assert offsets.min() < 0 < offsets.max()
    if bound_mm:
        assert np.any(np.abs(offsets) > bound_mm) and np.any(np.abs(offsets) < bound_mm)
    # the delays move the comparison: the loss differs from the nominal contact's
    assert not np.allclose(features.loss(y), nominal.loss(y0))


def test_the_features_give_the_loss_clipped_at_the_flow_stop(run_dir: Path) -> None:
    """The synthetic run's trials given flow stops before their measured ends, the loss
    clipped there: the features reproduce it, and it differs from the unclipped one."""
    from smcbayes.simulation.objective import SimulatorObjective

    problem = load_run(run_dir).problem
    spec = problem.project.loss.model_copy(update={"clip": "flow_stop"})
    measured = {cid: dataclasses.replace(m, flow_stop_s=0.7 * float(m.force.time_s[-1]))
                for cid, m in problem.dataset.measurements.items()}
    dataset = dataclasses.replace(problem.dataset, measurements=measured)
    objective = SimulatorObjective(problem.simulator, dataset, problem.train_ids, spec)
    clipped = dataclasses.replace(problem, project=problem.project.model_copy(update={"loss": spec}),
                                  objective=objective)
    theta = problem.space.from_unit(np.random.default_rng(4).random((6, problem.space.dim)))
    features = CurveFeatures(clipped)
    y, ok = features.of(clipped.runner().simulate(theta, features.ids))
    assert ok.all()
    np.testing.assert_allclose(features.loss(y), clipped.runner().loss(theta), rtol=1e-9)
    assert not np.allclose(features.loss(y), CurveFeatures(problem).loss(y))
    # features of another width are refused, not read past their rows
    with pytest.raises(ValueError, match="per row expected"):
        features.loss(y[:, :-1])


def test_a_loss_the_curves_cannot_give_is_refused(run_dir: Path) -> None:
    problem = load_run(run_dir).problem
    profiled = problem.project.model_copy(update={"loss": LossSpec(contact="profile", contact_offset_mm=0.3)})
    with pytest.raises(CurveLossUnsupported, match="nominal contact"):
        CurveFeatures(dataclasses.replace(problem, project=profiled))


def test_the_emulator_interpolates_its_points_and_predicts_new_ones(run_dir: Path) -> None:
    features, u, y, loss = _rows(run_dir, 60, 1)
    emulator = CurveEmulator(features, u[:45], y[:45])
    # at its own points the GP interpolates the curves (a nugget of at most 1e-1 of the variance)
    np.testing.assert_allclose(emulator.loss(u[:45]), loss[:45], rtol=0.05)
    held_out = np.abs(np.log(emulator.loss(u[45:])) - np.log(loss[45:]))
    # the training curves' mean, the prediction of an emulator that learnt nothing, is far worse
    mean_curve = np.repeat(y[:45].mean(axis=0, keepdims=True), 15, axis=0)
    naive = np.abs(np.log(features.loss(mean_curve)) - np.log(loss[45:]))
    assert np.median(held_out) < 0.2 * np.median(naive), (np.median(held_out), np.median(naive))
    # the variance term raises the loss, least at the training points, where the emulator is sure
    mean_loss = emulator.loss(u[45:])
    with_var = emulator.loss(u[45:], variance=True)
    assert np.all(with_var > mean_loss)
    np.testing.assert_allclose(emulator.loss(u[:45], variance=True), emulator.loss(u[:45]), rtol=1e-3)
    # the variance term is the nodes' mean of (F + 1 kN)^2 var log(F + 1 kN), var log from
    # the predicted variances of the principal components
    mean, var = emulator.predict(u[45:], variance=True)
    force = emulator.curves(mean)[:, :len(features.ids) * features.nodes] + FORCE_FLOOR_KN
    var_log = var[:, :emulator.components] @ emulator.basis ** 2
    s2 = features.spec.w_force * np.mean(force ** 2 * var_log, axis=1)
    np.testing.assert_allclose(with_var, mean_loss + s2, rtol=1e-12)
    # variances calibrated after a call reach the variance term (it keeps its node profile
    # until they change)
    emulator.calibrate(u[:45])
    mean, var = emulator.predict(u[45:], variance=True)
    var_log = var[:, :emulator.components] @ emulator.basis ** 2
    calibrated = emulator.loss(u[45:], variance=True)
    assert not np.allclose(calibrated, with_var)
    np.testing.assert_allclose(calibrated,
                               mean_loss + features.spec.w_force * np.mean(force ** 2 * var_log, axis=1),
                               rtol=1e-12)


def test_the_emulator_ignores_repeated_rows(run_dir: Path) -> None:
    features, u, y, _ = _rows(run_dir, 40, 3)
    emulator = CurveEmulator(features, u[:30], y[:30])
    # repeats at the end and in the middle: each row counts once, in its first place
    twice = CurveEmulator(features, np.vstack([u[:20], u[:5], u[20:30], u[25:28]]),
                          np.vstack([y[:20], y[:5], y[20:30], y[25:28]]))
    np.testing.assert_array_equal(twice.x, u[:30])
    np.testing.assert_array_equal(twice.y, y[:30])
    np.testing.assert_allclose(twice.loss(u[30:]), emulator.loss(u[30:]), rtol=1e-9)


def test_the_emulator_calibrates_its_variance_by_leave_one_out_errors(run_dir: Path) -> None:
    """The variance factor of each output is the mean squared standardised error of the GP
    refitted without each chosen row (same correlation and trend), computed here by brute
    force; too few chosen rows, or rows not in the data, leave the fit as it is."""
    from smcbayes.posterior.curve_spread import joint_outputs
    from smcbayes.posterior.curves import CALIBRATION_BOUNDS, JITTER, matern52

    features, u, y, _ = _rows(run_dir, 40, 8)
    emulator = CurveEmulator(features, u, y)
    chol, ls, nugget = emulator.corr.chol, emulator.corr.lengthscales, emulator.corr.nugget
    z = chol @ (chol.T @ emulator.alpha)  # the outputs less the trend
    chosen = np.arange(10, 35)
    z2 = []
    for i in chosen:
        rest = np.delete(np.arange(len(u)), i)
        k_rest = matern52(u[rest], u[rest], ls) + (nugget + JITTER) * np.eye(len(rest))
        k_i = matern52(u[i:i + 1], u[rest], ls)[0]
        mean = k_i @ np.linalg.solve(k_rest, z[rest])
        var = 1.0 + nugget + JITTER - k_i @ np.linalg.solve(k_rest, k_i)
        z2.append((z[i] - mean) ** 2 / var / np.where(emulator.scale2 > 0, emulator.scale2, np.inf))
    expected = np.where(emulator.scale2 > 0, np.clip(np.mean(z2, axis=0), *CALIBRATION_BOUNDS), 1.0)
    _, before = emulator.predict(u[:3] + 0.01, variance=True)
    # rows not in the data are ignored and a repeated row counts once
    emulator.calibrate(np.vstack([u[chosen], u[chosen[:4]], np.full((5, u.shape[1]), 0.123)]))
    factor = emulator.variance_factor
    np.testing.assert_allclose(factor, expected, rtol=1e-6)
    assert emulator.calibration_rows == len(chosen)
    inside = (factor > CALIBRATION_BOUNDS[0]) & (factor < CALIBRATION_BOUNDS[1])
    assert np.any(inside & (np.abs(factor - 1) > 0.05))
    _, after = emulator.predict(u[:3] + 0.01, variance=True)
    np.testing.assert_allclose(after, before * factor, rtol=1e-9)
    # a second call starts from the fit, not from the first call's factors
    emulator.calibrate(u[chosen])
    np.testing.assert_allclose(emulator.variance_factor, factor, rtol=1e-12)
    # the sample functions' spread about the mean follows the calibrated variance
    far = np.random.default_rng(4).random((3, u.shape[1]))
    draws = joint_outputs(emulator, far, 4000, np.random.default_rng(5))
    latent = emulator.predict(far, variance=True)[1] - emulator.corr.nugget * emulator.output_variance
    varies = emulator.scale2 > 0
    np.testing.assert_allclose(draws.var(axis=0)[:, varies], latent[:, varies], rtol=0.15)
    fresh = CurveEmulator(features, u, y)
    fresh.calibrate(u[:19])
    np.testing.assert_array_equal(fresh.variance_factor, 1.0)
    assert fresh.calibration_rows == 0


def test_sample_functions_of_the_curve_emulator_follow_its_variance(run_dir: Path) -> None:
    """Joint draws of the emulator's outputs: at its points they stay at the mean; far from
    them their spread is the GP's latent variance (the prediction's less the nugget)."""
    from smcbayes.posterior.curve_spread import joint_outputs

    features, u, y, _ = _rows(run_dir, 30, 4)
    emulator = CurveEmulator(features, u, y)
    far = np.random.default_rng(8).random((6, u.shape[1]))
    x = np.vstack([u[:4], far])
    draws = joint_outputs(emulator, x, 600, np.random.default_rng(9))
    mean, var = emulator.predict(x, variance=True)
    latent = var - emulator.corr.nugget * emulator.scale2[None, :]
    assert draws.shape == (600, 10, mean.shape[1])
    np.testing.assert_allclose(draws.mean(axis=0), mean, atol=0.2 * np.sqrt(latent.max()))
    varies = emulator.scale2 > 0.0  # a constant output has no spread anywhere
    ratio = draws[:, 4:, varies].var(axis=0) / latent[4:, varies]
    assert varies.sum() >= 3 and 0.75 < ratio.min() and ratio.max() < 1.3, (ratio.min(), ratio.max())
    near = draws[:, :4, varies].std(axis=0)
    assert np.all(near < 0.1 * np.sqrt(latent[4:, varies].min(axis=0))), near.max()


def test_the_hidden_mass_is_the_mean_curves_posterior_less_the_emulated_one(run_dir: Path) -> None:
    """The exploration's density is p_mean - p_expected, computed stably in logs: never
    above the mean curves' posterior, a share of it away from the training points (where
    the variance hides some of it) and almost none at them; the variance term is the GP's
    variance of log(F + 1 kN) carried to the force's squared error."""
    features, u, y, _ = _rows(run_dir, 30, 4)
    emulator = CurveEmulator(features, u, y)
    x = np.vstack([u[:5], np.random.default_rng(3).random((200, u.shape[1]))])
    mean_loss, s2 = emulator.loss_terms(x)
    np.testing.assert_allclose(mean_loss, emulator.loss(x))
    outputs, variance = emulator.predict(x, variance=True)
    j, nk = emulator.components, len(features.ids) * features.nodes
    force = emulator.curves(outputs)[:, :nk] + FORCE_FLOOR_KN
    expected_s2 = features.spec.w_force * np.mean(force ** 2 * (variance[:, :j] @ emulator.basis ** 2),
                                                  axis=1)
    np.testing.assert_allclose(s2, expected_s2, rtol=1e-9)
    for n_eff in (4.0, 2000.0):
        lp_mean = log_posterior(emulator, n_eff, variance=False)(x)
        lp_expected = log_posterior(emulator, n_eff, variance=True)(x)
        hidden = log_hidden_mass(emulator, n_eff)(x)
        # log(p_mean - p_expected) without leaving logs, as the densities underflow at large
        # N_eff; at the training points the reference's difference of two log posteriors
        # cancels to about 1e-7 nats, which the hidden mass's own form does not
        np.testing.assert_allclose(hidden, lp_mean + np.log(-np.expm1(lp_expected - lp_mean)),
                                   rtol=1e-9, atol=1e-5)
        assert np.all(np.isfinite(hidden[5:])) and np.all(hidden <= lp_mean)
    share = np.exp(log_hidden_mass(emulator, 4.0)(x) - log_posterior(emulator, 4.0, variance=False)(x))
    assert share[:5].max() < 1e-4 and share[5:].mean() > 0.01, (share[:5].max(), share[5:].mean())
    outside = x[5:7].copy()
    outside[:, 0] = 1.2
    assert np.all(log_hidden_mass(emulator, 4.0)(outside) == -np.inf)


def _emulator_sample(emulator: CurveEmulator, n_eff: float, count: int, seed: int) -> ImportanceSample:
    """The emulator's posterior sampled by importance from the prior (the unit cube)."""

    u = np.random.default_rng(seed).random((count, emulator.x.shape[1]))
    lp = log_posterior(emulator, n_eff, variance=False)(u)
    log_w = lp - np.logaddexp.reduce(lp)
    return ImportanceSample(u, lp, log_w, np.zeros(count, dtype=int), 0.0, 1.0 / np.sum(np.exp(2 * log_w)), 0,
                            target="emulator")


def test_a_spread_confirmed_after_a_failed_one_is_measured_again(run_dir: Path) -> None:
    """After more than one confirmation the reported spread and pool are drawn again on
    fresh supports of the same sample, the confirming reading kept beside them."""
    from smcbayes.posterior.curve_sample import CurveEmulation, FinalPosterior
    from smcbayes.posterior.curve_stage import _measured_again

    features, u, y, _ = _rows(run_dir, 25, 5)
    emulator = CurveEmulator(features, u, y)
    sample = _emulator_sample(emulator, 4.0, 6000, 6)
    final = FinalPosterior([], sample, {"max_quantile_shift": 0.01}, None, {"sampling": 1.0, "spread": 0.0})
    again = _measured_again(final, CurveEmulation(emulator, 4.0), ["a", "b"], np.random.default_rng(2))
    assert again.sample is sample and again.spread["confirmed_shift"] == 0.01
    assert again.max_shift != 0.01 and again.spread["supports"] >= 1 and again.pooled is not None
    np.testing.assert_array_equal(again.pooled.unit, sample.unit)
    assert again.seconds["sampling"] == 1.0 and again.seconds["spread"] > 0.0


def test_the_curve_emulator_spread_and_its_pooled_posterior(run_dir: Path) -> None:
    """Sample functions of an emulator of few points move its posterior; the pooled sample
    keeps the mean's points, each with the mean's share of its weight plus the functions';
    an emulator without uncertainty moves nothing and its pooled posterior is the mean's;
    the same seed gives the same result."""
    from smcbayes.posterior.curve_spread import curve_spread
    from smcbayes.posterior.weights import weighted_quantile

    features, u, y, _ = _rows(run_dir, 25, 5)
    emulator = CurveEmulator(features, u, y)
    sample = _emulator_sample(emulator, 4.0, 6000, 6)
    names = ["a", "b"]
    spread, pooled = curve_spread(emulator, 4.0, sample, names, np.random.default_rng(1), functions=3,
                                  supports=1)
    again = curve_spread(emulator, 4.0, sample, names, np.random.default_rng(1), functions=3, supports=1)
    assert again[0] == spread
    np.testing.assert_array_equal(again[1].log_weight, pooled.log_weight)
    assert spread["functions"] == 3 and set(spread["per_parameter"]) == set(names)
    assert spread["max_quantile_shift"] > 0.0 and min(spread["function_ess"]) > 1.0
    np.testing.assert_array_equal(pooled.unit, sample.unit)
    np.testing.assert_array_equal(pooled.log_target, sample.log_target)
    w = pooled.weights
    assert np.isclose(w.sum(), 1.0) and pooled.ess == pytest.approx(1.0 / np.sum(w * w))
    # a point off the support keeps the mean's quarter share of its weight
    off = w < 0.25 * sample.weights * (1 + 1e-9) + 1e-300
    assert off.sum() > 1000
    np.testing.assert_allclose(w[off], 0.25 * sample.weights[off], rtol=1e-9)
    sure = CurveEmulator(features, u, y)
    sure.scale2 = np.zeros_like(sure.scale2)
    # on several supports every function counts and takes an equal share of the pool
    wide, pooled_wide = curve_spread(emulator, 4.0, sample, names, np.random.default_rng(1), functions=3,
                                     supports=2)
    assert wide["functions"] == 6 and wide["supports"] == 2 and len(wide["function_ess"]) == 6
    off = pooled_wide.weights < sample.weights / 7 * (1 + 1e-9) + 1e-300
    assert off.sum() > 1000
    np.testing.assert_allclose(pooled_wide.weights[off], sample.weights[off] / 7, rtol=1e-9)
    still, same = curve_spread(sure, 4.0, sample, names, np.random.default_rng(1), functions=3, supports=1)
    assert still["max_quantile_shift"] < 1e-12  # the same weights, to rounding
    # each function's share is then the mean's posterior on the support, drawn with
    # probabilities ~ sqrt(weight) and weighted back: the pooled quantiles are the mean's
    for k in range(2):
        q_same = weighted_quantile(sample.unit[:, k], same.weights, [0.05, 0.5, 0.95])
        q_mean = weighted_quantile(sample.unit[:, k], sample.weights, [0.05, 0.5, 0.95])
        np.testing.assert_allclose(q_same, q_mean, atol=0.02)


def test_the_emulated_posterior_is_the_same_to_the_bit_on_one_thread_and_on_two(run_dir: Path) -> None:
    """The sample functions and the importance sample's batches run side by side on the
    emulator's threads, each task's rows as on one thread: the same values, the same path."""
    from smcbayes.posterior import curve_sample
    from smcbayes.posterior.curve_spread import curve_spread
    from smcbayes.posterior.threads import emulator_threads

    features, u, y, _ = _rows(run_dir, 25, 5)
    emulator = CurveEmulator(features, u, y)
    sample = _emulator_sample(emulator, 4.0, 9000, 6)
    start = np.random.default_rng(0).random((400, u.shape[1]))
    spec = CorrectionSettings(ess_target=2 * curve_sample.ROUND_ESS)
    before = log_posterior(CurveEmulator(features, u[:20], y[:20]), 4.0)
    runs = []
    for count in (1, 2):
        with emulator_threads(count):
            spread, pooled = curve_spread(emulator, 4.0, sample, ["a", "b"], np.random.default_rng(1),
                                          functions=5, supports=2)
            drawn = curve_sample.emulator_sample(emulator, 4.0, start, spec, 12000, np.random.default_rng(2),
                                                 per_iteration=6000)
            runs.append((spread, pooled, drawn, curve_sample.quantile_shift(drawn, before)))
    (s1, p1, d1, q1), (s2, p2, d2, q2) = runs
    np.testing.assert_equal(s1, s2)  # NaN equal to NaN, as a function's ESS may be
    assert q1 == q2 and q1 > 0.0
    np.testing.assert_array_equal(p1.log_weight, p2.log_weight)
    # the batches of an iteration (6,000 draws) ran on the two threads
    assert len(d1.unit) >= 6000 > curve_sample.EMULATOR_BATCH
    np.testing.assert_array_equal(d1.unit, d2.unit)
    np.testing.assert_array_equal(d1.log_target, d2.log_target)


def test_the_reported_emulator_sample_aims_past_the_target_it_is_settled_at(
        run_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The emulated posterior's importance sample draws on to the higher ESS it aims at,
    and counts as settled at the correction's own targets even where the draws run out
    before that aim; the stage's reported sample is that sample at the module's aim."""
    import smcbayes.posterior.curve_sample as curve_sample

    features, u, y, _ = _rows(run_dir, 25, 5)
    emulator = CurveEmulator(features, u, y)
    spec = CorrectionSettings(ess_target=2 * curve_sample.ROUND_ESS)
    start = np.random.default_rng(0).random((400, u.shape[1]))

    def draw(draws: int, aim: float) -> ImportanceSample:
        return curve_sample.emulator_sample(emulator, 4.0, start, spec, draws, np.random.default_rng(1),
                                           aim=aim, per_iteration=2000)

    plain, aimed, short = draw(30000, 0.0), draw(30000, 2500.0), draw(4000, 1e6)
    assert plain.settled and aimed.settled and plain.ess_target == aimed.ess_target == spec.ess_target
    assert 2500 <= aimed.ess and len(aimed.unit) > len(plain.unit) and aimed.ess_aim == 2500.0
    assert short.ess < 1e6 and short.settled and short.draws_needed is None
    monkeypatch.setattr(curve_sample, "FINAL_ESS", 2500.0)
    monkeypatch.setattr(curve_sample, "FINAL_ITERATION", 2000)
    monkeypatch.setattr(curve_sample, "EMULATOR_DRAWS", 30000)
    reported = curve_sample.sample_emulator(emulator, 4.0, start, spec, np.random.default_rng(1))
    np.testing.assert_array_equal(reported.unit, aimed.unit)


def _scripted_learning(run_dir: Path, monkeypatch: pytest.MonkeyPatch, budget: int, readings: list[float],
                       round_runs: int = ROUND_RUNS_CURVES, validated: Callable[..., bool] | None = None,
                       given: list[np.ndarray | None] | None = None) -> tuple[Learned, list[int]]:
    """The curve emulator's active learning from 25 points in rounds of ``round_runs`` with
    the validation stubbed (``validated`` of the rounds' errors, shifts, tolerance and
    spreads; by default every round validates) and confirmations that read the spreads
    ``readings`` in turn: what it learned and the training points each confirmation saw
    (the draws each was given to start from are appended to ``given``)."""
    import smcbayes.posterior.curve_progress as curve_progress
    import smcbayes.posterior.curve_sample as curve_sample
    import smcbayes.posterior.curve_stage as curve_stage
    from smcbayes.posterior.curve_sample import FinalPosterior

    monkeypatch.setattr(curve_round, "ROUND_DRAWS", 4000)
    # two iterations a round, so that the rounds' samples adapt as at full size
    monkeypatch.setattr(curve_sample, "EMULATOR_ITERATION", 2000)
    monkeypatch.setattr(curve_progress, "rounds_validated", validated or (lambda *args: True))
    ctx = load_run(run_dir)
    features, u, y, _ = _rows(run_dir, 25, 5)
    rng = np.random.default_rng(3)
    points = rng.random((500, u.shape[1]))
    flat = ImportanceSample(points, np.zeros(500), np.full(500, -np.log(500.0)), np.zeros(500, dtype=int),
                            0.0, 500.0, 0, target="emulator")
    spreads, seen = iter(readings), []

    def confirm(emulator: CurveEmulator, draws: np.ndarray | None = None) -> FinalPosterior:
        seen.append(len(emulator.x))
        if given is not None:
            given.append(draws)
        return FinalPosterior([], flat, {"max_quantile_shift": next(spreads)}, None,
                              {"sampling": 0.0, "spread": 0.0})

    def simulate(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return features.of(ctx.runner.simulate(ctx.space.from_unit(rows), features.ids))

    learned = curve_stage.learn(simulate, features, u, y, 4.0, budget, 1.0, rng, walkers=16, confirm=confirm,
                                round_runs=round_runs)
    return learned, seen


def test_the_active_learning_stops_only_when_the_reported_posterior_confirms(
        run_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With a confirmation, a validated emulator's reported posterior is drawn before the
    learning stops: while its spread is too large the learning goes on (one more round
    here, the validation itself stubbed), and the posterior that confirms is the one kept."""

    learned, seen = _scripted_learning(run_dir, monkeypatch, 200, [1.5 * SPREAD_MAX, 0.5 * SPREAD_MAX])
    record = learned.record
    assert record["converged"] and record["rounds"] == 1 and record["evaluations"] == ROUND_RUNS_CURVES
    assert seen == [25, 25 + ROUND_RUNS_CURVES] and len(learned.x) == seen[-1]
    assert [c["passed"] for c in record["confirmations"]] == [False, True]
    assert learned.final is not None and learned.final.max_shift == 0.5 * SPREAD_MAX


def test_each_rounds_exploring_walkers_go_on_from_where_the_last_rounds_stopped(
        run_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The first round's exploration (the hidden posterior mass) starts at the
    best training point and runs up to :data:`ROUND_STEPS` steps; each later one goes on
    from the walkers the round before left, for :data:`WARM_STEPS`; a confirmation gets
    draws of the last round's posterior to start its sampling from, and so does the
    reported posterior after the learning."""
    import smcbayes.posterior.curve_stage as curve_stage
    from smcbayes.posterior.curve_sample import START_ROWS

    calls: list[tuple[np.ndarray | None, np.ndarray | None]] = []
    steps: list[int] = []
    kinds: list[bool] = []
    real_round, real_chains = curve_stage.next_round, curve_round.sample_chains

    def spy(*args: Any, **kwargs: Any) -> curve_round.Round:
        step = real_round(*args, **kwargs)
        calls.append((kwargs["explorers"], step.explorers))
        return step

    def chains(*args: Any, **kwargs: Any) -> Any:
        steps.append(args[4])
        u = np.random.default_rng(len(steps)).random((20, args[0].x.shape[1]))
        kinds.append(bool(np.allclose(kwargs["log_prob"](u), log_hidden_mass(args[0], args[1])(u))))
        return real_chains(*args, **kwargs)

    monkeypatch.setattr(curve_stage, "next_round", spy)
    monkeypatch.setattr(curve_round, "sample_chains", chains)
    given: list[np.ndarray | None] = []
    # the rounds validate from the third on; the first confirmation passes
    learned, _ = _scripted_learning(run_dir, monkeypatch, 4 * ROUND_RUNS_CURVES, [0.5 * SPREAD_MAX],
                                    validated=lambda errors, *args: len(errors) >= 3, given=given)
    d = learned.x.shape[1]
    assert learned.record["rounds"] == len(calls) == 3 and calls[0][0] is None
    assert steps == [curve_round.ROUND_STEPS, curve_round.WARM_STEPS, curve_round.WARM_STEPS]
    assert kinds == [True] * 3
    for (handed, _), (_, left) in zip(calls[1:], calls[:-1], strict=True):
        assert handed is left and left is not None and left.shape == (16, d)
    assert len(given) == 1 and given[0] is not None and given[0].shape == (3 * START_ROWS // 4, d)
    assert learned.draws is given[0]


def test_each_round_logs_its_measures_beside_the_bounds_of_the_stop(
        run_dir: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """A user watching a long learning sees after each round the runs spent and the round's
    error, move and spread beside the bounds the stop asks of them."""
    with caplog.at_level(logging.INFO, logger="smcbayes.posterior.curve_stage"):
        learned, _ = _scripted_learning(run_dir, monkeypatch, 200, [1.5 * SPREAD_MAX, 0.5 * SPREAD_MAX])
    lines = [r.getMessage() for r in caplog.records if "curve emulator round" in r.getMessage()]
    record = learned.record
    assert len(lines) == record["rounds"] == 1
    assert (f"round 1: {25 + ROUND_RUNS_CURVES} points, {ROUND_RUNS_CURVES} of 200 active-learning runs;"
            in lines[0])
    assert f"error {record['last_errors_nats'][-1]:.2f} nats" in lines[0] and "at most 1 to stop" in lines[0]
    # the first round has no earlier emulator to have moved from, and no three rounds to average
    assert "posterior move not measured" in lines[0] and "mean of the last" not in lines[0]
    assert f"spread {record['last_spreads'][-1]:.3f} (at most {SPREAD_MAX:g} on average)" in lines[0]


def test_the_curve_emulator_learns_in_rounds_of_the_size_asked(run_dir: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Rounds of 15 runs: the second confirmation sees the first round's 15 more points."""
    learned, seen = _scripted_learning(run_dir, monkeypatch, 200, [1.5 * SPREAD_MAX, 0.5 * SPREAD_MAX], 15)
    assert seen == [25, 40] and learned.record["evaluations"] == 15 and learned.record["rounds"] == 1


def test_after_its_last_failed_confirmation_the_learning_runs_to_its_budget(
        run_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Once :data:`CONFIRMATIONS` confirmations failed, a validation (stubbed here) neither
    draws the reported posterior again nor stops the learning before its budget's end;
    there, where the stage draws that posterior anyway, it is confirmed once more."""
    import smcbayes.posterior.curve_progress as curve_progress

    monkeypatch.setattr(curve_progress, "CONFIRMATIONS", 1)
    budget = 2 * ROUND_RUNS_CURVES
    learned, seen = _scripted_learning(run_dir, monkeypatch, budget, [1.5 * SPREAD_MAX, 0.5 * SPREAD_MAX])
    record = learned.record
    # none after the first round: the one failure allowed was spent
    assert seen == [25, 25 + budget] and [c["passed"] for c in record["confirmations"]] == [False, True]
    assert record["converged"] and record["rounds"] == 2 and record["evaluations"] == budget
    assert learned.final is not None and learned.final.max_shift == 0.5 * SPREAD_MAX


def test_at_the_budgets_end_rounds_from_before_a_failed_confirmation_count(
        run_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """After a failed confirmation new rounds must validate before the next one, but at the
    budget's end, where none can follow, the last rounds count whenever they ran, and the
    reported posterior drawn there confirms the learning (the validation stubbed: any two
    rounds validate); before the budget's end the old rounds do not count."""
    def two_rounds(errors: list[float], *args: Any) -> bool:
        return len(errors) >= 2

    readings = [1.5 * SPREAD_MAX, 0.5 * SPREAD_MAX]
    learned, seen = _scripted_learning(run_dir, monkeypatch, 3 * ROUND_RUNS_CURVES, readings,
                                       validated=two_rounds)
    record = learned.record
    # the failure after two rounds asks for two new ones; only one more fits the budget
    assert [(c["rounds"], c["passed"]) for c in record["confirmations"]] == [(2, False), (3, True)]
    assert seen == [25 + 2 * ROUND_RUNS_CURVES, 25 + 3 * ROUND_RUNS_CURVES]
    assert record["converged"] and record["validated_at_budget_end"] and record["rounds"] == 3
    assert learned.final is not None and learned.final.max_shift == 0.5 * SPREAD_MAX
    # with room for both new rounds the next confirmation waits for them, and at the
    # budget's end it is an ordinary validation
    learned, _ = _scripted_learning(run_dir, monkeypatch, 4 * ROUND_RUNS_CURVES, readings,
                                    validated=two_rounds)
    record = learned.record
    assert [(c["rounds"], c["passed"]) for c in record["confirmations"]] == [(2, False), (4, True)]
    assert record["converged"] and not record["validated_at_budget_end"]


def test_a_confirmation_that_passes_is_the_posterior_drawn_after_the_learning(
        run_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The confirmation draws in the order the stage draws its reported posterior after the
    learning, so a learning that stops at its first confirmation reports what it reported
    without one (the validation stubbed, every spread confirming)."""
    import smcbayes.posterior.curve_progress as curve_progress
    import smcbayes.posterior.curve_sample as curve_sample
    import smcbayes.posterior.curve_stage as curve_stage
    from smcbayes.posterior.stage import PosteriorSettings

    monkeypatch.setattr(curve_sample, "EMULATOR_DRAWS", 8000)
    monkeypatch.setattr(curve_sample, "FINAL_ITERATION", 2000)
    monkeypatch.setattr(curve_progress, "rounds_validated", lambda *args: True)
    monkeypatch.setattr(curve_progress, "SPREAD_MAX", 1.0)
    ctx = load_run(run_dir)
    features, u, y, _ = _rows(run_dir, 25, 5)
    settings = PosteriorSettings(emulator="curves", walkers=16, steps=600, correct_draws=0)
    names = ctx.space.free_names

    def simulate(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return features.of(ctx.runner.simulate(ctx.space.from_unit(rows), features.ids))

    def final(emulator: CurveEmulator, rng: np.random.Generator,
              draws: np.ndarray | None = None) -> curve_sample.FinalPosterior:
        return curve_sample.final_posterior(curve_sample.CurveEmulation(emulator, 4.0), settings, names, rng,
                                            start=draws)

    rng = np.random.default_rng(7)
    plain = curve_stage.learn(simulate, features, u, y, 4.0, 40, 1.0, rng, walkers=16)
    after = final(plain.emulator, rng)
    rng = np.random.default_rng(7)
    confirmed = curve_stage.learn(simulate, features, u, y, 4.0, 40, 1.0, rng, walkers=16,
                                  confirm=lambda emulator, draws: final(emulator, rng, draws))
    assert plain.final is None and confirmed.final is not None
    assert plain.record["rounds"] == confirmed.record["rounds"] == 0 and confirmed.record["converged"]
    np.testing.assert_array_equal(confirmed.final.sample.unit, after.sample.unit)
    np.testing.assert_array_equal(confirmed.final.pooled.log_weight, after.pooled.log_weight)
    assert confirmed.final.spread == after.spread


def test_the_calibration_keeps_the_curves_of_the_gps_points_not_the_local_searchs(run_dir: Path) -> None:
    from smcbayes.surrogate.polish import is_search

    ctx = load_run(run_dir)
    state = ctx.run.evaluation_log().read()
    cache, ids = ctx.run.calibration_cache(), ctx.problem.train_ids
    searched = [is_search(state, r["round"]) for r in state.evaluations.values()]
    assert any(searched) and not all(searched)
    for rec, search in zip(state.evaluations.values(), searched, strict=True):
        theta = np.array([[rec["params"][n] for n in ctx.space.free_names]])
        assert cache.holds(ids, theta)[0] == (rec["status"] == "ok" and not search)


def test_the_curve_emulators_start_takes_the_calibrations_curves_as_simulated(run_dir: Path,
                                                                             tmp_path: Path) -> None:
    """The GP's points as the log holds them, to the bit, and their kept curves equal to
    those simulated afresh: a posterior that reuses them takes the path of one that does not."""
    from smcbayes.posterior.context import logged_rows

    ctx = load_run(run_dir)
    gp, _ = load_surrogate(ctx.run.gp_path)
    theta = logged_rows(ctx, gp.x_unit)
    logged = {tuple(r["params"][n] for n in ctx.space.free_names)
              for r in ctx.run.evaluation_log().read().evaluations.values()}
    assert all(tuple(row) in logged for row in theta.tolist())
    off = np.full((1, ctx.space.dim), 0.123)  # a point the log does not hold: mapped back
    np.testing.assert_array_equal(logged_rows(ctx, off), ctx.space.from_unit(off))
    ids = ctx.problem.train_ids
    fresh = ctx.runner.simulate(theta, ids)
    reuse = ctx.problem.runner()
    reuse.cache = ctx.run.forward_cache("posterior", tmp_path, earlier=ctx.calibration_runs)
    kept = reuse.simulate(theta, ids)
    # the local search's best is the one GP point whose curves the calibration did not keep
    assert reuse.forward_runs_made == len(ids)
    for cid in ids:
        for name in ("time_s", "force_kN", "gap_mm", "displacement_mm"):
            np.testing.assert_array_equal(getattr(kept[cid], name), getattr(fresh[cid], name))


def test_a_calibration_whose_runs_are_all_of_another_model_is_named(run_dir: Path, tmp_path: Path) -> None:
    """Only where the calibration kept runs of other models alone does the stage warn that
    none is reused: beside runs of the present model, older ones are no reason to."""
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, ignore=shutil.ignore_patterns("posterior"))
    folder = copy / "forward_cache"
    own = sorted(folder.glob("*.jsonl"))
    assert len(own) == 1 and load_run(copy).stale_calibration_runs is None
    (folder / "0123456789abcdef.jsonl").write_text("")
    assert load_run(copy).stale_calibration_runs is None
    for path in folder.glob(f"{own[0].stem}*"):
        path.unlink()
    note = load_run(copy).stale_calibration_runs
    assert note is not None and "the package, its model code or the run's model changed" in note


def _gp_points_of_the_local_search(run: Path) -> tuple[int, bool]:
    """How many of the calibration GP's points are evaluations of a local search, and whether
    the best point is one (every evaluation of the calibration succeeded)."""
    from smcbayes.surrogate.polish import is_search

    ctx = load_run(run)
    state = ctx.run.evaluation_log().read()
    assert all(r["status"] == "ok" for r in state.evaluations.values())
    names = ctx.space.free_names
    gp, _ = load_surrogate(ctx.run.gp_path)
    rows = [[r["params"][n] for n in names] for r in state.evaluations.values()]
    logged = [(ctx.space.to_unit(np.array([row]))[0], is_search(state, r["round"]), row)
              for row, r in zip(rows, state.evaluations.values(), strict=True)]
    searched = sum(next(s for u, s, _ in logged if np.max(np.abs(u - x)) <= 1e-9) for x in gp.x_unit)
    best = ctx.best_theta[0].tolist()
    return searched, any(s and row == best for _, s, row in logged)


def test_the_curve_emulator_path(run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``emulator = "curves"``: the truth inside the 90 % intervals, the slip pair's
    correlation sign right, the runs counted and logged, and a rerun with the same settings
    simulating nothing (every curve batch is seeded and kept in the stage's cache)."""
    import smcbayes.posterior.curve_sample as curve_sample
    import smcbayes.posterior.curve_spread as curve_spread
    from smcbayes.posterior.stage import PosteriorSettings, run_posterior

    # a small budget: the importance sampling's algorithm has its own tests
    monkeypatch.setattr(curve_sample, "EMULATOR_DRAWS", 8000)
    monkeypatch.setattr(curve_sample, "FINAL_ITERATION", 2000)
    monkeypatch.setattr(curve_round, "ROUND_DRAWS", 4000)
    monkeypatch.setattr(curve_sample, "EMULATOR_ITERATION", 2000)
    settings = PosteriorSettings(emulator="curves", walkers=16, steps=1500, refine=120, draws=20,
                                 correct_draws=0, seed=1)
    folder = _fresh_copy(run_dir, tmp_path / "curves")
    info = run_posterior(folder, settings)
    _truth_inside_and_slip_pair_positive(info)
    active = info["active_learning"]
    assert active["kind"] == "curves" and info["emulator_spread"]["pooled"]
    assert active["validated_rounds"] == 3 and active["bounds"]["spread"] == SPREAD_MAX
    assert (folder / "posterior" / "figures" / "learning.png").is_file()
    functions = curve_spread.CURVE_FUNCTIONS * curve_spread.SPREAD_SUPPORTS
    assert info["emulator_spread"]["functions"] == functions
    assert len(info["emulator_spread"]["function_ess"]) == functions
    assert 0.0 <= info["emulator_spread"]["pooled_shift"] < 1.0
    spent = active["evaluations"] - active["start_runs"]
    assert 0 < spent <= 120
    # the calibration kept the curves of the GP's points but the local searches' bests; the
    # best point's run is the sensitivities' (2 d + 1 rows), counted there only
    searched, best_searched = _gp_points_of_the_local_search(folder)
    assert active["start_runs_from_calibration"] == active["start_points"]["calibration_gp"] - searched
    assert active["start_runs"] == searched - best_searched
    assert info["forward_evaluations"]["residual_budget"] == 5 - (not best_searched)
    assert info["forward_evaluations"]["inference"] == active["evaluations"] + 5 - (not best_searched)
    log = [json.loads(line) for line in (folder / "posterior" / "refine.jsonl").read_text().splitlines()]
    assert len(log) == active["rounds"] and log[-1]["forward_runs"] == spent
    # a quarter of each round's 40 runs explore, the rest are draws of the emulated posterior
    assert [rec["posterior_points"] for rec in log] == [30] * active["rounds"]
    # three rounds: the first has no earlier emulator to compare with, so the three rounds
    # a validation needs cannot all be compared, and the stage says so
    assert active["rounds"] == 3 and not active["converged"] and log[0]["quantile_shift"] is None
    assert not info["reliable"]
    assert any("not measured" in r and "active learning" in r for r in info["reliability"]["reasons"])
    again = run_posterior(folder, settings)
    assert again["forward_runs_made"] == 0 and again["parameters"] == info["parameters"]
