"""Importance-sampling correction of an emulated posterior on analytic targets."""

from __future__ import annotations

import logging
import warnings

import numpy as np
import pytest
from scipy.stats import multivariate_t

from smcbayes import progress
from smcbayes.errors import ConvergenceWarning, SmcBayesWarning, UnreliablePosteriorWarning
from smcbayes.posterior._blocks import PARALLEL_ROWS
from smcbayes.posterior.centre_chains import CentreChains
from smcbayes.posterior.correct import (
    K_HAT_WARN,
    CorrectionSettings,
    Proposal,
    correct,
    correction_warnings,
    draws_advice,
    draws_for_target,
    ess_of,
    fit_proposal,
    seed_weights,
    temper,
    weighted_moments,
    weighted_quantile,
)

MU = np.array([0.45, 0.3, 0.6])
SD = np.array([0.08, 0.12, 0.06])
R12 = -0.85


def _target() -> tuple[np.ndarray, np.ndarray]:
    cov = np.diag(SD**2)
    cov[1, 2] = cov[2, 1] = R12 * SD[1] * SD[2]
    return cov, np.linalg.inv(cov)


def log_target(u: np.ndarray) -> np.ndarray:
    """Correlated Gaussian well inside the unit cube (truncation negligible)."""
    _, prec = _target()
    z = np.atleast_2d(u) - MU
    return -0.5 * np.einsum("ij,jk,ik->i", z, prec, z)


def biased_start(rng: np.random.Generator) -> np.ndarray:
    """A too narrow, offset and uncorrelated 'emulated posterior'."""
    return rng.normal(MU + np.array([0.1, -0.1, 0.05]), 0.4 * SD, size=(3000, 3))


def test_correction_recovers_exact_moments_from_biased_proposal() -> None:
    rng = np.random.default_rng(0)
    start = biased_start(rng)
    res = correct(log_target, start,
                  CorrectionSettings(draws=1600, per_iteration=400, ess_target=np.inf), rng)
    mean, sd, corr = weighted_moments(res.unit[res.weights > 0], res.weights[res.weights > 0])
    # the uncorrected draws are off by >= 0.05 in the mean and have no correlation ...
    assert np.max(np.abs(start.mean(0) - MU)) > 0.09
    # ... the corrected sample has the exact mean, spread and correlation
    np.testing.assert_allclose(mean, MU, atol=0.02)
    np.testing.assert_allclose(sd, SD, rtol=0.2)
    assert abs(corr[1, 2] - R12) < 0.1
    assert res.k_hat < 0.7 and res.ess > 200
    assert res.evaluations <= 1600
    assert len(res.history) == 4 and res.history[-1]["ess"] > res.history[0]["ess"]
    assert abs(res.weights.sum() - 1.0) < 1e-9


def test_weighted_quantiles_contain_truth_and_match_exact() -> None:
    rng = np.random.default_rng(1)
    res = correct(log_target, biased_start(rng), CorrectionSettings(draws=1600, per_iteration=400), rng)
    w = res.weights
    for j in range(3):
        q05, q50, q95 = weighted_quantile(res.unit[:, j], w, [0.05, 0.5, 0.95])
        assert q05 < MU[j] < q95
        assert abs(q50 - MU[j]) < 0.25 * SD[j]
        assert abs((q95 - q05) - 2 * 1.645 * SD[j]) < 0.25 * 2 * 1.645 * SD[j]


def test_same_seed_same_result_and_failed_runs_get_zero_weight() -> None:
    def flaky(u: np.ndarray) -> np.ndarray:
        out = log_target(u)
        out[u[:, 0] > 0.6] = np.nan  # the forward model "failed" there
        return out

    a = correct(flaky, biased_start(np.random.default_rng(2)),
                CorrectionSettings(draws=400, per_iteration=200),
                np.random.default_rng(3))
    b = correct(flaky, biased_start(np.random.default_rng(2)),
                CorrectionSettings(draws=400, per_iteration=200),
                np.random.default_rng(3))
    np.testing.assert_array_equal(a.unit, b.unit)
    np.testing.assert_array_equal(a.log_weight, b.log_weight)
    assert np.all(a.weights[a.unit[:, 0] > 0.6] == 0.0)
    outside = ~np.all((a.unit >= 0) & (a.unit <= 1), axis=1)
    assert np.all(a.weights[outside] == 0.0)


