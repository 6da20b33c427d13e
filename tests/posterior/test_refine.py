"""Refinement design and emulator check: point kinds, boxes, spacing, offset-free errors."""

from __future__ import annotations

import numpy as np
import pytest

from smcbayes.posterior.refine import (
    acquisition_points,
    acquisition_zeta,
    check_emulator,
    check_values,
    local_box,
    log_exp_acquisition,
    quantile_shift,
    round_design,
)


class DistanceStd:
    """Stand-in surrogate: mean 0, standard deviation = distance from a point."""

    def __init__(self, centre: tuple[float, ...] = (0.5, 0.5)) -> None:
        self.centre = np.asarray(centre)

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.atleast_2d(x)
        return np.zeros(len(x)), np.linalg.norm(x - self.centre, axis=1)


def draws(seed: int = 0, n: int = 600) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(rng.normal([0.4, 0.6], [0.05, 0.02], size=(n, 2)), 0.0, 1.0)


def test_local_box_is_the_widened_1_99_percent_range_clipped_to_the_cube() -> None:
    x = np.column_stack([np.linspace(0.2, 0.4, 1001), np.linspace(0.0, 1.0, 1001)])
    lo, hi = local_box(x, widen=0.5)
    # 1-99 % of a uniform grid: 0.202-0.398, widened by half that range on both sides
    np.testing.assert_allclose(lo[0], 0.202 - 0.5 * 0.196)
    np.testing.assert_allclose(hi[0], 0.398 + 0.5 * 0.196)
    assert lo[1] == 0.0 and hi[1] == 1.0
    lo, hi = local_box(np.full((10, 2), 0.3), min_width=0.02)  # degenerate: at least min_width
    np.testing.assert_allclose(hi - lo, 0.02)


class Bowl:
    """Stand-in surrogate: log-loss mean (|x - c|^2) and standard deviation (|x - c'|) given."""

    def __init__(self, centre: tuple[float, ...], unsure: tuple[float, ...], sd: float) -> None:
        self.centre, self.unsure, self.sd = np.asarray(centre), np.asarray(unsure), sd

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.atleast_2d(x)
        near = np.exp(-np.sum((x - self.unsure) ** 2, axis=1) / 0.01)
        return np.sum((x - self.centre) ** 2, axis=1), self.sd * near + 1e-3


def test_log_exp_acquisition_is_tempered_mean_plus_log_sd_in_nats() -> None:
    x = np.array([[0.3, 0.3], [0.9, 0.9]])
    surrogate = DistanceStd()
    mean, std = surrogate.predict(x)
    a, zeta = 0.5 * 4.0, 2.0 ** -1.1
    assert acquisition_zeta(2) == pytest.approx(zeta)
    np.testing.assert_allclose(log_exp_acquisition(x, surrogate, 4.0),
                               2 * zeta * (-a * mean) + np.log(a * std))


class Fixed:
    """Stand-in surrogate: given log-likelihoods (nats) and sds (nats) at successive points,
    for N_eff = 40 (a = 20)."""

    def __init__(self, ll_nats: list[float], sd_nats: list[float]) -> None:
        self.ll, self.sd = np.asarray(ll_nats), np.asarray(sd_nats)

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return -self.ll / 20.0, self.sd / 20.0


def test_log_exp_acquisition_weighs_uncertainty_against_the_tempered_posterior() -> None:
    # in 7 dimensions zeta = 7^-1.1 = 0.118 lies between 0.075 and 0.15, where these
    # orderings change: 10 nats down with sd e^3 beats the best with sd 1, 10 nats down
    # with sd e^1.5 does not (zeta = 0 or zeta = 1 would reverse one of them)
    x = np.zeros((2, 7))
    assert np.diff(log_exp_acquisition(x, Fixed([0.0, -10.0], [1.0, np.exp(3.0)]), 40.0))[0] > 0
    assert np.diff(log_exp_acquisition(x, Fixed([0.0, -10.0], [1.0, np.exp(1.5)]), 40.0))[0] < 0
    # the posterior's variance, exp(2 m + s^2)(exp(s^2) - 1), would pick a point 110 nats
    # down with sd 30 over one 10 nats down with sd 6; this acquisition does not
    assert np.diff(log_exp_acquisition(x, Fixed([-10.0, -110.0], [6.0, 30.0]), 40.0))[0] < 0


