"""The error model of the predictive bands, learnt from training residuals by phase of the closing.

Synthetic residual curves whose spread is known by construction (small early in the
closing, large over its last millimetre) check that the model is wide where the residuals
are, that bands stay within [0, F_limit], and that a well-specified case (measurements
drawn as model + errors of the same law) keeps about nominal coverage.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from smcbayes.posterior.discrepancy import (
    LEVELS,
    MIN_POINTS,
    ResidualCurve,
    fit_discrepancy,
    remaining_travel_mm,
    training_residuals,
)
from smcbayes.posterior.predictive import predictive_bands

T_END, TRAVEL = 10.0, 5.0  # s, mm: closing at 0.5 mm/s


def spread_kN(d_mm: np.ndarray) -> np.ndarray:
    """Error sd: 5 kN until the last millimetre of closing, 60 kN within it and after."""
    return np.where(d_mm < 1.0, 60.0, 5.0)


def curves(rng: np.random.Generator, n: int = 6, points: int = 400) -> list[ResidualCurve]:
    out = []
    for k in range(n):
        t = np.sort(rng.uniform(0.0, 1.05 * T_END, points))
        d = remaining_travel_mm(t, T_END, TRAVEL)
        out.append(ResidualCurve(f"c{k}", t, spread_kN(d) * rng.standard_normal(points), T_END, TRAVEL))
    return out


class RampModel:
    """Force ``a t`` up to the switch at ``T_END`` (then held), ram travel ``0.5 t`` mm."""

    def simulate(self, theta: np.ndarray, ids: list[str]) -> dict[str, SimpleNamespace]:
        t = np.linspace(0.0, 2 * T_END, 401)
        a = theta[:, 0][:, None]
        force = a * np.minimum(t, T_END)[None, :]
        disp = np.tile(TRAVEL / T_END * t, (theta.shape[0], 1))
        p = theta.shape[0]
        return {cid: SimpleNamespace(ok=np.ones(p, bool), time_s=np.tile(t, (p, 1)), force_kN=force,
                                     displacement_mm=disp, switch_time_s=np.full(p, T_END)) for cid in ids}


def test_the_error_model_is_wide_where_the_residuals_are_large() -> None:
    disc = fit_discrepancy(curves(np.random.default_rng(0)))
    assert disc is not None and disc.bins >= 3
    narrow = disc.scale_kN(np.array([4.0, 3.0, 2.5]))
    wide = disc.scale_kN(np.array([0.5, 0.1, -0.2]))
    # the central 90 % half-width of a normal law is 1.645 sd: 8 and 99 kN here
    np.testing.assert_allclose(narrow, 1.645 * 5.0, rtol=0.35)
    np.testing.assert_allclose(wide, 1.645 * 60.0, rtol=0.35)
    assert np.min(wide) > 5 * np.max(narrow)


def test_bins_hold_enough_points_of_more_than_one_configuration() -> None:
    disc = fit_discrepancy(curves(np.random.default_rng(1), n=3, points=60))
    assert disc is not None
    assert np.all(disc.points >= MIN_POINTS) and np.all(disc.configs >= 2)
    assert disc.quantiles_kN.shape == (disc.bins, LEVELS)
    assert np.all(np.diff(disc.quantiles_kN, axis=1) >= 0)  # quantiles increase with the level
    summary = disc.as_dict()
    assert len(summary["bins"]) == disc.bins and summary["bins"][0]["from_mm"] is None


def test_no_usable_residual_gives_no_error_model() -> None:
    t = np.linspace(0.0, 1.0, 5)
    assert fit_discrepancy([]) is None
    assert fit_discrepancy([ResidualCurve("c", t, np.full(5, np.nan), 1.0, 1.0)]) is None


def test_bands_stay_within_zero_and_the_force_limit() -> None:
    """Large errors at zero force and at the limit: the predictive band is clipped, the model's is not."""
    disc = fit_discrepancy(curves(np.random.default_rng(2)))
    theta = np.column_stack([np.full(50, 140.0), np.ones(50)])  # force 0 -> 1400 kN at the switch
    b = predictive_bands(RampModel(), theta, ["c"], {}, {}, np.random.default_rng(3), discrepancy=disc,
                         force_limit_kN={"c": 1400.0})["c"]
    assert b.error_model == "discrepancy"
    assert np.min(b.force_pred_kN) >= 0.0 and np.max(b.force_pred_kN) <= 1400.0
    assert b.force_pred_kN[0, -1] < 1400.0 - 50.0 and b.force_pred_kN[4, -1] == 1400.0
    early, late = b.time_s < 6.0, (b.time_s > 9.0) & (b.time_s < T_END)
    width = b.force_pred_kN[4] - b.force_pred_kN[0]
    assert np.mean(width[late]) > 5 * np.mean(width[early & (b.time_s > 1.0)])