def test_proposal_density_is_the_defensive_t_mixture() -> None:
    rng = np.random.default_rng(4)
    centre = np.array([[0.5, 0.4]])
    chol = np.linalg.cholesky(np.array([[0.01, 0.004], [0.004, 0.02]]))
    q = Proposal(centre, chol[None], nu=5.0, defensive=0.2)
    u = rng.random((50, 2))
    expected = np.log(0.8 * multivariate_t(centre[0], chol @ chol.T, df=5.0).pdf(u) + 0.2)
    np.testing.assert_allclose(q.log_pdf(u), expected, rtol=1e-10)
    # many points share the kernels out over numba's threads, with the same values
    centres = rng.random((5, 2))
    several = Proposal(centres, np.repeat(chol[None], 5, axis=0) * rng.uniform(0.5, 2.0, (5, 1, 1)), 5.0, 0.2)
    many = rng.random((PARALLEL_ROWS + 33, 2))
    np.testing.assert_array_equal(several.log_pdf(many), np.concatenate([several.log_pdf(many[i:i + 50])
                                                                         for i in range(0, len(many), 50)]))
    x, kernel = q.sample_indexed(20000, rng)
    inside = np.all((x >= 0) & (x <= 1), axis=1)
    # a fifth of the draws from the uniform density, all of them in the cube ...
    uniform = kernel == -1
    assert abs(uniform.mean() - 0.2) < 4 * np.sqrt(0.2 * 0.8 / x.shape[0])
    assert inside[uniform].all() and (kernel[~uniform] == 0).all()
    # ... so the share inside is the uniform share plus the t kernel's mass inside the cube
    t = multivariate_t(centre[0], chol @ chol.T, df=5.0)
    cdf = [t.cdf([a, b], maxpts=200_000, random_state=1) for a, b in ((1, 1), (0, 1), (1, 0), (0, 0))]
    expected = 0.2 + 0.8 * (cdf[0] - cdf[1] - cdf[2] + cdf[3])
    assert abs(inside.mean() - expected) < 4 * np.sqrt(expected * (1 - expected) / x.shape[0]) + 1e-3
    assert abs(np.median(x[:, 0]) - 0.5) < 0.02


def _run_chains(chol_at, steps: int, seed: int) -> np.ndarray:
    """Positions of 50 chains (started far off) moved by their own kernels' draws for
    ``steps`` iterations, the first 100 dropped, ``(50 (steps - 100), 3)``."""
    rng = np.random.default_rng(seed)
    chains = CentreChains(np.tile([0.9, 0.9, 0.1], (50, 1)))
    kept = []
    for step in range(steps):
        q = Proposal(chains.position.copy(), chol_at(chains.position), nu=5.0, defensive=0.1, chol_at=chol_at)
        draws, kernel = q.sample_indexed(120, rng)
        inside = np.all((draws >= 0.0) & (draws <= 1.0), axis=1)
        chains.advance(q, draws, kernel, np.where(inside, log_target(draws), -np.inf), rng)
        if step >= 100:
            kept.append(chains.position.copy())
    return np.concatenate(kept)


def test_chains_moved_by_kernel_draws_sample_the_exact_posterior() -> None:
    """Metropolis with the proposal's own kernel draws leaves the target invariant."""
    cov, _ = _target()
    x = _run_chains(lambda p: np.broadcast_to(np.linalg.cholesky(0.5 * cov), (p.shape[0], 3, 3)), 600, 11)
    np.testing.assert_allclose(x.mean(axis=0), MU, atol=0.01)
    np.testing.assert_allclose(x.std(axis=0), SD, rtol=0.06)
    assert abs(np.corrcoef(x[:, 1], x[:, 2])[0, 1] - R12) < 0.05


def test_chains_with_position_dependent_kernels_keep_the_target() -> None:
    """Kernels 8x wider (in variance) above the mean of u_1 than below: without the Hastings
    term the chains spend about 60 % of their time in the wide half instead of 50 %."""
    cov, _ = _target()
    narrow, wide = np.linalg.cholesky(0.5 * cov), np.linalg.cholesky(4.0 * cov)

    def chol_at(p: np.ndarray) -> np.ndarray:
        return np.where((p[:, 1] > MU[1])[:, None, None], wide, narrow)

    x = _run_chains(chol_at, 800, 12)
    assert abs(np.mean(x[:, 1] > MU[1]) - 0.5) < 0.03
    np.testing.assert_allclose(x.std(axis=0), SD, rtol=0.08)