def test_acquisition_prefers_unsure_and_probable_points_spread_out() -> None:
    rng = np.random.default_rng(1)
    x = rng.random((400, 2))
    # unsure where the posterior is large: picked there
    pts = acquisition_points(x, Bowl((0.5, 0.5), (0.5, 0.5), 0.5), 40.0, 4, rng, min_distance=0.05)
    assert pts.shape == (4, 2) and np.all(np.linalg.norm(pts - 0.5, axis=1) < 0.15)
    d = np.linalg.norm(pts[:, None] - pts[None, :], axis=2)
    assert np.min(d[np.triu_indices(4, 1)]) >= 0.05
    # very unsure in a corner no posterior draw reached: the uniform candidates find it
    near_centre = np.clip(rng.normal(0.5, 0.02, size=(400, 2)), 0, 1)
    pts = acquisition_points(near_centre, Bowl((0.5, 0.5), (0.9, 0.1), 6.0), 4.0, 2, rng)
    assert np.linalg.norm(pts[0] - [0.9, 0.1]) < 0.15
    assert acquisition_points(x, DistanceStd(), 4.0, 0, rng).shape == (0, 2)


def test_quantile_shift_is_the_largest_change_of_the_5_50_95_quantiles() -> None:
    x = np.random.default_rng(2).random((5000, 2))
    q, shift = quantile_shift(None, x)
    assert q.shape == (3, 2) and shift == np.inf
    _, shift = quantile_shift(q, x + [0.0, 0.1])
    assert shift == pytest.approx(0.1)


def test_round_design_orders_random_draws_lhs_then_uncertain_points() -> None:
    x = draws()
    pts, n_rand = round_design(x, DistanceStd(), 9, np.random.default_rng(2), 4.0)
    assert n_rand == 3 and pts.shape == (9, 2)
    # the leading random draws are posterior draws themselves
    for p in pts[:3]:
        assert np.any(np.all(x == p, axis=1))
    # a sixth: the Latin hypercube over the local box (one point of 9)
    lo, hi = local_box(x)
    assert np.all((pts[3] >= lo) & (pts[3] <= hi))
    # the rest: by the acquisition; with a flat mean, the most uncertain candidates
    # (farthest from the stand-in's centre: draws or uniform points over the box)
    for p in pts[4:]:
        assert np.linalg.norm(p - 0.5) > 0.4


def test_round_design_is_reproducible_and_caps_random_draws() -> None:
    x = draws()
    a, _ = round_design(x, DistanceStd(), 7, np.random.default_rng(3), 4.0)
    b, _ = round_design(x, DistanceStd(), 7, np.random.default_rng(3), 4.0)
    np.testing.assert_array_equal(a, b)
    c, _ = round_design(x, DistanceStd(), 7, np.random.default_rng(4), 4.0)
    assert not np.array_equal(a, c)
    pts, n_rand = round_design(x[:1], DistanceStd(), 9, np.random.default_rng(5), 4.0)
    # one posterior draw only: picked once at random; the acquisition still has the uniform
    # candidates over the box
    assert n_rand == 1 and pts.shape[0] == 9


def test_check_values_removes_the_common_offset_and_scales_by_n_eff() -> None:
    true = np.array([1.0, 2.0, 3.0, 4.0])
    assert check_values(true + 7.3, true, 50.0) == pytest.approx(0.0, abs=1e-12)
    # em - true = [0, 1, 0, 1] -> err = -(n_eff/2) [0, 1, 0, 1] -> |err - mean| = n_eff/4
    em = true + np.array([0.0, 1.0, 0.0, 1.0])
    assert check_values(em, true, 2.0) == pytest.approx(0.5)
    assert check_values(em, true, 10.0) == pytest.approx(2.5)
    # non-finite pairs are left out; fewer than two finite gives NaN
    assert check_values(np.append(em, 99.0), np.append(true, np.nan), 2.0) == pytest.approx(0.5)
    assert np.isnan(check_values(np.array([1.0, np.inf]), np.array([1.0, 2.0]), 2.0))


