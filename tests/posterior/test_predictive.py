"""Predictive bands: quantiles of the draws' curves, added noise, coverage counting.

The forward model is replaced by a stand-in whose curves are known in closed form
(force = a t for a draw with parameter a), so every band has a hand-computable value.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from smcbayes.posterior.predictive import QUANTILES, predictive_bands


class LinearModel:
    """``simulate(theta, ids)``: force a t and displacement -b t on 0..T, switch at T."""

    def __init__(self, t_end: float = 10.0, failed: tuple[int, ...] = ()) -> None:
        self.t_end = t_end
        self.failed = failed

    def simulate(self, theta: np.ndarray, ids: list[str]) -> dict[str, SimpleNamespace]:
        t = np.linspace(0.0, self.t_end, 51)
        out = {}
        for cid in ids:
            a = theta[:, 0][:, None]
            force = a * t[None, :]
            disp = -theta[:, 1][:, None] * t[None, :]
            ok = np.ones(theta.shape[0], dtype=bool)
            ok[list(self.failed)] = False
            force[~ok] = np.nan
            out[cid] = SimpleNamespace(ok=ok, time_s=np.tile(t, (theta.shape[0], 1)), force_kN=force,
                                       displacement_mm=disp,
                                       switch_time_s=np.full(theta.shape[0], self.t_end))
        return out


def test_model_bands_are_the_quantiles_of_the_draws_and_noise_free_prediction_equals_them() -> None:
    rng = np.random.default_rng(0)
    a = rng.uniform(1.0, 3.0, 200)
    theta = np.column_stack([a, 0.1 * a])
    bands = predictive_bands(LinearModel(), theta, ["c"], {}, {"c": 0.0}, rng, grid_points=101)
    b = bands["c"]
    np.testing.assert_allclose(b.time_s, np.linspace(0.0, 11.0, 101))  # switch time x 1.1
    qa = np.quantile(a, QUANTILES)
    inside = b.time_s <= 10.0
    np.testing.assert_allclose(b.force_kN[:, inside], qa[:, None] * b.time_s[None, inside], rtol=1e-12)
    np.testing.assert_allclose(b.force_kN[:, ~inside],
                               np.broadcast_to(qa[:, None] * 10.0, (5, (~inside).sum())))
    # the displacement quantiles of -0.1 a t are those of a reversed
    np.testing.assert_allclose(b.displacement_mm[:, inside], -0.1 * qa[::-1, None] * b.time_s[None, inside],
                               rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(b.force_pred_kN, b.force_kN)
    assert b.draws == 200 and b.noise_kN == 0.0 and b.measured is None
    assert np.isnan(b.coverage50) and np.isnan(b.coverage90)


def test_predictive_bands_add_gaussian_noise_of_the_given_sd_clipped_at_zero() -> None:
    """Zero force: the predictive quantiles are sigma times the normal ones, those below 0 kN
    clipped to 0 (a press does not pull)."""
    rng = np.random.default_rng(1)
    theta = np.zeros((4000, 2))
    b = predictive_bands(LinearModel(), theta, ["c"], {}, {"c": 5.0}, rng, grid_points=50)["c"]
    z = np.array([-1.6449, -0.6745, 0.0, 0.6745, 1.6449])
    np.testing.assert_allclose(np.median(b.force_pred_kN, axis=1), 5.0 * np.maximum(z, 0.0), atol=0.15)
    np.testing.assert_allclose(b.force_kN, 0.0)
    assert b.error_model == "white noise"
    # the point prediction is the mean of the clipped draws: sigma / sqrt(2 pi), not 0
    np.testing.assert_allclose(b.force_pred_mean_kN, 5.0 / np.sqrt(2.0 * np.pi), atol=0.2)


def test_noise_of_a_configuration_without_its_own_is_the_mean_of_the_others() -> None:
    rng = np.random.default_rng(2)
    theta = np.ones((20, 2))
    bands = predictive_bands(LinearModel(), theta, ["a", "new"], {}, {"a": 2.0, "b": 4.0}, rng)
    assert bands["a"].noise_kN == 2.0 and bands["new"].noise_kN == 3.0


def test_failed_draws_are_left_out() -> None:
    rng = np.random.default_rng(3)
    a = np.linspace(1.0, 2.0, 11)
    theta = np.column_stack([a, a])
    b = predictive_bands(LinearModel(failed=(0, 10)), theta, ["c"], {}, {"c": 0.0}, rng)["c"]
    assert b.draws == 9 and np.all(np.isfinite(b.force_kN))
    np.testing.assert_allclose(b.force_kN[:, -1], np.quantile(a[1:10], QUANTILES) * 10.0)


def test_coverage_counts_measured_points_inside_the_predictive_bands() -> None:
    """Measured = median + offsets placed inside/outside the 50 % and 90 % bands by hand."""
    rng = np.random.default_rng(4)
    theta = np.column_stack([np.linspace(1.0, 3.0, 101), np.ones(101)])  # quantiles of a are exact
    tm = np.linspace(1.0, 9.0, 8)
    qa = np.quantile(theta[:, 0], QUANTILES)
    # a per point: two inside the 50 % band, three only inside the 90 %, three outside
    a_meas = np.array([qa[2], 0.5 * (qa[1] + qa[3]), 0.5 * (qa[0] + qa[1]), 0.5 * (qa[3] + qa[4]),
                       0.5 * (qa[3] + qa[4]), 0.9 * qa[0], 1.1 * qa[4], 1.2 * qa[4]])
    measured = {"c": (tm, a_meas * tm)}
    b = predictive_bands(LinearModel(), theta, ["c"], measured, {"c": 0.0}, rng, grid_points=2001)["c"]
    assert b.coverage50 == pytest.approx(2 / 8)
    assert b.coverage90 == pytest.approx(5 / 8)
    assert b.measured is measured["c"]


def test_coverage_of_data_drawn_like_the_model_is_about_nominal() -> None:
    """Measured points that are model + noise fall in the 50 / 90 % bands about that often."""
    rng = np.random.default_rng(5)
    theta = np.column_stack([rng.normal(2.0, 0.1, 2000), np.ones(2000)])
    tm = np.linspace(0.5, 10.0, 400)
    fm = rng.normal(2.0, 0.1) * tm + rng.normal(0.0, 1.0, tm.size)
    b = predictive_bands(LinearModel(), theta, ["c"], {"c": (tm, fm)}, {"c": 1.0}, rng)["c"]
    assert 0.40 < b.coverage50 < 0.60
    assert 0.84 < b.coverage90 < 0.96


def test_the_point_prediction_is_the_predictive_mean_not_the_median() -> None:
    """Draws of slopes 1, 2 and 6 without noise: the median curve is 2 t, the predictive mean
    3 t.  A measurement of 3 t has zero RMSE against the mean and the RMSE of t against the
    median."""
    rng = np.random.default_rng(8)
    theta = np.column_stack([[1.0, 2.0, 6.0], np.ones(3)])
    tm = np.linspace(0.5, 9.5, 10)
    b = predictive_bands(LinearModel(), theta, ["c"], {"c": (tm, 3.0 * tm)}, {"c": 0.0}, rng,
                         grid_points=2201)["c"]
    inside = b.time_s <= 10.0
    np.testing.assert_allclose(b.force_pred_mean_kN[inside], 3.0 * b.time_s[inside], atol=1e-9)
    np.testing.assert_allclose(b.force_kN[2][inside], 2.0 * b.time_s[inside], atol=1e-9)
    assert b.rmse_mean_kN == pytest.approx(0.0, abs=1e-9)
    assert b.rmse_median_kN == pytest.approx(float(np.sqrt(np.mean(tm**2))), rel=1e-9)


def test_the_predictive_mean_averages_over_the_contact_delays() -> None:
    """One draw, force t up to 10 s, taken at delays 0 and 2 s: the mean is the average of
    t and (t - 2) clipped to [0, 10]."""
    rng = np.random.default_rng(9)
    theta = np.array([[1.0, 1.0]])
    b = predictive_bands(LinearModel(), theta, ["c"], {}, {"c": 0.0}, rng, grid_points=1321,
                         delays_s={"c": np.array([0.0, 2.0])})["c"]
    t = b.time_s
    expected = 0.5 * (np.minimum(t, 10.0) + np.clip(t - 2.0, 0.0, 10.0))
    np.testing.assert_allclose(b.force_pred_mean_kN, expected, atol=1e-9)


def test_the_grid_extends_past_the_last_measured_point() -> None:
    """Measured points after the simulated switch are compared with the held end values."""
    rng = np.random.default_rng(6)
    theta = np.column_stack([np.linspace(0.5, 1.5, 41), np.ones(41)])
    tm = np.linspace(1.0, 20.0, 5)
    b = predictive_bands(LinearModel(), theta, ["c"], {"c": (tm, np.minimum(tm, 10.0))}, {"c": 0.0},
                         rng)["c"]
    assert b.time_s[-1] == pytest.approx(20.0 * 1.02)
    assert b.coverage90 == 1.0 and b.coverage50 == 1.0
    b = predictive_bands(LinearModel(), theta, ["c"], {"c": (tm, tm)}, {"c": 0.0}, rng)["c"]
    assert b.coverage90 == pytest.approx(3 / 5)  # 15.25 and 20 kN lie above the held 5.5-14.5 kN


def test_a_configuration_where_every_draw_failed_gives_an_empty_band() -> None:
    rng = np.random.default_rng(7)
    theta = np.column_stack([np.linspace(1.0, 2.0, 3), np.ones(3)])
    bands = predictive_bands(LinearModel(failed=(0, 1, 2)), theta, ["c"], {}, {"c": 1.0}, rng)
    assert bands["c"].draws == 0 and bands["c"].force_pred_mean_kN is None