def curves_of(rng: np.random.Generator, sd_kN: float) -> list[ResidualCurve]:
    """Two residual curves of constant spread ``sd_kN`` over the closing."""
    t = np.linspace(0.0, T_END, 300)
    return [ResidualCurve(cid, t, sd_kN * rng.standard_normal(t.size), T_END, TRAVEL) for cid in ("a", "b")]


def test_bands_take_each_configurations_own_error_model() -> None:
    rng = np.random.default_rng(1)
    narrow = fit_discrepancy(curves_of(rng, 5.0))
    wide = fit_discrepancy(curves_of(rng, 60.0))
    theta = np.column_stack([np.full(40, 100.0), np.ones(40)])
    bands = predictive_bands(RampModel(), theta, ["n", "w", "x"], {}, {"n": 1.0, "w": 1.0, "x": 1.0},
                             np.random.default_rng(2), discrepancy={"n": narrow, "w": wide, "x": None})
    width = {cid: float(np.mean(b.force_pred_kN[4] - b.force_pred_kN[0])) for cid, b in bands.items()}
    assert width["w"] > 5 * width["n"]
    assert bands["n"].error_model == bands["w"].error_model == "discrepancy"
    assert bands["x"].error_model == "white noise"


def test_a_well_specified_case_keeps_about_nominal_coverage() -> None:
    """Measured = model + errors of the law the training residuals came from."""
    rng = np.random.default_rng(4)
    disc = fit_discrepancy(curves(rng))
    theta = np.column_stack([rng.normal(100.0, 0.5, 100), np.ones(100)])
    cov50, cov90 = [], []
    for _ in range(4):
        tm = np.sort(rng.uniform(0.0, 1.05 * T_END, 500))
        fm = (100.0 * np.minimum(tm, T_END)
              + spread_kN(remaining_travel_mm(tm, T_END, TRAVEL)) * rng.standard_normal(tm.size))
        b = predictive_bands(RampModel(), theta, ["c"], {"c": (tm, fm)}, {}, rng, grid_points=600,
                             discrepancy=disc, force_limit_kN={"c": 5000.0})["c"]
        cov50.append(b.coverage50)
        cov90.append(b.coverage90)
        assert b.crps_kN > 0 and b.interval_score90_kN > 0 and b.rmse_median_kN > 0
    assert 0.42 < np.mean(cov50) < 0.58
    assert 0.85 < np.mean(cov90) < 0.95


def test_sharper_bands_score_better_when_both_cover() -> None:
    """CRPS and interval score of the right error law beat those of a 4x too wide white noise."""
    rng = np.random.default_rng(5)
    theta = np.column_stack([np.full(40, 100.0), np.ones(40)])
    tm = np.linspace(0.5, 9.0, 300)
    fm = 100.0 * tm + 10.0 * rng.standard_normal(tm.size)
    right = predictive_bands(RampModel(), theta, ["c"], {"c": (tm, fm)}, {"c": 10.0}, rng)["c"]
    wide = predictive_bands(RampModel(), theta, ["c"], {"c": (tm, fm)}, {"c": 40.0}, rng)["c"]
    assert wide.coverage90 > 0.97 and right.coverage90 > 0.8
    assert right.crps_kN < wide.crps_kN and right.interval_score90_kN < wide.interval_score90_kN
    # CRPS of N(0, s) at its own draws: s / sqrt(pi)
    assert right.crps_kN == pytest.approx(10.0 * 0.5642, rel=0.2)


def test_training_residuals_are_measured_minus_simulated_at_the_measured_times() -> None:
    tm = np.linspace(0.0, 12.0, 25)
    res = training_residuals(RampModel(), np.array([[100.0, 1.0]]), ["a", "b"],
                             {"a": (tm, 100.0 * np.minimum(tm, T_END) + 3.0)})
    assert [r.config_id for r in res] == ["a"]
    np.testing.assert_allclose(res[0].residual_kN, 3.0, atol=1e-9)
    assert res[0].switch_s == T_END and res[0].travel_mm == pytest.approx(TRAVEL)


