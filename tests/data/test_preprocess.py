"""Pre-processing of measured curves against hand-computed cases and closed forms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smcbayes.data import preprocess as pp
from smcbayes.data.curve import Curve
from smcbayes.errors import DataError

SOURCE = Path("press.csv")


def force(t: np.ndarray, v: np.ndarray) -> Curve:
    return Curve(np.asarray(t, float), np.asarray(v, float), "force", "kN", SOURCE)


def pressing() -> Curve:
    """Idle at 0.5 kN until 2 s, a linear rise of 10 kN/s to 50.5 kN at 7 s, a hold to 9 s,
    a fall back to idle at 10 s, idle to 12 s; sampled every 0.5 s."""
    t = np.arange(0.0, 12.01, 0.5)
    v = np.interp(t, [0.0, 2.0, 7.0, 9.0, 10.0, 12.0], [0.5, 0.5, 50.5, 50.5, 0.5, 0.5])
    return force(t, v)


def test_crossing_time_interpolates_linearly_and_none_when_never_reached() -> None:
    """First crossing of a level between two samples, at the first sample if already above."""
    c = force([0.0, 1.0, 2.0, 3.0], [0.0, 2.0, 6.0, 1.0])
    assert pp.crossing_time(c, 4.0) == pytest.approx(1.5)
    assert pp.crossing_time(c, 2.0) == pytest.approx(1.0)
    assert pp.crossing_time(c, -1.0) == 0.0
    assert pp.crossing_time(c, 6.5) is None


def test_cut_keeps_inner_samples_and_interpolates_the_ends() -> None:
    c = force([0.0, 1.0, 2.0, 3.0], [0.0, 10.0, 20.0, 40.0])
    out = pp.cut(c, 0.5, 2.5)
    np.testing.assert_allclose(out.time_s, [0.5, 1.0, 2.0, 2.5])
    np.testing.assert_allclose(out.values, [5.0, 10.0, 20.0, 30.0])
    whole = pp.cut(c, -5.0, 99.0)  # clamped to the curve's own range
    np.testing.assert_allclose(whole.time_s, c.time_s)
    np.testing.assert_allclose(whole.values, c.values)


def test_trim_idle_keeps_the_pressing_with_one_idle_sample_before_contact() -> None:
    """Start: last sample below the threshold before contact; end: first below it after the peak."""
    c = pressing()
    start, end, text = pp.trim_idle(c, 2.0)
    # 0.5 + 10 (t - 2) >= 2 from t = 2.15 s: the first sample at or above is 2.5 s
    assert start == 2.0
    # after the peak the force falls 50 kN/s from 9 s: below 2 kN after 9.97 s -> sample 10 s
    assert end == 10.0
    assert "2.000-10.000 s" in text and "0.000-12.000 s" in text
    with pytest.raises(DataError, match="never reaches 60 kN"):
        pp.trim_idle(c, 60.0)


def test_trim_idle_keeps_the_end_when_the_force_never_falls_back() -> None:
    t = np.arange(0.0, 5.01, 1.0)
    start, end, _ = pp.trim_idle(force(t, [0.0, 0.0, 3.0, 6.0, 9.0, 9.0]), 1.0)
    assert (start, end) == (1.0, 5.0)


def test_zero_at_contact_shifts_time_to_the_threshold_crossing() -> None:
    c = pressing()
    out, tc, text = pp.zero_at_contact(c, 2.0)
    assert tc == pytest.approx(2.15)
    assert out.time_s[0] == 0.0 and out.values[0] == pytest.approx(2.0)
    # the later samples are kept, moved by tc, with their values
    np.testing.assert_allclose(out.time_s[1:], c.time_s[c.time_s > tc] - tc)
    np.testing.assert_allclose(out.values[1:], c.values[c.time_s > tc])
    assert "2.1500 s" in text
    with pytest.raises(DataError, match="contact threshold"):
        pp.zero_at_contact(c, 100.0)


def test_split_at_limit_is_where_the_force_first_reaches_98_percent() -> None:
    c = pressing()
    ts, _ = pp.split_at_limit(c, 50.0)
    # 0.5 + 10 (t - 2) = 49 -> t = 6.85 s
    assert ts == pytest.approx(2.0 + (0.98 * 50.0 - 0.5) / 10.0)
    with pytest.raises(DataError, match="maximum 50.5 kN"):
        pp.split_at_limit(c, 1000.0)


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_hold_from_travel_is_relative_and_negative_when_closing(direction: float) -> None:
    """Whatever the sign convention of the position, continued closing gives negative values."""
    t = np.arange(0.0, 10.01, 1.0)
    position = direction * np.where(t < 4.0, 2.0 * t, 8.0 + 0.1 * (t - 4.0))  # keeps closing slowly
    travel = Curve(t, position, "position", "mm", SOURCE)
    hold, _ = pp.hold_from_travel(travel, 4.0)
    np.testing.assert_allclose(hold.time_s, t[t >= 4.0] - 4.0)
    np.testing.assert_allclose(hold.values, -0.1 * hold.time_s, atol=1e-12)
    assert hold.quantity == "displacement" and hold.unit == "mm"


def test_savgol_reproduces_polynomials_up_to_its_order() -> None:
    """Savitzky-Golay is exact on polynomials of degree <= order, edges included."""
    t = np.linspace(0.0, 10.0, 201)  # dt = 0.05 s
    cubic = 3.0 - 2.0 * t + 0.4 * t**2 - 0.03 * t**3
    out, text = pp.savgol(force(t, cubic), 0.5, 3)
    np.testing.assert_allclose(out.time_s, t, atol=1e-12)
    np.testing.assert_allclose(out.values, cubic, atol=1e-9)
    assert "window 11 samples" in text and "order 3" in text


def test_savgol_reduces_white_noise_and_resamples_uneven_times() -> None:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.choice([0.01, 0.01, 0.01, 0.02], size=2000))  # median spacing 0.01 s
    signal = 100.0 * np.sin(t / 3.0)
    noisy = force(t, signal + rng.standard_normal(t.size))
    out, text = pp.savgol(noisy, 0.3, 2)
    np.testing.assert_allclose(np.diff(out.time_s), 0.01, rtol=1e-6)
    assert out.time_s[0] == t[0] and out.time_s[-1] <= t[-1]
    residual = out.values - 100.0 * np.sin(out.time_s / 3.0)
    # a 31-point quadratic fit leaves about sqrt(0.15) of the noise sd in the interior
    assert np.std(residual[50:-50]) < 0.5
    assert "window 31 samples" in text


def test_savgol_rejects_a_window_not_longer_than_the_order() -> None:
    c = force(np.linspace(0.0, 1.0, 11), np.zeros(11))
    with pytest.raises(DataError, match="smooth_window_s"):
        pp.savgol(c, 0.2, 3)  # 3 samples, order 3
    with pytest.raises(DataError, match="smooth_window_s"):
        pp.savgol(c, 5.0, 3)  # longer than the curve


def test_resample_is_uniform_from_the_first_sample_and_exact_on_lines() -> None:
    t = np.array([1.0, 1.3, 2.9, 4.0, 5.05])
    out, text = pp.resample(force(t, 2.0 + 3.0 * t), 0.25)
    np.testing.assert_allclose(out.time_s, 1.0 + 0.25 * np.arange(17))
    np.testing.assert_allclose(out.values, 2.0 + 3.0 * out.time_s)
    assert "17 points every 0.25 s" in text
    with pytest.raises(DataError, match="fewer than 2"):
        pp.resample(force(t, t), 10.0)


def test_flow_stop_time_is_thesis_eq_4_1() -> None:
    """h_flow = coverage * h_init; travel (1 - coverage) h_init at the set speed."""
    assert pp.flow_stop_time(8.0, 0.6, 0.4) == pytest.approx(8.0)
    assert pp.flow_stop_time(8.0, 1.0, 0.4) == 0.0
    assert pp.flow_stop_time(10.0, 0.8, 1.0) == pytest.approx(2.0)


def test_clip_modes_end_the_force_curve_at_their_time() -> None:
    c = pressing()
    flow, text = pp.clip_flow_stop(c, 4.2)
    assert flow.time_s[-1] == 4.2 and flow.values[-1] == pytest.approx(0.5 + 10.0 * 2.2)
    assert np.all(flow.time_s <= 4.2) and "4.2000 s" in text
    limit, _ = pp.clip_force_limit(c, 30.0)
    assert limit.time_s[-1] == pytest.approx(2.0 + 29.5 / 10.0)
    assert limit.values[-1] == pytest.approx(30.0) and limit.values.max() == pytest.approx(30.0)
    same, text = pp.clip_force_limit(c, 80.0)
    assert same is c and "not reached" in text