def test_more_chains_than_points_per_iteration() -> None:
    """100 chains with 50 draws per iteration: the proposals have fewer centres than chains."""
    rng = np.random.default_rng(13)
    res = correct(log_target, biased_start(rng), CorrectionSettings(draws=300, per_iteration=50), rng)
    assert res.evaluations > 0 and np.isfinite(res.ess)


def test_temper_keeps_an_effective_sample() -> None:
    lw = np.array([0.0, -50.0, -60.0, -70.0] + [-80.0] * 96)
    assert ess_of(lw) < 1.01
    t = temper(lw, 20.0)
    assert ess_of(t) >= 20.0 - 1e-6
    assert np.argmax(t) == 0


def test_fit_proposal_covers_a_degenerate_sample() -> None:
    rng = np.random.default_rng(5)
    u = np.tile([[0.3, 0.7]], (10, 1))
    q = fit_proposal(u, None, CorrectionSettings(), rng)
    assert np.all(np.isfinite(q.log_pdf(rng.random((10, 2)))))


def test_the_correction_recovers_from_a_degenerate_start() -> None:
    """Every start draw at one point off the posterior: the first kernels are a sliver, and
    the defensive prior's draws carry the next proposals to the posterior."""
    rng = np.random.default_rng(0)
    start = np.tile(MU + np.array([0.1, -0.1, 0.05]), (3000, 1))
    res = correct(log_target, start,
                  CorrectionSettings(draws=3000, per_iteration=500, ess_target=np.inf), rng)
    mean, sd, _ = weighted_moments(res.unit[res.weights > 0], res.weights[res.weights > 0])
    assert res.history[0]["ess"] < 10 and res.ess > 500 and res.k_hat < 0.5
    np.testing.assert_allclose(mean, MU, atol=0.01)
    np.testing.assert_allclose(sd, SD, rtol=0.05)


def test_a_posterior_pinned_to_a_tiny_share_of_its_range_gets_kernels_of_its_width() -> None:
    """Data can pin a parameter to 1e-4 of its range: the kernels must shrink to that width
    (a floor of the variance far above it made them a hundred times wider) and the weights
    then estimate its spread."""
    mu, sd = np.array([0.4, 0.6]), np.array([0.1, 1e-4])

    def narrow(u: np.ndarray) -> np.ndarray:
        z = (np.atleast_2d(u) - mu) / sd
        return -0.5 * np.sum(z * z, axis=1)

    rng = np.random.default_rng(0)
    start = rng.normal(mu, 1.5 * sd, size=(3000, 2))
    settings = CorrectionSettings(draws=4000, per_iteration=1000, ess_target=np.inf)
    q = fit_proposal(start, None, settings, rng)
    kernel_sd = np.sqrt(np.einsum("kij,kij->ki", q.chol, q.chol))  # (centres, d)
    assert np.all(kernel_sd[:, 1] < 3 * sd[1]) and np.all(kernel_sd[:, 0] > 3e-3)
    res = correct(narrow, start, settings, rng)
    mean, spread, _ = weighted_moments(res.unit[res.weights > 0], res.weights[res.weights > 0])
    np.testing.assert_allclose(spread, sd, rtol=0.1)
    assert abs(mean[1] - mu[1]) < 0.1 * sd[1] and res.ess > 1000


@pytest.mark.parametrize("q", [0.05, 0.5, 0.95])
def test_weighted_quantile_equal_weights(q: float) -> None:
    x = np.random.default_rng(6).standard_normal(4001)
    assert abs(weighted_quantile(x, np.full(x.size, 1 / x.size), [q])[0] - np.quantile(x, q)) < 0.01


def test_stops_early_once_the_weights_are_good() -> None:
    rng = np.random.default_rng(7)
    start = rng.normal(MU, SD, size=(3000, 3))  # a good emulator: little to correct
    res = correct(log_target, start, CorrectionSettings(draws=5000, per_iteration=500, ess_target=300), rng)
    assert len(res.history) < 10 and res.evaluations < 5000
    assert res.ess >= 300 and res.k_hat <= 0.5


def test_local_kernels_follow_the_sample() -> None:
    rng = np.random.default_rng(8)
    res = correct(log_target, biased_start(rng),
                  CorrectionSettings(draws=1600, per_iteration=400, local=True), rng)
    mean = res.weights @ res.unit
    np.testing.assert_allclose(mean, MU, atol=0.03)