def test_bands_mix_over_the_contact_delays() -> None:
    """A single zero delay changes nothing; delays of -1, 0 and 1 s spread the model band of a
    ramp of 100 kN/s by about +-100 kN and delay the switch with them."""
    theta = np.column_stack([np.full(30, 100.0), np.ones(30)])
    plain = predictive_bands(RampModel(), theta, ["c"], {}, {"c": 1.0}, np.random.default_rng(4))["c"]
    zero = predictive_bands(RampModel(), theta, ["c"], {}, {"c": 1.0}, np.random.default_rng(4),
                            delays_s={"c": np.array([0.0])})["c"]
    np.testing.assert_allclose(zero.force_kN, plain.force_kN)
    np.testing.assert_allclose(zero.force_pred_kN, plain.force_pred_kN)
    mixed = predictive_bands(RampModel(), theta, ["c"], {}, {"c": 1.0}, np.random.default_rng(4),
                             delays_s={"c": np.array([-1.0, 0.0, 1.0])})["c"]
    mid = np.argmin(np.abs(mixed.time_s - 5.0))
    assert plain.force_kN[4, mid] - plain.force_kN[0, mid] < 1e-6
    assert mixed.force_kN[4, mid] - mixed.force_kN[0, mid] == pytest.approx(200.0, rel=0.02)
    assert mixed.force_kN[2, mid] == pytest.approx(500.0, rel=0.02)
    assert mixed.draws == 30
    # one delay of +1 s: the closing comes a second later, the force at 5 s is that of 4 s
    later = predictive_bands(RampModel(), theta, ["c"], {}, {"c": 1.0}, np.random.default_rng(4),
                             delays_s={"c": np.array([1.0])})["c"]
    assert later.force_kN[2, mid] == pytest.approx(100.0 * (later.time_s[mid] - 1.0), rel=1e-6)


def test_residuals_of_a_delayed_closing() -> None:
    from smcbayes.posterior.discrepancy import residual_curve

    res = RampModel().simulate(np.array([[100.0, 1.0]]), ["a"])["a"]
    tm = np.linspace(0.0, 12.0, 50)
    measured = 100.0 * np.clip(tm - 0.5, 0.0, T_END)
    curve = residual_curve("a", res, 0, tm, measured, delay_s=0.5)
    np.testing.assert_allclose(curve.residual_kN, 0.0, atol=1e-9)
    assert curve.switch_s == pytest.approx(T_END + 0.5)
    # the remaining travel of the delayed closing is the undelayed one shifted by the delay
    plain = residual_curve("a", res, 0, tm, measured)
    assert curve.travel_mm == pytest.approx(TRAVEL + 0.5 * TRAVEL / T_END)
    d_plain = remaining_travel_mm(tm[10:20], plain.switch_s, plain.travel_mm)
    np.testing.assert_allclose(remaining_travel_mm(tm[10:20] + 0.5, curve.switch_s, curve.travel_mm), d_plain)


def test_a_closing_that_ended_at_the_limit_is_held_there_to_the_horizon() -> None:
    from smcbayes.posterior.discrepancy import held_at_limit

    t = np.linspace(0.0, 10.0, 21)  # step 0.5 s
    at_limit = np.linspace(0.0, 1400.0, 21)
    tt, ff = held_at_limit(t, at_limit, 1400.0, 12.0)
    np.testing.assert_allclose(tt[21:], [10.5, 11.0, 11.5, 12.0])
    np.testing.assert_allclose(ff[21:], 1400.0)
    np.testing.assert_array_equal(tt[:21], t)
    # a curve stopping at 97 % of the limit ended at the switch too; the press then holds the limit
    assert held_at_limit(t, 0.97 * at_limit, 1400.0, 12.0)[1][-1] == 1400.0
    # a curve cut short of the limit is not continued, nor one reaching the horizon already
    assert held_at_limit(t, 0.9 * at_limit, 1400.0, 12.0)[0].size == 21
    assert held_at_limit(t, at_limit, 1400.0, 10.0)[0].size == 21


