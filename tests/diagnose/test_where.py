"""Where the gap lies: windows, words and a verdict computed from the residuals."""

from __future__ import annotations

import numpy as np

from smcbayes.diagnose.where import analyse, time_window, window_words


def test_time_window_finds_the_shortest_run_holding_the_share() -> None:
    profile = np.zeros(10)
    profile[7:] = 1.0
    assert time_window(profile, 0.6) == (7, 9)
    assert time_window(profile, 1.0) == (7, 10)
    flat = np.ones(10)
    i, j = time_window(flat, 0.5)
    assert j - i == 5


def test_window_words_name_the_part_of_the_closing() -> None:
    assert window_words(7, 10, 10) == "the last 30 % of the closing"
    assert window_words(0, 2, 10) == "the first 20 % of the closing"
    assert window_words(4, 7, 10) == "the closing between 40 % and 70 % of its duration"
    assert window_words(0, 10, 10) == "the whole closing"


def test_verdict_follows_the_data(synthetic_ctx) -> None:
    """Data with a compliant press vs a curing resin: different misfit, different verdict."""
    press = synthetic_ctx("press_compliance")
    cure = synthetic_ctx("curing")
    rep_p = analyse(press, (), press.start(()), press.ids)
    rep_c = analyse(cure, (), cure.start(()), cure.ids)
    assert rep_p.verdict != rep_c.verdict
    # the compliant press closes the gap later: the rigid model reaches the limit early
    assert rep_p.focus["limit_lag_s"] < -0.1
    assert "early" in rep_p.verdict
    # curing stiffens the slow (long) closing most: the 0.3 mm/s trial carries the misfit
    assert rep_c.focus["configurations"] == ["60-bar-03"]
    assert rep_c.focus["mean_residual_kN"] > 0 and "above" in rep_c.verdict
    # the parts of the error split add up to each configuration's MSE
    np.testing.assert_allclose(rep_p.split_kN2.sum(axis=1), rep_p.mse_kN2, rtol=1e-9)
    assert rep_p.heat_kN.shape == (3, rep_p.bins.size)


def test_no_effect_data_leave_noise_sized_residuals(synthetic_ctx) -> None:
    ctx = synthetic_ctx(None)
    rep = analyse(ctx, (), ctx.start(()), ctx.ids)
    # white 2 kN + correlated 3 kN: an RMS misfit of the order of 3.6 kN
    assert np.sqrt(np.mean(rep.mse_kN2)) < 8.0