def test_known_points_shape_the_first_proposal() -> None:
    rng = np.random.default_rng(9)
    far = rng.normal([0.8, 0.8, 0.2], 0.02, size=(2000, 3))  # an emulator that is plain wrong
    known_x = rng.random((60, 3))
    known = (known_x, log_target(known_x))
    res = correct(log_target, far, CorrectionSettings(draws=2000, per_iteration=500), rng, known)
    np.testing.assert_allclose(res.weights @ res.unit, MU, atol=0.03)
    x, lw = seed_weights(far, known)
    assert x.shape[0] == 2060 and abs(np.exp(lw[2000:]).sum() - 0.5) < 1e-9


def _two_regions(u: np.ndarray) -> np.ndarray:
    """A main region and a thin second one turned another way, holding 5 % of the mass."""
    from scipy.stats import multivariate_normal

    cov2 = np.array([[0.0004, 0.0, 0.0], [0.0, 0.004, 0.0035], [0.0, 0.0035, 0.004]])
    u = np.atleast_2d(u)
    return np.logaddexp(np.log(0.95) + multivariate_normal(MU, _target()[0]).logpdf(u),
                        np.log(0.05) + multivariate_normal([0.8, 0.75, 0.25], cov2).logpdf(u))


def test_second_region_missed_by_the_emulator_gets_its_mass() -> None:
    """Over four seeds (one estimate is noisy: 2-6 % at this budget), the region the emulator
    missed is found every time and its mass is right on average."""
    mass = []
    for seed in (10, 11, 12, 13):
        rng = np.random.default_rng(seed)
        start = rng.normal(MU, SD, size=(3000, 3))  # the emulator saw the main region only
        res = correct(_two_regions, start, CorrectionSettings(draws=6000, per_iteration=500), rng)
        mass.append(res.weights[res.unit[:, 0] > 0.65].sum())
        assert res.k_hat < 0.7
    assert min(mass) > 0.02
    assert abs(np.mean(mass) - 0.05) < 0.01


def test_proposals_follow_the_tempered_posterior_while_estimates_follow_the_exact_one() -> None:
    """With T = 1/2 the proposals follow pi^(1/2), sqrt(2) times wider for a Gaussian than
    with T = 1, while the weighted estimates are those of pi in both cases."""
    spread = {}
    for temp in (1.0, 0.5):
        rng = np.random.default_rng(4)
        settings = CorrectionSettings(draws=4000, per_iteration=500, ess_target=np.inf, chains=0, clusters=1,
                                      fit_temperature=temp)
        res = correct(log_target, biased_start(rng), settings, rng)
        live = res.weights > 0
        mean, sd, corr = weighted_moments(res.unit[live], res.weights[live])
        np.testing.assert_allclose(mean, MU, atol=0.02)
        np.testing.assert_allclose(sd, SD, rtol=0.15)
        assert abs(corr[1, 2] - R12) < 0.1
        # the spread of the last proposals' draws (their uniform quarter is the same for both)
        late = res.unit[res.iteration >= 5]
        q25, q75 = np.quantile(late, [0.25, 0.75], axis=0)
        spread[temp] = q75 - q25
    ratio = spread[0.5] / spread[1.0]
    assert np.all((ratio > 1.2) & (ratio < 1.7)), ratio


def test_fit_temperature_outside_unit_interval_is_refused() -> None:
    from smcbayes.errors import ConfigError

    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(ConfigError, match="fit_temperature"):
            CorrectionSettings(fit_temperature=bad)


def test_unsettled_correction_warns_once_by_class_and_prints_nothing(capsys, caplog) -> None:
    """The weights' warning is recorded on the sample and emitted once, with its class;
    progress goes to the progress logger, nothing to stderr."""
    rng = np.random.default_rng(3)
    progress.enable(True, interval_s=0.0)
    try:
        with warnings.catch_warnings(record=True) as seen, caplog.at_level(logging.INFO):
            warnings.simplefilter("always")
            res = correct(log_target, biased_start(rng),
                          CorrectionSettings(draws=400, per_iteration=200, ess_target=np.inf), rng)
    finally:
        progress.enable(False)
    ours = [w for w in seen if issubclass(w.category, SmcBayesWarning)]
    assert not res.settled and len(ours) == 1 and [str(w.message) for w in ours] == res.warnings
    expected = UnreliablePosteriorWarning if res.k_hat > K_HAT_WARN else ConvergenceWarning
    assert ours[0].category is expected and ours[0].filename == __file__
    assert correction_warnings(res, warn=False) == res.warnings
    assert capsys.readouterr().err == ""
    lines = [r.getMessage() for r in caplog.records if r.name == "smcbayes.progress"]
    assert lines and lines[-1].startswith("importance correction: 400/400 draw")
    assert "forward runs" in lines[-1] and "k-hat" in lines[-1]


