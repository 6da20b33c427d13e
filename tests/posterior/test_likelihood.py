"""Effective points, the NumPy GP copy and the emcee driver."""

from __future__ import annotations

import logging
import warnings
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from smcbayes import progress
from smcbayes.errors import ConvergenceWarning, UnreliablePosteriorWarning
from smcbayes.posterior.active import REFIT_GROWTH, fit_local, principal_axes, update_gp
from smcbayes.posterior.emulator import NumpyGP
from smcbayes.posterior.likelihood import (
    CAP_FLOOR_NATS,
    PLATEAU_MARGIN_NATS,
    PLATEAU_MASS,
    PLATEAU_SLOPE,
    EmulatedPosterior,
    cap_nats,
    effective_points,
    integrated_autocorr_time,
    sandwich_points,
)
from smcbayes.posterior.sampler import Chains, SamplerSettings, run_ensemble
from smcbayes.posterior.summary import ParameterSummary, warnings_for
from smcbayes.surrogate.gp import (
    condition_surrogate,
    fit_surrogate,
    load_surrogate,
    matched_axes,
    save_surrogate,
)


def ar1(phi: float, n: int, rng: np.random.Generator) -> np.ndarray:
    x = np.zeros(n)
    e = rng.standard_normal(n)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.8])
def test_autocorrelation_time_of_ar1(phi: float) -> None:
    # integrated autocorrelation time of AR(1) is (1 + phi) / (1 - phi)
    rng = np.random.default_rng(1)
    taus = [integrated_autocorr_time(ar1(phi, 4000, rng)) for _ in range(5)]
    expected = (1 + phi) / (1 - phi)
    assert np.mean(taus) == pytest.approx(expected, rel=0.2)


def test_effective_points_count_independent_samples() -> None:
    rng = np.random.default_rng(2)
    white, smooth = rng.standard_normal(1000), ar1(0.9, 1000, rng)
    tau, n_eff = effective_points([white, smooth])
    assert n_eff[0] > 5 * n_eff[1]
    assert n_eff[0] == pytest.approx(1000 / tau[0])


DURATIONS_S = (10.7, 2.96, 4.62)


