"""The curve emulator path's rounds: the draws that lean to the sample functions' disagreement,
the error at them, the posterior's move between rounds on common draws, and when rounds
validate the emulator."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import norm

from smcbayes.posterior.correct import ImportanceSample
from smcbayes.posterior.curve_aim import AIMED, TARGETED, aimed, draws, lift, targeted
from smcbayes.posterior.curve_progress import (
    QUANTILE_SHIFT,
    VALIDATED_ROUNDS,
    LearningProgress,
    confirmed,
    round_status,
    rounds_validated,
)
from smcbayes.posterior.curve_round import Round
from smcbayes.posterior.curve_sample import START_ROWS, FinalPosterior, quantile_shift
from smcbayes.posterior.curve_spread import FunctionPosteriors, function_spread, spread_standard_error
from smcbayes.posterior.curve_stage import _fresh_error, _take
from smcbayes.posterior.spread import SPREAD_MAX


def _sample(centre: float, count: int = 20000, seed: int = 0) -> ImportanceSample:
    """A normal posterior (sd 0.1) on the unit interval, sampled by importance from the
    uniform prior."""
    u = np.random.default_rng(seed).random((count, 1))
    log_target = norm.logpdf(u[:, 0], centre, 0.1)
    log_w = log_target - np.logaddexp.reduce(log_target)
    ess = 1.0 / np.sum(np.exp(2 * log_w))
    return ImportanceSample(u, log_target, log_w, np.zeros(count, dtype=int), 0.0, ess,
                            0, target="emulator")


def test_the_shift_is_the_move_of_the_quantiles_between_two_posteriors() -> None:
    sample = _sample(0.5)
    assert quantile_shift(sample, lambda u: norm.logpdf(u[:, 0], 0.5, 0.1)) < 1e-12
    # a posterior 0.04 to the left: each quantile moves by 0.04 (up to the draws' noise,
    # which the common draws keep well below the move)
    moved = quantile_shift(sample, lambda u: norm.logpdf(u[:, 0], 0.46, 0.1))
    assert abs(moved - 0.04) < 0.005, moved
    # a posterior with no draw where it lies cannot be compared: infinitely far
    assert quantile_shift(sample, lambda u: np.full(u.shape[0], -np.inf)) == np.inf
    # draws the earlier posterior rules out (-inf, or NaN from a failed evaluation) carry no
    # weight under it: without the left half, the 5 % quantile moves most, to the normal's
    # 52.5 % quantile
    cut = quantile_shift(sample, lambda u: np.where(u[:, 0] < 0.5, np.nan, norm.logpdf(u[:, 0], 0.5, 0.1)))
    assert abs(cut - (norm.ppf(0.525, 0.5, 0.1) - norm.ppf(0.05, 0.5, 0.1))) < 0.01, cut


def test_the_draws_stop_at_distinct_points_of_weight_and_count_repeats() -> None:
    rng = np.random.default_rng(0)
    w = np.array([0.5, 0.3, 0.2, 0.0, 0.0])
    picked, times = draws(w, 3, rng)
    assert picked.tolist() == [0, 1, 2] and np.all(times >= 1)  # no point without weight
    # more wanted than carry weight: each point of weight, with how often it came up
    again, times = draws(w, 5, rng)
    assert again.tolist() == [0, 1, 2] and np.all(times >= 1)
    # one wanted: the first draw settles it
    one, times = draws(w, 1, rng)
    assert len(one) == 1 and times.tolist() == [1]


def test_the_weighted_draws_estimate_a_concentrated_posteriors_mean() -> None:
    # a posterior with 0.9 on one point of 60: ten distinct points drawn without
    # replacement would hold it once in ten; the draws' multiplicities keep its share, up
    # to the one extra draw of the point that stops them
    rng = np.random.default_rng(1)
    p = np.full(60, 0.1 / 59)
    p[0] = 0.9
    f = (np.arange(60) == 0).astype(float)
    est = []
    for _ in range(2000):
        rows, times = draws(p, 10, rng)
        est.append(np.average(f[rows], weights=times))
    assert abs(np.mean(est) - 0.9) < 0.02, np.mean(est)


def _posteriors(log_lik: np.ndarray, seed: int = 0) -> FunctionPosteriors:
    """Functions' posteriors on a support of ``log_lik.shape[1]`` points under a flat mean."""
    count = log_lik.shape[1]
    log_mean = np.full(count, -np.log(count))
    log_f = log_lik - np.logaddexp.reduce(log_lik, axis=1, keepdims=True)
    return FunctionPosteriors(np.arange(count), log_mean, log_f, log_lik)