def test_residuals_after_both_ends_of_closing_are_zero_and_before_a_late_switch_positive() -> None:
    """Measured closings end at the limit (1000 kN at 10 s for the ramp of 100 kN/s); the
    simulated one switches at 10 s too or, delayed by 1 s, at 11 s.  Continued at the limit,
    the residuals are 0 once both have switched and limit - simulated in between."""
    from smcbayes.posterior.discrepancy import residual_curve

    res = RampModel().simulate(np.array([[100.0, 1.0]]), ["a"])["a"]
    tm = np.linspace(0.0, T_END, 41)
    measured = 100.0 * tm
    same = residual_curve("a", res, 0, tm, measured, limit_kN=1000.0)
    assert same.time_s[-1] == pytest.approx(1.1 * T_END, abs=0.25)
    np.testing.assert_allclose(same.residual_kN, 0.0, atol=1e-9)
    late = residual_curve("a", res, 0, tm, measured, delay_s=1.0, limit_kN=1000.0)
    after = late.time_s > T_END
    expected = 1000.0 - 100.0 * np.clip(late.time_s[after] - 1.0, 0.0, T_END)
    np.testing.assert_allclose(late.residual_kN[after], expected, atol=1e-9)
    assert np.all(late.residual_kN[after][late.time_s[after] < T_END + 1.0] > 0.0)
    # without the limit the residuals stop with the measured curve, as before
    assert residual_curve("a", res, 0, tm, measured).time_s.size == tm.size


def test_the_error_model_after_the_switch_is_not_the_trials_still_closing_alone() -> None:
    """Six trials of the ramp end at the limit 0-0.8 s after the simulated switch.  Learnt from
    the closings alone, the errors after the switch are at most 0 (the measurement still
    rises), and a prediction long after it stays below the limit; with the closings held at
    the limit the errors there are zero and the predictive force reaches the limit."""
    res = RampModel().simulate(np.array([[100.0, 1.0]]), ["a"])["a"]
    lags = np.linspace(0.0, 0.8, 6)
    plain, held = [], []
    for k, lag in enumerate(lags):
        tm = np.linspace(0.0, T_END + lag, 200)
        measured = 1000.0 * tm / (T_END + lag)  # the same limit, reached lag seconds late
        plain.append(residual_curve_of(res, tm, measured, None, k))
        held.append(residual_curve_of(res, tm, measured, 1000.0, k))
    late = np.array([-0.1 * TRAVEL])  # 1 s after the simulated switch
    q_plain, q_held = fit_discrepancy(plain), fit_discrepancy(held)
    assert q_plain is not None and q_held is not None
    assert q_plain.quantile(late, np.array([0.5]))[0] < -15.0
    assert q_held.quantile(late, np.array([0.5]))[0] == pytest.approx(0.0, abs=1e-9)
    theta = np.array([[100.0, 1.0]])
    bands = predictive_bands(RampModel(), theta, ["c"], {}, {}, np.random.default_rng(5),
                             discrepancy=q_held, force_limit_kN={"c": 1000.0})["c"]
    end = bands.time_s > 1.08 * T_END
    np.testing.assert_allclose(bands.force_pred_kN[2, end], 1000.0, atol=1e-6)
    assert np.all(bands.force_pred_mean_kN[end] > 995.0)
    before = predictive_bands(RampModel(), theta, ["c"], {}, {}, np.random.default_rng(5),
                              discrepancy=q_plain, force_limit_kN={"c": 1000.0})["c"]
    assert np.all(before.force_pred_kN[2, end] < 985.0)


def test_the_far_bins_past_the_switch_hold_every_trial_that_ended_at_the_limit() -> None:
    """Four trials end at the limit with the simulated switch, two 1.5 and 2 s later:
    1.2 s after the switch (d = -0.6 mm, past the on-time trials' own horizon of 1.1 times
    their closing) four of six sit at the limit, so the median error is 0, while the two
    still closing keep the lower quantiles below it.  Each curve continued only to its own
    horizon would leave that bin to the late trials alone."""
    res = RampModel().simulate(np.array([[100.0, 1.0]]), ["a"])["a"]
    curves = []
    for k, lag in enumerate((0.0, 0.0, 0.0, 0.0, 1.5, 2.0)):
        tm = np.linspace(0.0, T_END + lag, 200)
        curves.append(residual_curve_of(res, tm, 1000.0 * tm / (T_END + lag), 1000.0, k))
    assert all(c.held for c in curves)
    model = fit_discrepancy(curves)
    assert model is not None
    far = np.array([-0.12 * TRAVEL])
    assert model.quantile(far, np.array([0.5]))[0] == pytest.approx(0.0, abs=1e-9)
    assert model.quantile(far, np.array([0.05]))[0] < -20.0


def residual_curve_of(res: SimpleNamespace, tm: np.ndarray, fm: np.ndarray, limit: float | None,
                      k: int) -> ResidualCurve:
    from smcbayes.posterior.discrepancy import residual_curve

    return residual_curve(f"c{k}", res, 0, tm, fm, limit_kN=limit)