def test_draws_for_target_extrapolates_the_later_growth_of_the_ess() -> None:
    """Linear growth of 0.1 effective points a draw after a slow start: 2000 need 20,000
    draws (and 1,000 effective points 10,000, an exact multiple); no growth, growth too
    slow to be a guide, a reached or infinite target or too short a history give none."""
    slow = [{"draws": 500, "ess": 5.0 * t} for t in range(4)]
    linear = [{"draws": 500, "ess": 0.1 * 500 * (t + 1)} for t in range(4, 12)]
    assert draws_for_target(slow + linear, 2000.0) == 20000
    assert draws_for_target(slow + linear, 1000.0) == 10000
    # the later half of 4-6 iterations is their last 3
    short = slow[:1] + [{"draws": 500, "ess": 0.1 * 500 * (t + 2)} for t in range(3)]
    assert draws_for_target(short, 2000.0) == 20000
    assert draws_for_target([{"draws": 500, "ess": 300.0 - t} for t in range(10)], 2000.0) is None
    creeping = [{"draws": 500, "ess": 300.0 + 0.01 * t} for t in range(10)]
    assert draws_for_target(creeping, 2000.0) is None
    assert draws_for_target(linear, 100.0) is None
    assert draws_for_target(linear, np.inf) is None
    assert draws_for_target(linear[:2], 2000.0) is None
    assert draws_for_target([{"draws": 500, "ess": np.nan}] * 5, 2000.0) is None


def test_draws_advice_names_the_remedy_each_case_calls_for() -> None:
    assert "--correct-draws 20000 would reach the ESS target" in draws_advice(600.0, 2000.0, 20000, 12)
    assert "grew too little" in draws_advice(300.0, 2000.0, None, 12)
    assert "k-hat" in draws_advice(2100.0, 2000.0, None, 12)
    # too few iterations to measure a growth, or no finite target: the plain remedy
    assert draws_advice(300.0, 2000.0, None, 2) == "raise --correct-draws"
    assert draws_advice(300.0, np.inf, None, 12) == "raise --correct-draws"


def test_an_unsettled_correction_says_how_many_draws_would_settle_it() -> None:
    rng = np.random.default_rng(5)
    settings = CorrectionSettings(draws=2500, per_iteration=500, ess_target=3000.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = correct(log_target, biased_start(rng), settings, rng)
    assert not res.settled and res.ess_target == 3000.0
    assert res.draws_needed is not None and res.draws_needed > 2500
    assert f"--correct-draws {res.draws_needed}" in res.warnings[0]
    assert "of 3000" in res.warnings[0]


def test_proposal_density_of_several_kernels() -> None:
    """The compiled density of several kernels against scipy's."""
    rng = np.random.default_rng(8)
    centres = rng.random((3, 2))
    a = rng.normal(size=(3, 2, 2)) * 0.1
    scales = a @ a.transpose(0, 2, 1) + 0.002 * np.eye(2)
    q = Proposal(centres, np.linalg.cholesky(scales), nu=5.0, defensive=0.3)
    u = rng.random((50, 2))
    mix = np.mean([multivariate_t(c, sc, df=5.0).pdf(u)
                   for c, sc in zip(centres, scales, strict=True)], axis=0)
    np.testing.assert_allclose(q.log_pdf(u), np.log(0.7 * mix + 0.3), rtol=1e-10)


def test_proposal_density_in_seven_dimensions_far_and_near() -> None:
    """The compiled density against scipy's with many kernels in the stage's dimension,
    at points near the centres and far outside the cube (where every kernel is tiny)."""
    rng = np.random.default_rng(9)
    d, m = 7, 40
    centres = rng.random((m, d))
    a = rng.normal(size=(m, d, d)) * 0.05
    scales = a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(d)
    q = Proposal(centres, np.linalg.cholesky(scales), nu=4.0, defensive=0.1)
    u = np.vstack([centres[:5] + 0.01, rng.random((30, d)), 50.0 + rng.random((5, d))])
    mix = np.mean([multivariate_t(c, sc, df=4.0).pdf(u) for c, sc in zip(centres, scales, strict=True)],
                  axis=0)
    inside = np.all((u >= 0) & (u <= 1), axis=1)
    np.testing.assert_allclose(q.log_pdf(u), np.log(0.9 * mix + 0.1 * inside), rtol=1e-9)