def test_the_targeted_draws_lean_to_disagreement_with_bounded_error_weights() -> None:
    rng = np.random.default_rng(0)
    # 400 support points; the functions agree on the first 300 and disagree on the rest
    log_lik = np.zeros((8, 400))
    log_lik[:, 300:] = rng.normal(0.0, 1.0, (8, 100))
    posteriors = _posteriors(log_lik)
    p, s = posteriors.pooled(), posteriors.disagreement()
    assert np.isclose(p.sum(), 1.0) and np.all(s[:300] == 0.0) and np.all(s[300:] > 0.0)
    unit = np.linspace(0.0, 1.0, 400)[:, None]
    toward, tail = aimed(posteriors, unit, p * s)
    up = lift(p, s, toward)
    # a proposal (sums to one) whose importance weights p / q are bounded
    assert np.isclose(np.sum(p * up), 1.0)
    assert np.max(1.0 / up) <= 1.0 / (1.0 - TARGETED) + 1e-12
    np.testing.assert_allclose(up[:300], 1.0 - TARGETED)
    chosen, weight, aim = targeted(posteriors, unit, 40, rng)
    assert len(np.unique(chosen)) == 40 and aim["posterior_points"] == 40
    # each point's importance weight times how often it was drawn
    times = np.rint(weight * up[chosen])
    assert np.allclose(weight * up[chosen], times) and np.all(times >= 1) and times.sum() == aim["draws"]
    assert np.isclose(aim["mean_disagreement_nats"], np.sum(p * s))
    assert np.isclose(aim["error_weight_ess"], weight.sum() ** 2 / np.sum(weight ** 2))
    assert np.isclose(aim["tail_share"], np.sum((p * up)[tail]))
    assert np.isclose(aim["tail_posterior"], np.sum(p[tail])) and aim["tail_share"] > aim["tail_posterior"]
    # the disagreeing quarter of the posterior gets more than its share of the draws
    q_far = np.sum((p * up)[300:])
    assert q_far > 0.5 and np.sum(chosen >= 300) > 10
    # functions that agree everywhere leave the posterior's own draws, each of weight one
    still = lift(p, np.zeros(400))
    np.testing.assert_allclose(still, 1.0)


@pytest.mark.parametrize("upper", [True, False])
def test_the_aimed_draws_go_to_the_tail_whose_quantile_the_functions_move(upper: bool) -> None:
    rng = np.random.default_rng(3)
    unit = rng.uniform(size=(2000, 2))
    # the functions disagree a little everywhere and much beyond x0 = 0.9 (or below 0.1),
    # which moves the 95 % (5 %) quantile of x0 (a tail holding a tenth of the posterior)
    log_lik = rng.normal(0.0, 0.2, (16, 2000))
    far = unit[:, 0] > 0.9 if upper else unit[:, 0] < 0.1
    log_lik[:, far] += rng.normal(0.0, 1.5, (16, 1))
    posteriors = _posteriors(log_lik)
    p, s = posteriors.pooled(), posteriors.disagreement()
    toward, tail = aimed(posteriors, unit, p * s)
    assert toward is not None and np.isclose(toward.sum(), 1.0) and np.all(toward >= 0.0)
    # the tail recorded is beyond x0's 95 % (5 %) quantile under the mean's (flat) weights
    assert abs(tail.mean() - 0.05) < 0.01 and np.all(far[tail])
    # beyond the quantile (5 % of the posterior) the aimed weights put far more than the
    # density-weighted disagreement does, which already leans to the disagreeing tenth
    lean = p * s / np.sum(p * s)
    assert np.sum(toward[tail]) > 0.4 and np.sum(toward[tail]) > 2.0 * np.sum(lean[tail])
    # the proposal still sums to one, with the importance weights bounded
    up = lift(p, s, toward)
    assert np.isclose(np.sum(p * up), 1.0) and np.max(1.0 / up) <= 1.0 / (1.0 - TARGETED) + 1e-12
    np.testing.assert_allclose(lift(p, s, None), (1.0 - TARGETED) + TARGETED * lean / p)
    np.testing.assert_allclose(up, (1.0 - TARGETED) + TARGETED * ((1.0 - AIMED) * lean + AIMED * toward) / p)
    # a quarter of the proposal is aimed, as the README's formula says
    assert (TARGETED, AIMED) == (0.5, 0.5)
    # functions that agree everywhere aim nowhere and record no tail
    agree = _posteriors(np.zeros((8, 2000)))
    none, no_tail = aimed(agree, unit, agree.pooled() * agree.disagreement())
    assert none is None and not no_tail.any()
    with pytest.raises(ValueError, match="support has 2000 points"):
        targeted(posteriors, unit[:10], 5, rng)