def test_check_emulator_of_a_shifted_exact_emulator_and_of_a_wrong_one() -> None:
    rng = np.random.default_rng(6)
    x = rng.random((50, 2))

    def true(u: np.ndarray) -> np.ndarray:
        out = np.sum((u - 0.3) ** 2, axis=1)
        out[:5] = np.nan  # failed simulations
        return out

    exact = check_emulator(x, lambda u: np.sum((u - 0.3) ** 2, axis=1) + 2.0, true, 40.0)
    assert exact.points == 45
    assert exact.mean_abs_error == pytest.approx(0.0, abs=1e-9)
    assert exact.max_abs_error == pytest.approx(0.0, abs=1e-9)
    assert exact.correlation == pytest.approx(1.0)

    def wrong(u: np.ndarray) -> np.ndarray:
        return np.sum((u - 0.3) ** 2, axis=1) + 0.1 * u[:, 0]

    chk = check_emulator(x, wrong, true, 40.0)
    err = -20.0 * 0.1 * x[5:, 0]
    err -= err.mean()
    assert chk.mean_abs_error == pytest.approx(np.mean(np.abs(err)))
    assert chk.rmse == pytest.approx(np.sqrt(np.mean(err**2)))
    assert chk.max_abs_error == pytest.approx(np.max(np.abs(err)))
    assert set(chk.as_dict()) == {"points", "mean_abs_error", "rmse", "max_abs_error", "correlation"}


@pytest.mark.parametrize("share", [6, 3])
def test_round_design_gives_the_wide_draws_their_share(share: int) -> None:
    """After the random posterior draws come ``count // share`` random rows of ``wide_unit``
    (a sixth from the tempered posterior, a third from disputed sample-function draws)."""
    x = draws()
    wide = np.random.default_rng(8).uniform(0.8, 1.0, size=(500, 2))
    pts, n_rand = round_design(x, DistanceStd(), 30, np.random.default_rng(6), 4.0, wide, share)
    taken = pts[n_rand:n_rand + 30 // share]
    assert all(np.any(np.all(wide == p, axis=1)) for p in taken)
    # the next row is the Latin hypercube's, inside the posterior's box, not a wide draw
    assert not np.any(np.all(wide == pts[n_rand + 30 // share], axis=1))


def test_emulator_start_adds_the_local_search_spaced_best_first() -> None:
    from types import SimpleNamespace

    from smcbayes.forward.parameters import Parameter, ParameterSpace
    from smcbayes.posterior.context import emulator_start
    from smcbayes.run.runlog import LogState

    space = ParameterSpace([Parameter("a", "a", "-", 1.0, 0.0, 1.0, False, 0.5, (-np.inf, np.inf), "a"),
                            Parameter("b", "b", "-", 1.0, 0.0, 1.0, False, 0.5, (-np.inf, np.inf), "b")])
    # evaluations 0-1: the optimisation; 2-9: a local search
    pts = [((0.1, 0.1), 9.0), ((0.9, 0.9), 8.0), ((0.5, 0.5), 2.0), ((0.5, 0.505), 1.0),
           ((0.6, 0.5), 3.0), ((0.7, 0.5), None), ((0.55, 0.5), 4.0), ((0.3, 0.3), 6.0),
           ((0.3, 0.305), 5.0), ((0.2, 0.8), float("inf"))]
    rounds = {i: {"kind": "polish" if i >= 2 else "bo"} for i in range(len(pts))}
    evals = {i: {"round": i, "params": {"a": p[0], "b": p[1]}, "loss": loss}
             for i, (p, loss) in enumerate(pts)}
    state = LogState(rounds=rounds, evaluations=evals)
    ctx = SimpleNamespace(space=space, run=SimpleNamespace(
        evaluation_log=lambda: SimpleNamespace(read=lambda: state)))
    x0, y0 = np.array([[0.1, 0.1], [0.9, 0.9], [0.5, 0.505]]), np.log([9.0, 8.0, 1.0])
    x, y = emulator_start(ctx, x0, y0, spacing=0.02)
    # the GP's points first and unchanged; failed and infinite losses left out; 0.5, 0.5 is
    # too close to the best (already in the GP); of 0.3, 0.3 and 0.3, 0.305 the better
    # one, though logged later; the rest best first
    np.testing.assert_array_equal(x[:3], x0)
    np.testing.assert_allclose(x[3:], [[0.6, 0.5], [0.55, 0.5], [0.3, 0.305]])
    np.testing.assert_allclose(y[3:], np.log([3.0, 4.0, 5.0]))
    x, _ = emulator_start(ctx, x0, y0, spacing=0.02, limit=2)
    np.testing.assert_allclose(x[3:], [[0.6, 0.5], [0.55, 0.5]])
    # a run without a local search keeps its GP's data
    state.rounds = {r: {"kind": "bo"} for r in rounds}
    x, y = emulator_start(ctx, x0, y0)
    assert x is x0 and y is y0