def press_noise_factors() -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Per closing: sample times ``(M,)``, noise covariance ``(M, M)``, its Cholesky factor
    and the loss grid ``(400,)``.

    The force errors are white (5 kN) plus Ornstein-Uhlenbeck (3 kN, 0.5 s) noise sampled
    every 0.02 s; the loss reads the measured curve on 400 points per closing.  The 1.1 mm/s
    closing lasts only about six correlation times of the drift.
    """
    out = []
    for duration_s in DURATIONS_S:
        t = np.append(np.arange(0.0, duration_s, 0.02), duration_s)
        cov = 9.0 * np.exp(-np.abs(t[:, None] - t[None, :]) / 0.5) + 25.0 * np.eye(t.size)
        out.append((t, cov, np.linalg.cholesky(cov), np.linspace(0.0, duration_s, 400)))
    return out


def sensitivity(x: np.ndarray) -> np.ndarray:
    """Force sensitivities of three parameters along a closing (x = t / duration), ``(N, 3)``:
    an offset, a ramp and one acting only near the end of the closing."""
    return np.column_stack([np.ones_like(x), x, x**4])


def test_sandwich_points_of_white_residuals_count_every_point() -> None:
    # the loss averages each curve's MSE, so with white residuals a point of a short curve
    # weighs more: with the same sensitivities on every curve N_eff = K^2 / sum_k (1/N_k),
    # which is sum_k N_k for curves of equal length
    rng = np.random.default_rng(4)
    for lengths in ((400, 400, 400), (400, 250, 400)):
        grids = [np.linspace(0.0, 1.0, n) for n in lengths]
        exact = len(lengths) ** 2 / sum(1.0 / n for n in lengths)
        ratios = [sandwich_points([rng.standard_normal(g.size) for g in grids],
                                  [sensitivity(g) for g in grids])
                  / exact for _ in range(100)]
        assert np.median(ratios) == pytest.approx(1.0, abs=0.06)


def test_sandwich_points_match_the_information_of_short_correlated_records() -> None:
    # exact: the scalar N_eff whose pseudo-likelihood curvature N_eff A / (K L) matches the
    # generalised-least-squares information F = S' C^-1 S of the raw samples on average,
    # N_eff = K L tr(A^-1 F) / d
    rng = np.random.default_rng(3)
    factors = press_noise_factors()
    info = sum(sensitivity(t / t[-1]).T @ np.linalg.solve(cov, sensitivity(t / t[-1]))
               for t, cov, _, _ in factors)
    a = sum(sensitivity(g / g[-1]).T @ sensitivity(g / g[-1]) / g.size for _, _, _, g in factors)
    sandwich, about_zero, centred = [], [], []
    for _ in range(60):
        res = [np.interp(g, t, chol @ rng.standard_normal(t.size)) for t, _, chol, g in factors]
        sens = [sensitivity(g / g[-1]) for _, _, _, g in factors]
        loss = np.mean([np.mean(r * r) for r in res])
        exact = len(factors) * loss * np.trace(np.linalg.solve(a, info)) / 3
        sandwich.append(sandwich_points(res, sens) / exact)
        about_zero.append(effective_points(res, centred=False)[1].sum() / exact)
        centred.append(effective_points(res)[1].sum() / exact)
    assert 0.6 < np.median(sandwich) < 1.25
    assert 0.75 < np.median(about_zero) < 1.35
    # centring removes the drift's low-frequency power a short record carries in its mean:
    # N_eff overstated, the posterior too narrow
    assert np.median(centred) > 1.4


@pytest.fixture(scope="module")
def surrogates() -> dict:
    rng = np.random.default_rng(0)
    x = rng.random((40, 3))
    y = np.log(1 + ((x - 0.4) ** 2).sum(1) * 50) + 1e-3 * rng.standard_normal(40)
    rotation = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    out = {k: fit_surrogate(x, y, k, 0) for k in ("rbf", "matern52")}
    out.update({f"{k}-rotated": fit_surrogate(x, y, k, 0, rotation=rotation) for k in ("rbf", "matern52")})
    return out


KINDS = ["rbf", "matern52", "rbf-rotated", "matern52-rotated"]


@pytest.mark.parametrize("kernel", KINDS)
def test_numpy_gp_equals_botorch(surrogates: dict, kernel: str) -> None:
    s = surrogates[kernel]
    g = NumpyGP.from_surrogate(s)
    u = np.random.default_rng(3).random((50, 3))
    mean, std = s.predict(u)
    np.testing.assert_allclose(g.mean(u), mean, atol=1e-7)
    np.testing.assert_allclose(g.std(u), std, rtol=1e-5)
    fast_mean, fast_std = g.predict(u)
    np.testing.assert_array_equal(fast_mean, g.mean(u))
    np.testing.assert_array_equal(fast_std, g.std(u))


@pytest.mark.parametrize("kernel", KINDS)
def test_sample_functions_have_posterior_moments(surrogates: dict, kernel: str) -> None:
    s = surrogates[kernel]
    g = NumpyGP.from_surrogate(s)
    u = np.array([[0.9, 0.9, 0.1], [0.4, 0.4, 0.4]])
    paths = g.sample_functions(300, np.random.default_rng(4), features=1024)
    values = np.stack([paths(u, i) for i in range(paths.count)])
    mean, std = s.predict(u)
    assert np.all(np.abs(values.mean(0) - mean) < 4 * std / np.sqrt(300) + 1e-6)
    np.testing.assert_allclose(values.std(0), std, rtol=0.2)


def test_rotated_surrogate_survives_save_and_load(surrogates: dict, tmp_path: Path) -> None:
    s = surrogates["matern52-rotated"]
    save_surrogate(tmp_path / "gp.pt", s, {})
    back, _ = load_surrogate(tmp_path / "gp.pt")
    np.testing.assert_array_equal(back.rotation, s.rotation)
    u = np.random.default_rng(5).random((20, 3))
    np.testing.assert_allclose(back.predict(u)[0], s.predict(u)[0], atol=1e-10)


@pytest.mark.parametrize("kernel", ["rbf", "matern52-rotated"])
def test_conditioned_gp_keeps_its_hyperparameters_and_learns_the_new_points(surrogates: dict,
                                                                             kernel: str) -> None:
    s = surrogates[kernel]
    rng = np.random.default_rng(8)
    x_new = rng.random((15, 3))
    x = np.vstack([s.x_unit, x_new])
    y = np.concatenate([s.log_loss, np.log(1 + ((x_new - 0.4) ** 2).sum(1) * 50)])
    c = condition_surrogate(s, x, y)
    # hyperparameters and the standardisation they are expressed in: the same GP in log-loss units
    for k, v in s.model.state_dict().items():
        np.testing.assert_array_equal(c.model.state_dict()[k].numpy(), v.numpy())
    assert (c.rotation is None) == (s.rotation is None)
    if s.rotation is not None:
        np.testing.assert_array_equal(c.rotation, s.rotation)
    assert np.abs(c.predict(x_new)[0] - y[-15:]).max() < 0.4 * np.abs(s.predict(x_new)[0] - y[-15:]).max()
    # what the NumPy emulator and the refined GP's file see is the same conditioned GP
    np.testing.assert_allclose(NumpyGP.from_surrogate(c).mean(x_new), c.predict(x_new)[0], atol=1e-7)


def test_fit_starts_from_the_given_gp(surrogates: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    import smcbayes.surrogate.gp as gp_module

    monkeypatch.setattr(gp_module, "fit_gpytorch_mll", lambda mll: None)  # where the fit starts

    def lengthscales(g: object) -> np.ndarray:
        return g.model.covar_module.lengthscale.detach().numpy().ravel()

    s = surrogates["matern52-rotated"]
    warm = fit_surrogate(s.x_unit, s.log_loss, "matern52", 0, rotation=s.rotation, start=s)
    np.testing.assert_array_equal(lengthscales(warm), lengthscales(s))
    # the same axes in another order carry their lengthscales with them
    order = np.array([2, 0, 1])
    turned = fit_surrogate(s.x_unit, s.log_loss, "matern52", 0, rotation=s.rotation[:, order], start=s)
    np.testing.assert_array_equal(lengthscales(turned), lengthscales(s)[order])
    cold = fit_surrogate(s.x_unit, s.log_loss, "matern52", 0, rotation=s.rotation)
    assert not np.allclose(lengthscales(cold), lengthscales(s))
    # another kernel, or axes turned by 45 degrees, start cold
    half = np.sqrt(0.5)
    turn = s.rotation @ np.array([[half, -half, 0.0], [half, half, 0.0], [0.0, 0.0, 1.0]])
    assert matched_axes(s.rotation, turn, 3) is None
    for kernel, rotation in (("rbf", s.rotation), ("matern52", turn)):
        other = fit_surrogate(s.x_unit, s.log_loss, kernel, 0, rotation=rotation, start=s)
        np.testing.assert_array_equal(lengthscales(other), lengthscales(cold))
    np.testing.assert_array_equal(matched_axes(None, np.eye(2)[:, ::-1], 2), [1, 0])


def test_update_gp_refits_only_after_the_data_grew() -> None:
    rng = np.random.default_rng(9)
    x = rng.random((50, 2))
    y = np.log(1 + ((x - 0.5) ** 2).sum(1) * 20) + np.sin(8 * x[:, 0])
    # N_eff 2: the cap lies above every target, so the conditioned GP interpolates them all
    first = fit_local(x[:40], y[:40], 2.0, "matern52", 0)
    same, at = update_gp(first, x[:49], y[:49], 2.0, 1, x, fitted_at=40)
    assert at == 40 and same.x_unit.shape == (49, 2) and same.rotation is None
    assert same.model.covar_module.lengthscale.tolist() == first.model.covar_module.lengthscale.tolist()
    new_err = np.abs(same.predict(x[40:49])[0] - y[40:49]).max()
    assert new_err < 0.2 * np.abs(first.predict(x[40:49])[0] - y[40:49]).max()
    refit, at = update_gp(first, x, y, 2.0, 1, x, fitted_at=40)
    assert at == 50 == int(REFIT_GROWTH * 40) and refit.rotation is not None
    assert update_gp(first, x[:41], y[:41], 2.0, 1, x, fitted_at=0)[1] == 41
    first.fitted = False
    assert update_gp(first, x[:41], y[:41], 2.0, 1, x, fitted_at=40)[1] == 41


def test_inputs_rotated_onto_a_ridge_extrapolate_along_it() -> None:
    # log-loss with a narrow valley along x0 = x1, trained on its lower half only: along the
    # cube's axes the valley needs short lengthscales in both and the GP cannot follow it
    # into the upper half; on the draws' principal axes one lengthscale runs along it
    rng = np.random.default_rng(6)

    def f(u: np.ndarray) -> np.ndarray:
        return ((u[:, 0] - u[:, 1]) / 0.05) ** 2 + 0.5 * (u[:, 0] + u[:, 1])

    along = rng.uniform(0.0, 0.5, 60)
    x = np.column_stack([along, along]) + rng.normal(0, 0.04, (60, 2))
    draws = np.column_stack([along, along]) + rng.normal(0, 0.02, (60, 2))
    test = np.column_stack([np.linspace(0.6, 0.9, 10)] * 2)
    plain = fit_local(x, f(x), 8.0, "matern52", 0)
    rotated = fit_local(x, f(x), 8.0, "matern52", 0, draws)
    assert principal_axes(draws) is not None and principal_axes(draws[:3]) is None
    err_plain = np.abs(plain.predict(test)[0] - f(test)).mean()
    err_rotated = np.abs(rotated.predict(test)[0] - f(test)).mean()
    assert err_rotated < 0.5 * err_plain


def test_principal_axes_are_signed_and_absent_in_one_dimension(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(7)
    draws = rng.multivariate_normal([0.5, 0.5, 0.5], [[1, 0.9, 0], [0.9, 1, 0], [0, 0, 0.2]], 200) * 0.05
    axes = principal_axes(draws)
    np.testing.assert_allclose(axes.T @ axes, np.eye(3), atol=1e-12)
    lead = axes[np.argmax(np.abs(axes), axis=0), np.arange(3)]
    assert np.all(lead > 0)
    # the columns do not depend on the signs the eigensolver happens to return
    eigh = np.linalg.eigh

    def flipped(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        values, vectors = eigh(a)
        return values, vectors * np.array([-1.0, 1.0, -1.0])

    monkeypatch.setattr(np.linalg, "eigh", flipped)
    np.testing.assert_allclose(principal_axes(draws), axes, atol=1e-12)
    assert principal_axes(draws[:, :1]) is None


@pytest.mark.parametrize("moves", ["de", "stretch"])
def test_sampler_recovers_a_gaussian(moves: str) -> None:
    centre, sd = np.array([0.3, 0.6]), np.array([0.05, 0.1])

    def log_prob(u: np.ndarray) -> np.ndarray:
        inside = np.all((u >= 0) & (u <= 1), axis=1)
        lp = -0.5 * np.sum(((u - centre) / sd) ** 2, axis=1)
        return np.where(inside, lp, -np.inf)

    chains = run_ensemble(log_prob, 2,
                          SamplerSettings(walkers=16, max_steps=3000, min_steps=500, moves=moves),
                          np.random.default_rng(5))
    flat = chains.samples.reshape(-1, 2)
    np.testing.assert_allclose(flat.mean(0), centre, atol=0.02)
    np.testing.assert_allclose(flat.std(0), sd, rtol=0.15)
    assert 0.2 < np.median(chains.acceptance) < 0.9


@pytest.mark.parametrize("moves", ["de", "stretch"])
def test_same_seed_same_chains(moves: str) -> None:
    def log_prob(u: np.ndarray) -> np.ndarray:
        return -0.5 * np.sum(((u - 0.5) / 0.1) ** 2, axis=1)

    s = SamplerSettings(walkers=8, max_steps=600, min_steps=600, moves=moves)
    a = run_ensemble(log_prob, 2, s, np.random.default_rng(9))
    b = run_ensemble(log_prob, 2, s, np.random.default_rng(9))
    np.testing.assert_array_equal(a.samples, b.samples)


def test_the_walkers_go_on_from_the_positions_given_and_leave_their_last() -> None:
    """Walkers started at given positions stay near them for a step (differential
    evolution moves along their differences), the chains keep where they stopped, the same
    seed gives the same chains, and a start of the wrong shape or with two walkers at one
    point is refused."""
    def log_prob(u: np.ndarray) -> np.ndarray:
        return -0.5 * np.sum(((u - 0.3) / 0.1) ** 2, axis=1)

    at = 0.9 + 0.01 * np.random.default_rng(4).standard_normal((8, 2))
    one = SamplerSettings(walkers=8, max_steps=1, min_steps=2, check_every=1)
    chains = run_ensemble(log_prob, 2, one, np.random.default_rng(5), start=at)
    assert chains.last is not None and chains.last.shape == (8, 2)
    np.testing.assert_array_equal(chains.last, chains.samples[-1])
    assert np.all(np.abs(chains.last - 0.9) < 0.06)
    longer = SamplerSettings(walkers=8, max_steps=2000, min_steps=500)
    on = run_ensemble(log_prob, 2, longer, np.random.default_rng(6), start=chains.last)
    np.testing.assert_allclose(on.samples.reshape(-1, 2).mean(0), 0.3, atol=0.03)
    again = run_ensemble(log_prob, 2, longer, np.random.default_rng(6), start=chains.last)
    np.testing.assert_array_equal(on.samples, again.samples)
    with pytest.raises(ValueError, match=r"shape \(7, 2\), not \(8, 2\)"):
        run_ensemble(log_prob, 2, one, np.random.default_rng(5), start=at[:7])
    with pytest.raises(ValueError, match="repeats a position"):
        run_ensemble(log_prob, 2, one, np.random.default_rng(5), start=np.vstack([at[:7], at[:1]]))


def test_sampler_rejects_unknown_moves() -> None:
    with pytest.raises(ValueError, match="unknown emcee moves 'walk'"):
        SamplerSettings(moves="walk")  # type: ignore[arg-type]


def test_likelihood_is_minus_half_n_eff_log_loss(surrogates: dict) -> None:
    post = EmulatedPosterior(surrogates["rbf"], n_eff=40.0, functions=0)
    u = np.array([[0.4, 0.4, 0.4], [0.9, 0.1, 0.5], [1.2, 0.5, 0.5]])
    lp = post.log_prob_fn(None)(u)
    np.testing.assert_allclose(lp[:2], -20.0 * surrogates["rbf"].predict(u[:2])[0], atol=1e-5)
    assert lp[2] == -np.inf  # outside the prior box


def test_cap_keeps_a_gaussian_posterior_off_the_plateau() -> None:
    # a Gaussian posterior's log density falls by chi^2_d / 2; the plateau starts beyond
    # the drop that holds all but PLATEAU_MASS of it, and never closer than the floor
    rng = np.random.default_rng(4)
    for dim in (2, 5, 8, 12):
        start = cap_nats(dim) - PLATEAU_MARGIN_NATS
        drop = 0.5 * np.sum(rng.standard_normal((200_000, dim)) ** 2, axis=1)
        assert np.mean(drop > start) <= PLATEAU_MASS * 1.2
        assert cap_nats(dim) >= CAP_FLOOR_NATS
    assert cap_nats(12) > cap_nats(9) > CAP_FLOOR_NATS == cap_nats(8) == cap_nats(2)


def test_local_gp_targets_are_capped_at_cap_nats() -> None:
    rng = np.random.default_rng(2)
    x = rng.random((40, 2))
    y = np.log(1 + ((x - 0.5) ** 2).sum(1) * 20)
    n_eff = 20.0  # a = 10: the cap lies cap_nats(2) / 10 above the best target
    cap = y.min() + cap_nats(2) / 10.0
    assert np.any(y > cap)
    for gp in (fit_local(x, y, n_eff, "matern52", 0),
               update_gp(fit_local(x[:35], y[:35], n_eff, "matern52", 0), x, y, n_eff, 1, x, 35)[0]):
        np.testing.assert_allclose(gp.log_loss, np.minimum(y, cap))


def test_capped_emulator_gives_its_plateau_no_density(surrogates: dict) -> None:
    """Below the plateau's start the log density is -(N_eff/2) times the GP mean; beyond it,
    it falls by PLATEAU_SLOPE per nat more."""
    gp = surrogates["rbf"]
    a, cap = 20.0, 6.0
    plain = EmulatedPosterior(gp, n_eff=2 * a, functions=0).log_prob_fn(None)
    capped = EmulatedPosterior(gp, n_eff=2 * a, functions=0, cap_nats=cap).log_prob_fn(None)
    u = np.random.default_rng(5).random((400, 3))
    nats = a * (gp.predict(u)[0] - np.min(gp.log_loss))
    excess = nats - (cap - PLATEAU_MARGIN_NATS)
    near, far = excess <= 0, excess > 0
    assert near.sum() > 5 and far.sum() > 5
    np.testing.assert_allclose(capped(u)[near], plain(u)[near], rtol=1e-10)
    np.testing.assert_allclose(capped(u)[far], plain(u)[far] - PLATEAU_SLOPE * excess[far], rtol=1e-8)


def test_sampler_reports_progress_through_the_logger_not_stderr(capsys, caplog) -> None:
    def log_prob(u: np.ndarray) -> np.ndarray:
        return -0.5 * np.sum(((u - 0.5) / 0.1) ** 2, axis=1)

    progress.enable(True, interval_s=0.0)
    try:
        with caplog.at_level(logging.INFO):
            run_ensemble(log_prob, 2, SamplerSettings(walkers=8, max_steps=500, min_steps=250,
                                                      check_every=250), np.random.default_rng(2),
                         label=" (component 1/1)")
    finally:
        progress.enable(False)
    assert capsys.readouterr().err == ""
    lines = [r.getMessage() for r in caplog.records if r.name == "smcbayes.progress"]
    assert [ln.split("  ")[0] for ln in lines] == ["sampling (component 1/1): 250/500 step",
                                                   "sampling (component 1/1): 500/500 step"]
    assert "tau ~" in lines[-1]


def test_sampler_warnings_are_recorded_and_emitted_once_by_class() -> None:
    bad = ParameterSummary("eta0", "Pa s", 1.0, 0.1, 0.9, 1.0, 1.1, r_hat=1.3, ess=50.0)
    good = ParameterSummary("n", "-", 0.5, 0.1, 0.4, 0.5, 0.6, r_hat=1.0, ess=1000.0)
    chains = [Chains(np.zeros((10, 4, 2)), np.zeros((10, 4)), np.full(4, 0.95), np.ones(2), 100, 10, 1,
                     converged=False)]
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        text = warnings_for([bad, good], chains, prefix="emulator chains: ")
    assert [str(w.message) for w in seen] == text and len(text) == 4
    assert all(t.startswith("emulator chains: ") for t in text)
    assert [w.category for w in seen] == [ConvergenceWarning, UnreliablePosteriorWarning,
                                          ConvergenceWarning, ConvergenceWarning]
    assert seen[0].filename == __file__
    assert warnings_for([good], [replace(chains[0], acceptance=np.full(4, 0.3), converged=True)]) == []
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        assert warnings_for([bad], chains, warn=False)
    assert not seen


def test_chains_that_only_started_a_settled_importance_sample_give_notes_not_warnings() -> None:
    """The proposal's chains: warnings while the weights have not settled, notes once they
    have (the reported numbers are the weights'), never raised; the reported chains' own
    warnings are raised."""
    from smcbayes.posterior.report import _chain_warnings

    bad = ParameterSummary("eta0", "Pa s", 1.0, 0.1, 0.9, 1.0, 1.1, r_hat=1.3, ess=5000.0)
    chains = [Chains(np.zeros((10, 4, 2)), np.zeros((10, 4)), np.full(4, 0.3), np.ones(2), 100, 10, 1,
                     converged=False)]
    for target, of in (("emulator", "the importance sampling on the emulator"),
                       ("forward model", "the correction")):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            settled = _chain_warnings([bad], chains, SimpleNamespace(target=target, settled=True))
            unsettled = _chain_warnings([bad], chains, SimpleNamespace(target=target, settled=False))
        assert not seen
        assert settled[0] == [] and unsettled[1] == [] and settled[1] == unsettled[0]
        assert len(settled[1]) == 2 and all(n.startswith(f"emulator chains (proposal of {of}): ")
                                            for n in settled[1])
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        raised = _chain_warnings([bad], chains, None)
    assert raised[1] == [] and [str(w.message) for w in seen] == raised[0] and len(raised[0]) == 2


def test_reliability_names_each_failed_diagnostic() -> None:
    """A posterior is called reliable only when its diagnostics pass; each failure and each
    degenerate case gets its own plain reason."""
    from smcbayes.config import build_project
    from smcbayes.forward.model import ForwardModel
    from smcbayes.posterior.reliability import assess

    raw = {"name": "t", "configuration": [{"id": "a", "charge": {"shape": "bar", "coverage_pct": 60.0},
                                           "press": {"speed_mm_s": 0.5}}]}
    space = ForwardModel(build_project(raw, "<t>", Path("."))).space
    narrow = [{"name": p.name, "q05": p.lower + 0.4 * (p.upper - p.lower),
               "q95": p.lower + 0.5 * (p.upper - p.lower), "r_hat": 1.01} for p in space.free]
    wide = [{"name": p.name, "q05": p.lower, "q95": p.upper, "r_hat": 1.01} for p in space.free]
    good = {"parameters": narrow, "correction": {"enabled": True, "k_hat": 0.2, "ess": 2500, "settled": True}}
    assert assess(good, space, 10.0) == {"reliable": True, "reasons": [], "notes": []}
    bad_k = {**good, "correction": {"enabled": True, "k_hat": 0.9, "ess": 20, "settled": False}}
    assert "k-hat 0.90" in assess(bad_k, space, 10.0)["reasons"][0]
    # a correction short of its ESS says how many draws would settle it, or that more would not
    short = {"enabled": True, "k_hat": 0.4, "ess": 400.0, "settled": False, "ess_target": 2000.0,
             "draws_needed": 72000, "history": [{"draws": 500}] * 28}
    reason = assess({**good, "correction": short}, space, 10.0)["reasons"][0]
    assert "ESS 400 of 2000" in reason and "--correct-draws 72000" in reason
    flat = assess({**good, "correction": {**short, "draws_needed": None}}, space, 10.0)["reasons"][0]
    assert "grew too little" in flat and "--refine" in flat
    older = {k: v for k, v in short.items() if k not in ("ess_target", "draws_needed")}
    plain = "(ESS 400); raise --correct-draws"
    assert assess({**good, "correction": older}, space, 10.0)["reasons"][0].endswith(plain)
    # an infinite target is written as null: no "of", the plain remedy
    endless = {**short, "ess_target": None, "draws_needed": None}
    assert assess({**good, "correction": endless}, space, 10.0)["reasons"][0].endswith(plain)
    emulator_only = {"parameters": [{**r, "r_hat": 1.2} for r in narrow],
                     "emulator_check": {"mean_abs_error": 3.0}}
    reasons = assess(emulator_only, space, 10.0)["reasons"]
    assert len(reasons) == 2 and "R-hat 1.20" in reasons[0] and "3 nats" in reasons[1]
    # just past the bound, the check is not printed as the bound itself
    just = {"parameters": narrow, "emulator_check": {"mean_abs_error": 1.02}}
    assert "1.0200 nats off" in assess(just, space, 10.0)["reasons"][0]
    assert "is the prior" in assess({**good, "parameters": wide}, space, 10.0)["reasons"][0]
    assert "noise-free" in assess(good, space, 1e-12)["reasons"][0]
    converged = {"parameters": narrow, "emulator_check": {"mean_abs_error": 0.4}}
    assert assess(converged, space, 10.0)["reliable"]
    # a reliable emulated posterior of a cheap simulator says how to compare it with the exact one,
    # not one that the correction shaped, nor one that is unreliable anyway
    assert "--correct-draws" in assess(converged, space, 10.0, cheap=True)["notes"][-1]
    # the curve emulator's own importance sample is no correction by the forward model
    sampled = {**converged, "correction": {"enabled": True, "target": "emulator", "k_hat": 0.2, "ess": 5000,
                                           "settled": True}, "forward_evaluations": {"correction": 0}}
    assert "--correct-draws" in assess(sampled, space, 10.0, cheap=True)["notes"][-1]
    corrected = {**good, "forward_evaluations": {"correction": 9000}}
    assert assess(corrected, space, 10.0, cheap=True)["notes"] == []
    assert assess(emulator_only, space, 10.0, cheap=True)["notes"] == []
    spread = {"max_quantile_shift": 0.25, "per_parameter": {"n": 0.05, "m": 0.25}}
    reasons = assess({**converged, "emulator_spread": spread}, space, 10.0)["reasons"]
    assert (len(reasons) == 1 and "quantile of m moves by 0.25" in reasons[0]
            and "raise --refine" in reasons[0])
    validated = {**converged, "emulator_spread": spread,
                 "active_learning": {"enabled": True, "converged": True}}
    reasons = assess(validated, space, 10.0)["reasons"]
    assert len(reasons) == 1 and "--refine" not in reasons[0] and "--correct-draws" in reasons[0]
    small = {"max_quantile_shift": 0.08, "per_parameter": {"n": 0.08, "m": 0.01}}
    assert assess({**converged, "emulator_spread": small}, space, 10.0)["reliable"]
    # a budget spent on validated rounds whose spread stayed large names the spread
    spent = {"enabled": True, "converged": False, "evaluations": 800, "error_nats": 0.4,
             "quantile_shift": 0.02, "spread": 0.3, "spread_checks": 4}
    reason = assess({**converged, "active_learning": spent}, space, 10.0)["reasons"][0]
    assert ("GP sample functions still moved" in reason and "0.3 of its range" in reason
            and "4 measurement" in reason)
    unvalidated = {**spent, "error_nats": 2.5, "spread": None, "spread_checks": 0}
    reason = assess({**converged, "active_learning": unvalidated}, space, 10.0)["reasons"][0]
    assert "before the emulator was validated" in reason and "2.5 nats" in reason


def test_reliability_reads_the_chains_r_hat_from_their_own_table() -> None:
    """An importance-weighted table has no R-hat (null in ``summary.json``): the chains'
    is read from ``emulator_parameters``, and every verdict is the one given when the table
    carried the chains' R-hat."""
    from smcbayes.config import build_project
    from smcbayes.forward.model import ForwardModel
    from smcbayes.posterior.reliability import assess

    raw = {"name": "t", "configuration": [{"id": "a", "charge": {"shape": "bar", "coverage_pct": 60.0},
                                           "press": {"speed_mm_s": 0.5}}]}
    space = ForwardModel(build_project(raw, "<t>", Path("."))).space
    rows = [{"name": p.name, "q05": p.lower + 0.4 * (p.upper - p.lower),
             "q95": p.lower + 0.5 * (p.upper - p.lower), "r_hat": 1.2} for p in space.free]
    weighted = [{**r, "r_hat": None} for r in rows]
    check = {"emulator_check": {"mean_abs_error": 0.4}}
    sampled = {"enabled": True, "target": "emulator", "k_hat": 0.2, "ess": 5000, "settled": True}
    forward = {"enabled": True, "target": "forward model", "k_hat": 0.2, "ess": 2500, "settled": True}
    # the chains are the reported posterior: their R-hat is in both tables
    chains_only = {"parameters": rows, "emulator_parameters": rows, **check}
    reasons = assess(chains_only, space, 10.0)["reasons"]
    assert len(reasons) == 1 and "chains did not converge (R-hat 1.20 > 1.05)" in reasons[0]
    # the same chains, their table as read back: still flagged (a null would hide them)
    hidden = {"parameters": weighted, "emulator_parameters": rows, **check}
    assert assess(hidden, space, 10.0) == assess(chains_only, space, 10.0)
    for corr in (sampled, forward, {**forward, "settled": False, "ess_target": 2000.0}):
        before = assess({"parameters": rows, "correction": corr, **check}, space, 10.0)
        now = assess({"parameters": weighted, "emulator_parameters": rows, "correction": corr, **check},
                     space, 10.0)
        assert now == before
    assert assess({"parameters": weighted, "emulator_parameters": rows, "correction": sampled, **check},
                  space, 10.0)["reliable"]


def test_a_spread_just_within_its_bound_by_its_standard_error_is_a_marginal_pass() -> None:
    """A reliable posterior whose spread passes within three standard errors of its bound
    gets a note naming the parameter (the verdict stands); a clear pass, a spread without a
    standard error (one support, or the log-loss emulator's) and a failed spread get none,
    and a failed spread's reason gives its standard error."""
    from smcbayes.config import build_project
    from smcbayes.forward.model import ForwardModel
    from smcbayes.posterior.reliability import assess
    from smcbayes.posterior.spread import spread_words

    raw = {"name": "t", "configuration": [{"id": "a", "charge": {"shape": "bar", "coverage_pct": 60.0},
                                           "press": {"speed_mm_s": 0.5}}]}
    space = ForwardModel(build_project(raw, "<t>", Path("."))).space
    narrow = [{"name": p.name, "q05": p.lower + 0.4 * (p.upper - p.lower),
               "q95": p.lower + 0.5 * (p.upper - p.lower), "r_hat": 1.01} for p in space.free]
    base = {"parameters": narrow, "emulator_check": {"mean_abs_error": 0.4}}

    def notes(shift: float, se: float | None) -> dict:
        spread = {"max_quantile_shift": shift, "max_quantile_shift_se": se, "supports": 12,
                  "per_parameter": {narrow[0]["name"]: shift}}
        return assess({**base, "emulator_spread": spread}, space, 10.0)

    marginal = notes(0.096, 0.006)
    assert marginal["reliable"] and len(marginal["notes"]) == 1
    note = marginal["notes"][0]
    assert note.startswith("a marginal pass") and "0.096" in note and "0.006" in note
    assert f"quantile of {narrow[0]['name']} by" in note
    # three standard errors, not two: 0.085 + 2 x 0.006 is below the bound, + 3 x 0.006 above
    assert len(notes(0.085, 0.006)["notes"]) == 1
    # a spread at the bound passes, by the narrowest margin
    assert notes(0.1, 0.006)["reliable"] and len(notes(0.1, 0.006)["notes"]) == 1
    assert notes(0.080, 0.006)["notes"] == [] and notes(0.096, None)["notes"] == []
    failed = notes(0.104, 0.006)
    assert not failed["reliable"] and failed["notes"] == []
    assert "(> 0.1; standard error 0.006)" in failed["reasons"][0]
    words = spread_words({"max_quantile_shift": 0.0831, "max_quantile_shift_se": 0.0064, "supports": 12,
                          "functions": 384, "shift_level": 0.9})
    assert "at most 0.083 of its range (standard error 0.006 over its 12 supports)" in words
    one = {"max_quantile_shift": 0.0831, "functions": 32, "shift_level": 0.9}
    assert "at most 0.08 of" in spread_words(one)


def test_the_chains_r_hat_is_nan_when_any_parameters_is_missing_in_either_order() -> None:
    """Python's ``max`` skips a NaN after a number but not before it: the chains' largest
    R-hat must not depend on the parameters' order."""
    from smcbayes.posterior.reliability import chains_r_hat

    def info(values: list) -> dict:
        return {"emulator_parameters": [{"r_hat": v} for v in values]}

    assert chains_r_hat(info([1.01, 1.2])) == 1.2
    for values in ([1.2, float("nan")], [float("nan"), 1.2], [None, 1.01], [1.01, None], []):
        assert np.isnan(chains_r_hat(info(values))), values
    # without the chains' own table, the reported one (a chains-only posterior)
    assert chains_r_hat({"parameters": [{"r_hat": 1.03}]}) == 1.03


def test_sample_functions_are_fixed_by_their_seed() -> None:
    """The spread's second measurement relies on it: the same GP and seed give the same
    sample functions, another seed others."""
    rng = np.random.default_rng(3)
    x = rng.uniform(size=(40, 2))
    gp = fit_surrogate(x, np.sin(3 * x[:, 0]) + x[:, 1] ** 2, "matern52", seed=0)
    u = rng.uniform(size=(25, 2))
    first, again, other = (EmulatedPosterior(gp, 50.0, 4, seed) for seed in (11, 11, 12))
    for k in range(4):
        np.testing.assert_array_equal(first.log_prob_fn(k)(u), again.log_prob_fn(k)(u))
    assert not np.allclose(first.log_prob_fn(0)(u), other.log_prob_fn(0)(u))


def test_quantile_shifts_measure_how_far_sample_function_posteriors_move() -> None:
    from smcbayes.posterior.spread import emulator_spread, quantile_shifts

    rng = np.random.default_rng(10)
    reported = rng.uniform(0.2, 0.6, size=(20000, 2))
    same = [rng.uniform(0.2, 0.6, size=(20000, 2)) for _ in range(3)]
    assert quantile_shifts(reported, same).max() < 0.01
    # one function extends the first parameter's upper tail to 0.9: its 95 % quantile moves
    tail = rng.uniform(0.2, 0.9, size=(20000, 2)) * np.array([1.0, 0.0]) + same[0] * np.array([0.0, 1.0])
    shifts = quantile_shifts(reported, [*same, tail])
    np.testing.assert_allclose(shifts, [0.865 - 0.58, 0.0], atol=0.01)
    # the control chain on the GP mean is off by 0.05 in b alone: that much is sampling noise
    control = same[1] + np.array([0.0, 0.05])
    out = emulator_spread(reported, control, [*same, tail], ["a", "b"], steps=300)
    assert out["functions"] == 4 and out["steps"] == 300
    assert out["sampling_noise"]["b"] == pytest.approx(0.05, abs=0.01) and out["per_parameter"]["b"] == 0.0
    assert out["per_parameter"]["a"] == pytest.approx(shifts[0] - out["sampling_noise"]["a"])
    assert out["max_quantile_shift"] == pytest.approx(out["per_parameter"]["a"])
    assert out["max_quantile_shift"] > 0.25