def test_the_rounds_error_is_the_weighted_mean_at_its_simulated_posterior_draws() -> None:
    # expected loss e^1 everywhere (the mean curves' e^3); simulated e^(1 + k / 10) at row k:
    # errors of k / 10 * N_eff / 2
    features = SimpleNamespace(loss=lambda y: np.exp(1.0 + y[:, 0] / 10.0))
    emulator = SimpleNamespace(
        loss=lambda x, variance=False: np.full(len(x), np.e if variance else np.e ** 3), features=features)
    new = np.zeros((5, 2))
    y_new = np.arange(5.0)[:, None]
    step = Round(new, 3, None, 0.0, np.array([2.0, 1.0, 1.0]))
    ok = np.array([True, True, False, True, True])
    # rows 3 and 4 are exploration; row 2 failed: (2 * 0 + 1 * 0.1) / 3 * 4 / 2
    assert np.isclose(_fresh_error(emulator, 4.0, step, y_new, ok), 0.2 / 3)
    assert _fresh_error(emulator, 4.0, step, y_new, np.zeros(5, dtype=bool)) == np.inf


def test_rounds_validate_only_when_stable_and_accurate_together() -> None:
    small = [0.5] * VALIDATED_ROUNDS
    stable = [QUANTILE_SHIFT / 2] * VALIDATED_ROUNDS
    narrow = [SPREAD_MAX / 2] * VALIDATED_ROUNDS

    def still() -> float:
        return QUANTILE_SHIFT / 2

    assert rounds_validated(small, [None, *stable], 1.0, narrow, still)
    assert not rounds_validated(small[:-1], stable[:-1], 1.0, narrow, still)  # too few rounds
    # the last round moved
    assert not rounds_validated(small, [*stable[:-1], 2 * QUANTILE_SHIFT], 1.0, narrow, still)
    # a round with nothing to compare
    assert not rounds_validated(small, [None, *stable[:-1]], 1.0, narrow, still)
    # every round must be within the tolerance: a good mean over the rounds is not enough
    assert not rounds_validated([0.2, 0.2, 1.4], stable, 1.0, narrow, still)
    # earlier rounds do not count
    assert rounds_validated([50.0, *small], stable, 1.0, [1.0, *narrow], still)
    # the same rounds' sample functions must agree with the mean, on average: one round's
    # noisy reading neither stops the learning nor holds it, and earlier rounds do not count
    assert not rounds_validated(small, stable, 1.0, [*narrow[:-1], 3 * SPREAD_MAX], still)
    assert not rounds_validated(small, stable, 1.0, [1.1 * SPREAD_MAX] * VALIDATED_ROUNDS, still)
    assert rounds_validated(small, stable, 1.0, [*narrow[:-1], 1.5 * SPREAD_MAX], still)
    assert rounds_validated(small, stable, 1.0, [3 * SPREAD_MAX, *narrow], still)
    # small moves that add up over the rounds do not validate, nor does a drift not measured
    assert not rounds_validated(small, stable, 1.0, narrow, lambda: 1.5 * QUANTILE_SHIFT)
    assert not rounds_validated(small, stable, 1.0, narrow, lambda: None)

    # the drift is measured only when the rest validates
    def unwanted() -> float:
        raise AssertionError("measured")

    assert not rounds_validated(small[:-1], stable[:-1], 1.0, narrow, unwanted)


def test_the_drift_is_the_move_from_the_emulator_before_the_validating_rounds(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A posterior that creeps one way by a little each round moves by the sum over the
    rounds that validate: each round's shift stays within the bound, the drift does not.
    The rounds are taken as the learning takes them (:func:`_take`), each emulator standing
    for a normal posterior at its centre."""
    import smcbayes.posterior.curve_stage as curve_stage

    monkeypatch.setattr(curve_stage, "log_posterior",
                        lambda centre, *args, **kwargs: lambda u: norm.logpdf(u[:, 0], centre, 0.1))
    monkeypatch.setattr(curve_stage, "_fresh_error", lambda *args: 0.5)
    monkeypatch.setattr(curve_stage, "_round_record", lambda *args: {})
    step = QUANTILE_SHIFT * 0.6
    progress = LearningProgress(np.zeros((4, 1)), np.zeros((4, 2)), np.full((4, 1), 0.2))
    assert progress.drift() is None  # no round yet
    rng = np.random.default_rng(1)

    def simulate(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros((len(rows), 2)), np.ones(len(rows), dtype=bool)

    # round k is drawn from emulator k, whose posterior lies at 0.5 - k * step
    for k in range(VALIDATED_ROUNDS + 2):
        centre = 0.5 - step * k
        drawn = Round(np.full((3, 1), centre), 2, _sample(centre, seed=k), 0.0, np.ones(2))
        _take(progress, drawn, centre, 4.0, simulate, rng, 0.0)
        if k < VALIDATED_ROUNDS:
            assert progress.drift() is None  # no emulator that many rounds back
    assert len(progress.earlier) == VALIDATED_ROUNDS + 1
    assert progress.shifts[-1] == pytest.approx(step, abs=0.01)
    assert progress.drift() == pytest.approx(VALIDATED_ROUNDS * step, abs=0.01)
    assert progress.record(False)["drift"] == progress.drift()
    # measured once a round: the reading is kept
    progress.sample = _sample(0.9)
    assert progress.drift() == pytest.approx(VALIDATED_ROUNDS * step, abs=0.01)


def _final(spread: float | None, se: float | None = None) -> FinalPosterior:
    """A reported posterior whose sample functions move a quantile by ``spread`` (``None``: not
    measured), with standard error ``se``."""
    measured = None if spread is None else {"max_quantile_shift": spread, "max_quantile_shift_se": se}
    return FinalPosterior([], _sample(0.7), measured, None, {"sampling": 0.0, "spread": 0.0})


def test_a_failed_confirmation_asks_for_new_validated_rounds_and_starts_from_its_sample() -> None:
    """The reported posterior's own spread confirms a validation; when it does not, the
    rounds that validated no longer count (but at the budget's end, with the new rounds
    among them), the next round starts from the reported sample, and both confirmations
    are recorded."""
    progress = LearningProgress(np.zeros((4, 1)), np.zeros((4, 2)), np.full((4, 1), 0.2))

    def good_round() -> None:
        progress.rounds += 1
        progress.spent += 40
        progress.errors.append(0.5)
        progress.shifts.append(QUANTILE_SHIFT / 2)
        progress.spreads.append(SPREAD_MAX / 2)
        progress.drifts[progress.rounds] = QUANTILE_SHIFT / 2

    for _ in range(VALIDATED_ROUNDS):
        good_round()
    assert progress.validated(1.0)
    rng = np.random.default_rng(0)
    assert not confirmed(progress, _final(1.5 * SPREAD_MAX), rng, True)
    assert not progress.validated(1.0) and progress.since == VALIDATED_ROUNDS
    # the next round's importance sampling starts from the reported sample (centred at 0.7)
    assert progress.start.shape == (3 * START_ROWS // 4, 1) and abs(np.median(progress.start) - 0.7) < 0.05
    good_round()
    # at the budget's end no new round can follow: the last rounds count whenever they ran
    assert not progress.validated(1.0) and progress.validated(1.0, ended=True)
    for _ in range(VALIDATED_ROUNDS - 2):
        good_round()
        assert not progress.validated(1.0)
    good_round()
    assert progress.validated(1.0)
    assert confirmed(progress, _final(SPREAD_MAX / 2, 0.004), rng, True)
    # with the budget spent, a failed confirmation is recorded and nothing restarts
    start = progress.start.copy()
    assert not confirmed(progress, _final(None), rng, False)  # an unmeasured spread confirms nothing
    assert progress.since == VALIDATED_ROUNDS and np.array_equal(progress.start, start)
    record = progress.record(True)
    assert [c["passed"] for c in record["confirmations"]] == [False, True, False]
    assert [c["rounds"] for c in record["confirmations"]] == [3, 6, 6]
    assert record["confirmations"][0]["spread"] == 1.5 * SPREAD_MAX
    assert record["confirmations"][1]["forward_runs"] == 240 and record["confirmations"][2]["spread"] is None
    assert [c["spread_se"] for c in record["confirmations"]] == [None, 0.004, None]
    assert all(c["seconds"] == 0.0 for c in record["confirmations"])


def test_a_rounds_line_gives_the_measures_the_stop_reads_beside_its_bounds() -> None:
    """The spreads' mean is over the rounds the stop counts: those since the last failed
    confirmation, or at the budget's end the last ones whenever they ran."""
    progress = LearningProgress(np.zeros((4, 1)), np.zeros((4, 2)), np.full((4, 1), 0.2), spent=160, rounds=4,
                         since=1, errors=[3.0, 1.5, 0.8, 0.625], shifts=[None, 0.04, 0.02, 0.031],
                         spreads=[0.5, 0.2, 0.1, 0.06])
    line = round_status(progress, 1.0, 400)
    assert line.startswith("160 of 400 active-learning runs; error 0.62 nats at fresh posterior draws")
    assert "(at most 1 to stop)" in line
    assert f"posterior moved 0.031 of a parameter's range (at most {QUANTILE_SHIFT:g})" in line
    mean = np.mean([0.2, 0.1, 0.06])
    assert (f"spread 0.060, mean of the last {VALIDATED_ROUNDS} {mean:.3f} "
            f"(at most {SPREAD_MAX:g} on average)") in line
    # two rounds since a failed confirmation: no mean the stop would read yet
    progress.since = 2
    assert "mean of the last" not in round_status(progress, 1.0, 400)
    # but at the budget's end the stop counts the last three whenever they ran
    assert f"mean of the last {VALIDATED_ROUNDS} {mean:.3f}" in round_status(progress, 1.0, 160)
    # the first round has no earlier emulator to move from
    progress.shifts[-1] = None
    assert "posterior move not measured" in round_status(progress, 1.0, 400)


def test_at_the_budgets_end_a_new_round_that_fails_keeps_the_learning_unvalidated() -> None:
    """Rounds from before a failed confirmation count at the budget's end only beside new
    rounds that pass too."""
    progress = LearningProgress(np.zeros((4, 1)), np.zeros((4, 2)), np.full((4, 1), 0.2))
    for error in [0.5] * VALIDATED_ROUNDS + [1.5]:
        progress.errors.append(error)
        progress.shifts.append(QUANTILE_SHIFT / 2)
        progress.spreads.append(SPREAD_MAX / 2)
    progress.since = VALIDATED_ROUNDS
    assert not progress.validated(1.0) and not progress.validated(1.0, ended=True)


def test_the_correlation_kernels_are_the_matern_of_the_distances() -> None:
    from smcbayes.posterior.curves import matern52

    rng = np.random.default_rng(0)
    a, b, ls = rng.random((7, 3)), rng.random((5, 3)), np.array([0.1, 0.5, 2.0])

    def closed_form(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        s = np.sqrt(5.0) * np.sqrt(np.sum(((p[:, None, :] - q[None, :, :]) / ls) ** 2, axis=-1))
        return (1 + s + s * s / 3) * np.exp(-s)

    np.testing.assert_allclose(matern52(a, b, ls), closed_form(a, b), rtol=1e-12, atol=1e-14)
    own = matern52(a, None, ls)
    np.testing.assert_array_equal(own, own.T)
    np.testing.assert_allclose(own, closed_form(a, a), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(own, matern52(a, a, ls), rtol=1e-14, atol=0.0)
    np.testing.assert_array_equal(np.diag(own), 1.0)
    # points 1e-9 apart at a short lengthscale: the matrix-product form of the squared
    # distance cancels to rounding there (errors ~1e-12 at a scaled squared norm near
    # 6,000), the differences do not (1 - r ~ 5/6 of the scaled squared distance)
    close = np.array([[0.9, 0.9, 0.9], [0.9 + 1e-9, 0.9, 0.9]])
    tiny = np.array([0.02, 0.02, 0.02])
    gap = 1.0 - matern52(close, close, tiny)
    np.testing.assert_array_equal(np.diag(gap), 0.0)
    np.testing.assert_allclose(gap[0, 1], 5.0 / 6.0 * (1e-9 / 0.02) ** 2, rtol=0.0, atol=1e-15)
    with pytest.raises(ValueError, match="coordinates"):
        matern52(a, b[:, :2], ls)


def test_many_rows_share_the_correlation_out_over_threads_with_the_same_values() -> None:
    import numba

    from smcbayes.posterior._blocks import BLOCK, PARALLEL_ROWS
    from smcbayes.posterior._matern_kernel import matern52_rows, matern52_rows_parallel
    from smcbayes.posterior.curves import matern52

    rng = np.random.default_rng(2)
    # a last block left part-full
    a, b = rng.random((PARALLEL_ROWS + BLOCK // 2 + 1, 4)), rng.random((37, 4))
    ls = np.array([0.3, 0.5, 1.0, 2.0])
    sa, sbt = np.ascontiguousarray(a / ls), np.ascontiguousarray((b / ls).T)
    serial = np.empty((len(a), len(b)))
    matern52_rows(sa, sbt, serial)
    np.testing.assert_array_equal(matern52(a, b, ls), serial)
    # on one thread the threaded kernel gives the same values too, as it does with fewer rows than a block
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = np.empty_like(serial)
        matern52_rows_parallel(sa, sbt, one, BLOCK)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(one, serial)
    few = np.empty((BLOCK // 2, len(b)))
    matern52_rows_parallel(sa[:BLOCK // 2], sbt, few, BLOCK)
    np.testing.assert_array_equal(few, serial[:BLOCK // 2])


def test_the_correlation_fits_gradient_is_the_derivative_of_its_likelihood() -> None:
    from smcbayes.posterior.curves import (
        LENGTHSCALE_BOUNDS,
        NUGGET_BOUNDS,
        _concentrated_nll,
        fit_correlation,
    )

    rng = np.random.default_rng(3)
    x = rng.random((60, 3))
    z = np.column_stack([np.sin(4 * x[:, 0]) + x[:, 1], np.cos(3 * x[:, 2]) * x[:, 0]])
    z = z + 0.01 * rng.normal(size=z.shape)
    z = (z - z.mean(axis=0)) / z.std(axis=0)

    def central(params: np.ndarray) -> np.ndarray:
        step = 1e-4
        return np.array([(_concentrated_nll(params + e, x, z)[0] - _concentrated_nll(params - e, x, z)[0])
                         / (2 * step) for e in np.eye(len(params)) * step])

    for params in (np.log([0.2, 0.7, 1.5, 1e-4]), np.log([1.0, 0.05, 3.0, 1e-7])):
        value, grad = _concentrated_nll(params, x, z)
        assert np.isfinite(value)
        np.testing.assert_allclose(grad, central(params), rtol=1e-5, atol=1e-6)
    # the fit stops where the likelihood's own slope (by differences) vanishes in every
    # direction a bound does not hold: a wrong gradient would stop it elsewhere
    fit = fit_correlation(x, z)
    params = np.log(np.r_[fit.lengthscales, fit.nugget])
    low = np.log(np.r_[[LENGTHSCALE_BOUNDS[0]] * 3, NUGGET_BOUNDS[0]])
    high = np.log(np.r_[[LENGTHSCALE_BOUNDS[1]] * 3, NUGGET_BOUNDS[1]])
    free = (params > low + 1e-3) & (params < high - 1e-3)
    assert np.count_nonzero(free) >= 3
    assert np.all(np.abs(central(params)[free]) < 1e-2)


def _kernel_case(rng: np.random.Generator, rows: int, nodes: int, grid: np.ndarray) -> dict[str, np.ndarray]:
    """Two configurations' simulated features (forces, switch times, end heights) and
    measured curves of different lengths, packed as :func:`loss_rows` reads them."""
    force = [np.cumsum(rng.random((rows, nodes)), axis=1) for _ in range(2)]
    switch = rng.uniform(0.5, 2.0, (rows, 2))
    heights = rng.uniform(3.0, 4.0, (rows, 2))
    time_m = [np.sort(rng.uniform(0.0, 2.0, 40)), np.sort(rng.uniform(0.0, 1.5, 23))]
    force_m = [np.cumsum(rng.random(40)), np.cumsum(rng.random(23))]
    return {"features": np.hstack(force + [switch, heights]), "force": force, "switch": switch,
            "heights": heights, "time_m": time_m, "force_m": force_m, "grid": grid,
            "times": np.concatenate(time_m), "forces": np.concatenate(force_m),
            "starts": np.array([0, 40, 63], dtype=np.int64), "stack": np.array([3.5, 3.4]),
            "speed": np.array([0.5, 1.1]), "ends": np.array([time_m[0][-1], 1.2])}


def _kernel_expected(case: dict[str, np.ndarray], end_state: bool, flow_stop: bool,
                     bound: float) -> np.ndarray:
    """The same comparison in numpy, summed over the configurations: the simulated curve's
    first value held before the delayed contact and its switch value beyond the switch, the
    measured one's ends held."""
    total = np.zeros(case["switch"].shape[0])
    nodes = case["force"][0].shape[1]
    for k in range(2):
        offset = case["stack"][k] - case["heights"][:, k]
        clipped = np.clip(offset, -bound, bound) if bound > 0 else offset
        delay = clipped / case["speed"][k] if end_state else 0.0
        switch = case["switch"][:, k]
        end = (np.full(len(switch), case["ends"][k]) if flow_stop
               else np.maximum(switch + delay, case["ends"][k]))
        t = end[:, None] * case["grid"][None, :]
        x = np.clip((t - np.reshape(delay, (-1, 1))) / switch[:, None], 0.0, 1.0) * (nodes - 1)
        i = np.minimum(np.floor(x).astype(int), nodes - 2)
        w = x - i
        f = case["force"][k]
        sim = np.take_along_axis(f, i, 1) * (1 - w) + np.take_along_axis(f, i + 1, 1) * w
        total += np.mean((sim - np.interp(t, case["time_m"][k], case["force_m"][k])) ** 2, axis=1)
    return total


@pytest.mark.parametrize(("end_state", "flow_stop", "bound"),
                         [(False, False, 0.0), (True, False, 0.0), (True, False, 0.2), (False, True, 0.0),
                          (True, True, 0.2)])
def test_the_loss_kernel_is_the_interpolated_comparison_of_the_two_curves(end_state: bool, flow_stop: bool,
                                                                         bound: float) -> None:
    from smcbayes.posterior._blocks import BLOCK
    from smcbayes.posterior._curve_kernel import loss_rows, loss_rows_parallel, measured_on_grid

    rng = np.random.default_rng(1)
    # over several of the parallel kernel's blocks, the last one part-full
    rows, nodes = 2 * BLOCK + 7, 9
    case = _kernel_case(rng, rows, nodes, np.linspace(0.0, 1.0, 57))
    # the window's usual end, and beyond the measured end too
    case["switch"][::3, 0] = 0.1
    case["features"][:, 2 * nodes] = case["switch"][:, 0]
    # a switch at 0 is taken at 1e-9 s
    zero = case["features"].copy()
    zero[4, 2 * nodes + 1] = 0.0
    case["switch"][4, 1] = 1e-9
    common = np.empty((2, 57))
    for k in range(2):
        measured_on_grid(case["ends"][k], case["grid"], case["time_m"][k], case["force_m"][k], common[k])

    def run(kernel, features: np.ndarray, *extra: int) -> np.ndarray:
        out = np.full(rows, -1.0)
        kernel(features, nodes, end_state, flow_stop, bound, case["stack"], case["speed"], case["ends"],
               common, case["grid"], case["times"], case["forces"], case["starts"], out, *extra)
        return out

    out = run(loss_rows, zero)
    np.testing.assert_allclose(out, _kernel_expected(case, end_state, flow_stop, bound), rtol=1e-12)
    # shared out over threads: the same values
    np.testing.assert_array_equal(run(loss_rows_parallel, zero, BLOCK), out)
    # a row without a switch time has no loss, not an arbitrary one, nor has one without an
    # end height when the end state places the contact
    features = case["features"].copy()
    features[2, 2 * nodes + 1] = np.nan
    features[5, 2 * nodes + 3] = np.nan
    out = run(loss_rows, features)
    lost = [2, 5] if end_state else [2]
    assert np.all(np.isnan(out[lost])) and np.all(np.isfinite(np.delete(out, lost)))
    np.testing.assert_array_equal(run(loss_rows_parallel, features, BLOCK), out)


def test_the_spread_counts_the_functions_common_lean_away_from_the_mean() -> None:
    # 32 functions that agree with one another and all shift the posterior 0.1 to the right:
    # around their pool they barely spread, but the emulator is that unsure of the mean's
    # posterior, and the spread says so
    sample = _sample(0.5)
    rows = np.arange(len(sample.unit))
    lik = np.tile(norm.logpdf(sample.unit[:, 0], 0.6, 0.1), (32, 1))
    log_f = np.array([lw - np.logaddexp.reduce(lw) for lw in sample.log_weight + lik - sample.log_target])
    posteriors = FunctionPosteriors(rows, sample.log_weight, log_f, lik)
    spread = function_spread([posteriors], sample, ["x"])
    assert abs(spread["max_quantile_shift"] - 0.1) < 0.01, spread


def test_the_spread_over_several_supports_is_the_level_of_all_their_functions() -> None:
    # each support's functions are measured against the mean's posterior on that support:
    # ten functions that shift it by 0.1 on one support and ten that leave it on another
    # are twenty moves, of which more than one in ten is 0.1
    sample = _sample(0.5)
    rng = np.random.default_rng(3)

    def support(centre: float | None) -> FunctionPosteriors:
        rows = np.sort(rng.choice(len(sample.unit), 8000, replace=False))
        log_mean = sample.log_weight[rows] - np.logaddexp.reduce(sample.log_weight[rows])
        x = sample.unit[rows, 0]
        lik = np.zeros((10, len(rows))) if centre is None else np.tile(
            norm.logpdf(x, centre, 0.1) - norm.logpdf(x, 0.5, 0.1), (10, 1))
        log_f = np.array([lw - np.logaddexp.reduce(lw) for lw in log_mean + lik])
        return FunctionPosteriors(rows, log_mean, log_f, lik)

    moved, still = support(0.6), support(None)
    both = function_spread([moved, still], sample, ["x"])
    assert both["functions"] == 20 and both["supports"] == 2 and len(both["function_ess"]) == 20
    assert abs(both["max_quantile_shift"] - 0.1) < 0.015, both
    assert both["support_points"] == len(np.union1d(moved.rows, still.rows))
    assert function_spread([still, support(None)], sample, ["x"])["max_quantile_shift"] < 1e-12
    # the noise is the larger of the two supports' own
    noise = [function_spread([s], sample, ["x"])["sampling_noise"]["x"] for s in (moved, still)]
    assert both["sampling_noise"]["x"] == max(noise)


def test_the_spreads_standard_error_is_that_of_the_level_over_resampled_supports() -> None:
    """The bootstrap over supports: none for one support, zero for supports that agree, and
    for independent supports close to the standard deviation of independent readings."""
    rng = np.random.default_rng(11)
    assert spread_standard_error([rng.random((32, 3, 2))]) is None
    same = rng.random((32, 3, 2))
    assert spread_standard_error([same, same.copy(), same.copy()]) < 1e-12  # interpolation rounding

    def support() -> np.ndarray:
        # moves of 32 functions, half-normal with scale 0.05 in one quantile, 0 elsewhere
        out = np.zeros((32, 3, 2))
        out[:, 0, 0] = np.abs(rng.normal(0.0, 0.05, 32))
        return out

    def reading(moves: list[np.ndarray]) -> float:
        return float(np.max(np.quantile(np.concatenate(moves), 0.9, axis=0)))

    readings = [[support() for _ in range(12)] for _ in range(300)]
    sd = np.std([reading(r) for r in readings], ddof=1)
    errors = [spread_standard_error(r) for r in readings[:40]]
    assert 0.6 * sd < np.mean(errors) < 1.5 * sd, (np.mean(errors), sd)
    # the same moves give the same error: its resampling has its own seed
    assert spread_standard_error(readings[0]) == errors[0]


def test_the_spread_records_its_standard_error_over_several_supports() -> None:
    sample = _sample(0.5)
    rng = np.random.default_rng(5)

    def support(shift: float) -> FunctionPosteriors:
        rows = np.sort(rng.choice(len(sample.unit), 8000, replace=False))
        log_mean = sample.log_weight[rows] - np.logaddexp.reduce(sample.log_weight[rows])
        x = sample.unit[rows, 0]
        lik = np.array([norm.logpdf(x, 0.5 + shift * k / 9, 0.1) - norm.logpdf(x, 0.5, 0.1)
                        for k in range(10)])
        log_f = np.array([lw - np.logaddexp.reduce(lw) for lw in log_mean + lik])
        return FunctionPosteriors(rows, log_mean, log_f, lik)

    one = function_spread([support(0.1)], sample, ["x"])
    assert one["max_quantile_shift_se"] is None
    alike = function_spread([support(0.1) for _ in range(4)], sample, ["x"])
    unlike = function_spread([support(0.1), support(0.0), support(0.2), support(0.05)], sample, ["x"])
    assert 0.0 <= alike["max_quantile_shift_se"] < 0.01 < unlike["max_quantile_shift_se"], (alike, unlike)


def test_the_final_chains_start_at_draws_of_a_close_posterior_and_run_fewer_steps(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Given draws of the last round's posterior (resampled, so repeated), the final chains'
    walkers are distinct rows of them and run at most :data:`WARM_CHAIN_STEPS` steps;
    without, or with fewer distinct rows than walkers, they start at the best training
    point and may run :data:`CHAIN_STEPS`."""
    from smcbayes.config import PosteriorSpec
    from smcbayes.posterior import curve_sample

    seen: list[dict[str, object]] = []
    monkeypatch.setattr(curve_sample, "sample_chains",
                        lambda emulator, n_eff, rng, centre, steps, walkers, **kw: seen.append(
                            {"centre": centre, "steps": steps, "walkers": walkers, **kw}))
    x = np.array([[0.2, 0.2], [0.6, 0.4], [0.9, 0.9]])
    features = SimpleNamespace(loss=lambda y: y[:, 0])
    emulation = curve_sample.CurveEmulation(SimpleNamespace(x=x, y=np.array([[3.0], [1.0], [2.0]]),
                                                            features=features), 4.0)
    settings = PosteriorSpec()
    distinct = np.random.default_rng(0).random((40, 2))
    curve_sample.curve_chains(emulation, settings, np.random.default_rng(1))
    curve_sample.curve_chains(emulation, settings, np.random.default_rng(1), np.repeat(distinct, 3, axis=0))
    repeated = np.repeat(distinct[:20], 5, axis=0)
    curve_sample.curve_chains(emulation, settings, np.random.default_rng(1), repeated)
    cold, warm, few = seen
    for start in (cold, few):
        assert start["start"] is None and np.array_equal(start["centre"], x[1])
        assert start["steps"] == min(settings.steps, curve_sample.CHAIN_STEPS)
    assert warm["steps"] == min(settings.steps, curve_sample.WARM_CHAIN_STEPS) < cold["steps"]
    rows = warm["start"]
    assert rows.shape == (settings.walkers, 2) and len(np.unique(rows, axis=0)) == settings.walkers
    assert all(any(np.array_equal(r, d) for d in distinct) for r in rows)
