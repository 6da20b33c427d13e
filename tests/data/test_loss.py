"""The loss (thesis eq. 3.5-3.7): hand-computed values, zero self-loss, clipping, batching."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smcbayes.data.breakdown import force_breakdown, split_error
from smcbayes.data.dataset import load_dataset
from smcbayes.data.loss import LossSpec, evaluate_loss, interp_rows
from smcbayes.errors import DataError
from smcbayes.forward.nodes import apply_weights, row_weights


def _dataset(dh, tmp_path: Path):
    dh.write_text(tmp_path / "force" / "c1.csv", "time_s,force_kN\n0,0\n1,100\n2,300\n")
    dh.write_text(tmp_path / "hold" / "c1.csv", "time_s,displacement_mm\n0.5,-0.1\n1.5,-0.2\n")
    proj = dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv", "hold": "hold/c1.csv"})])
    return load_dataset(proj)


def _sim(dh):
    return dh.sim_result("c1", [0, 1, 1.5, 3], [0, 150, 300, 300], [1.5],
                      displacement_mm=[0, 1, 1.5, 1.8])


def test_hand_computed_force_and_displacement(dh, tmp_path: Path) -> None:
    ds = _dataset(dh, tmp_path)
    # 8 mm stack, 50 % coverage: h_flow = 4 mm, reached after 4 mm / (4 mm/s) = 1 s.
    assert ds["c1"].flow_stop_s == pytest.approx(1.0)
    res = evaluate_loss({"c1": _sim(dh)}, ds, LossSpec(grid_points=5, w_displacement=2.0))
    # grid 0, .5, 1, 1.5, 2: sim held at 300 after 1.5 s -> 0 75 150 300 300 vs 0 50 100 200 300
    assert res.force_mse_kN2[0, 0] == pytest.approx((25**2 + 50**2 + 100**2) / 5)
    # hold: tau 0 .375 .75 1.125 1.5; sim 0 -.075 -.15 -.225 -.3; meas (0 at start) 0 -.075 -.125 -.1625 -.2
    e_d = (0.025**2 + 0.0625**2 + 0.1**2) / 5
    assert res.displacement_mse_mm2[0, 0] == pytest.approx(e_d)
    assert res.total[0] == pytest.approx(2625.0 + 2.0 * e_d)
    assert res.per_config()["c1"][0] == pytest.approx(2625.0 + 2.0 * e_d)
    assert res.ids == ["c1"] and bool(res.ok[0])


def test_thesis_clipped_loss_at_flow_stop(dh, tmp_path: Path) -> None:
    ds = _dataset(dh, tmp_path)
    res = evaluate_loss({"c1": _sim(dh)}, ds, LossSpec(grid_points=5, clip="flow_stop"))
    # grid 0 .25 .5 .75 1: sim 0 37.5 75 112.5 150 vs meas 0 25 50 75 100
    assert res.total[0] == pytest.approx((12.5**2 + 25**2 + 37.5**2 + 50**2) / 5)


def test_force_limit_clip_removes_overshoot(dh, tmp_path: Path) -> None:
    dh.write_text(tmp_path / "force" / "c1.csv", "time_s,force_kN\n0,0\n1,100\n2,300\n2.1,330\n")
    ds = load_dataset(dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv"})]))
    sim = {"c1": dh.sim_result("c1", [0, 1, 2, 3], [0, 100, 300, 300], [2.0])}
    assert evaluate_loss(sim, ds, LossSpec(clip="force_limit")).total[0] == pytest.approx(0.0, abs=1e-18)
    assert evaluate_loss(sim, ds, LossSpec(clip="none")).total[0] > 1.0


def test_a_limit_reached_at_first_contact_is_a_switch_not_a_perfect_fit(dh, tmp_path: Path) -> None:
    ds = _dataset(dh, tmp_path)
    stuck = {"c1": dh.sim_result("c1", [0, 100, 500], [300, 300, 300], [0.0])}
    # the measured 0-100-300 ramp over 2 s against 300 throughout
    expected = np.mean((300 - np.interp(np.linspace(0, 2, 5), [0, 1, 2], [0, 100, 300])) ** 2)
    res = evaluate_loss(stuck, ds, LossSpec(grid_points=5))
    assert res.force_mse_kN2[0, 0] == pytest.approx(expected)


def test_curve_against_itself_is_zero(dh, tmp_path: Path) -> None:
    t = np.linspace(0, 5, 60)
    f = 300 * (t / 5) ** 3
    body = "\n".join(f"{a:.17g},{b:.17g}" for a, b in zip(t, f, strict=False))
    dh.write_text(tmp_path / "force" / "c1.csv", "time_s,force_kN\n" + body + "\n")
    ds = load_dataset(dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv"})]))
    sim = {"c1": dh.sim_result("c1", np.append(t, 505.0), np.append(f, 300.0), [5.0])}
    for clip in ("none", "flow_stop", "force_limit"):
        res = evaluate_loss(sim, ds, LossSpec(clip=clip))
        assert res.total[0] == pytest.approx(0.0, abs=1e-18)


def test_batch_equals_rows_and_failed_rows_are_nan(dh, tmp_path: Path) -> None:
    ds = _dataset(dh, tmp_path)
    rng = np.random.default_rng(3)
    P = 7
    ts = rng.uniform(0.8, 2.5, P)
    t = np.stack([np.array([0, 0.3 * s, s, s + 500]) for s in ts])
    f = np.stack([[0, rng.uniform(10, 200), 300, 300] for _ in range(P)])
    status = ["ok"] * P
    status[4] = "failed: test"
    t_bad = t.copy()
    t_bad[4] = np.nan
    batch = dh.sim_result("c1", t_bad, f, ts, status=status)
    res = evaluate_loss({"c1": batch}, ds)
    for p in range(P):
        one = evaluate_loss({"c1": dh.sim_result("c1", t[p], f[p], ts[p:p + 1])}, ds).total[0]
        if p == 4:
            assert np.isnan(res.total[p]) and not res.ok[p]
        else:
            assert res.total[p] == pytest.approx(one, rel=1e-12)


def test_interp_rows_matches_numpy() -> None:
    rng = np.random.default_rng(0)
    xp = np.cumsum(rng.uniform(0.01, 1, (5, 30)), axis=1)
    fp = rng.normal(size=(5, 30))
    x = rng.uniform(-1, 20, (5, 40))
    out = interp_rows(x, xp, fp)
    for p in range(5):
        np.testing.assert_allclose(out[p], np.interp(x[p], xp[p], fp[p]), rtol=1e-12, atol=1e-12)


def test_interp_rows_on_sorted_grids_padded_nodes_and_nan() -> None:
    """The walk along rising queries, queries that fall back (bisection), repeated (padded)
    nodes, a flat row, NaN queries and one-node rows give what numpy.interp gives, and the
    weights of row_weights give the same values."""
    rng = np.random.default_rng(1)
    xp = np.cumsum(rng.uniform(0.0, 1, (6, 25)), axis=1)
    xp[:, 18:] = xp[:, 17:18]  # padded past the row's end
    xp[2, 5:8] = xp[2, 4]  # repeated nodes inside
    xp[4] = 3.0  # a row of one repeated node
    fp = rng.normal(size=(6, 25))
    fp[:, 18:] = fp[:, 17:18]
    x = np.sort(rng.uniform(-1, 20, (6, 50)), axis=1)
    x[:, 10:13] = x[:, 10:11]  # equal queries
    x[1, 30:] = np.linspace(xp[1, 16], xp[1, 1], 20)  # falling back inside the nodes
    x[3, 7] = np.nan
    x[3, 8] = x[3, 6] - 0.5  # a query after the NaN, below the one before it
    x[2, 40:43] = xp[2, 4]  # on the repeated node: its last copy's value
    out = interp_rows(x, xp, fp)
    for p in (0, 1, 3, 5):
        ok = np.isfinite(x[p])
        np.testing.assert_allclose(out[p][ok], np.interp(x[p][ok], xp[p], fp[p]), rtol=1e-12, atol=1e-12)
    on_node = x[2] == xp[2, 4]
    np.testing.assert_allclose(out[2][~on_node], np.interp(x[2][~on_node], xp[2], fp[2]),
                               rtol=1e-12, atol=1e-12)
    assert np.all(out[2][on_node] == fp[2, 7])
    assert np.isnan(out[3, 7]) and np.isfinite(out[3, 8])
    np.testing.assert_array_equal(out[4], fp[4, -1])  # a row of one node holds its last value
    j, w = row_weights(x, xp)
    np.testing.assert_array_equal(apply_weights(fp, j, w), out)
    # one node per row; nodes shared by all rows
    np.testing.assert_array_equal(interp_rows(x[:2], xp[:2, :1], fp[:2, :1]),
                                  np.repeat(fp[:2, :1], 50, axis=1))
    np.testing.assert_allclose(interp_rows(x[:2], xp[:1], fp[:1]), [np.interp(x[0], xp[0], fp[0]),
                                                                    np.interp(x[1], xp[0], fp[0])],
                               rtol=1e-12)


def test_missing_measurement_or_result_is_an_error(dh, tmp_path: Path) -> None:
    ds = _dataset(dh, tmp_path)
    with pytest.raises(DataError, match="no simulation result"):
        evaluate_loss({}, ds)
    with pytest.raises(DataError, match="no measured data"):
        evaluate_loss({"c2": _sim(dh)}, ds, ids=["c2"])


def test_split_parts_add_up_and_find_a_pure_shift() -> None:
    t = np.linspace(0, 10, 401)
    meas = np.tanh(t - 5)[None, :]
    shifted = np.tanh(t - 5.5)[None, :]
    dt = np.array([t[1] - t[0]])
    delta, e_shift, e_amp, e_shape, a = split_error(shifted, meas, dt)
    assert delta[0] == pytest.approx(0.5, abs=0.03)  # the simulation runs 0.5 s late
    assert e_shift[0] == pytest.approx(np.mean((shifted - meas) ** 2), rel=1e-2)
    scaled = 1.3 * meas
    _, e_shift, e_amp, e_shape, a = split_error(scaled, meas, dt)
    assert a[0] == pytest.approx(1 / 1.3) and e_shape[0] == pytest.approx(0.0, abs=1e-20)
    assert e_amp[0] == pytest.approx(np.mean((scaled - meas) ** 2))


def test_breakdown_sums_to_force_mse(dh, tmp_path: Path) -> None:
    ds = _dataset(dh, tmp_path)
    sims = {"c1": _sim(dh)}
    res = evaluate_loss(sims, ds)
    bd = force_breakdown(sims, ds)
    total = bd.shift_kN2 + bd.amplitude_kN2 + bd.shape_kN2
    np.testing.assert_allclose(total, res.force_mse_kN2, rtol=1e-10)
    np.testing.assert_allclose(np.nansum(bd.phase_share, axis=2), 1.0)
    assert bd.phases[3] == "force_control" and bd.phase_share[0, 0, 3] > 0


def _cubic_case(dh, tmp_path: Path, delay_s: float, rows: int = 1):
    """A measured cubic rise to the limit delayed by ``delay_s`` against the undelayed
    simulation of the same curve (speed 4 mm/s: a delay of 0.05 s is a 0.2 mm offset)."""
    t = np.linspace(0, 5, 400)
    f = 300 * (t / 5) ** 3
    tm = np.linspace(0, 5 + delay_s, 400)
    fm = 300 * (np.clip(tm - delay_s, 0, 5) / 5) ** 3
    body = "\n".join(f"{a:.17g},{b:.17g}" for a, b in zip(tm, fm, strict=True))
    dh.write_text(tmp_path / "force" / "c1.csv", "time_s,force_kN\n" + body + "\n")
    ds = load_dataset(dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv"})]))
    sim = dh.sim_result("c1", np.tile(np.append(t, 505.0), (rows, 1)), np.append(f, 300.0), [5.0] * rows)
    return ds["c1"], sim


def test_a_profiled_contact_offset_recovers_a_delayed_trial(dh, tmp_path: Path) -> None:
    """The measured curve comes 0.2 mm / 4 mm/s = 0.05 s later than the simulated one: the
    profiled offset finds 0.2 mm and the error vanishes; at the nominal contact it does not."""
    from smcbayes.data.loss import force_pair

    m, sim = _cubic_case(dh, tmp_path, 0.05, rows=2)
    assert m.speed_mm_s == 4.0
    nominal = force_pair(sim, m, LossSpec())
    assert np.all(nominal.offset_mm == 0.0)
    assert np.mean((nominal.sim_kN[0] - nominal.meas_kN[0]) ** 2) > 10.0
    profiled = force_pair(sim, m, LossSpec(contact_offset_mm=0.3))
    np.testing.assert_allclose(profiled.offset_mm, 0.2, atol=0.005)
    assert np.mean((profiled.sim_kN[0] - profiled.meas_kN[0]) ** 2) < 0.01
    # the same offset given explicitly gives the same pair; the loss sees the profiled one
    given = force_pair(sim, m, LossSpec(contact_offset_mm=0.3), offset_mm=profiled.offset_mm)
    np.testing.assert_allclose(given.sim_kN, profiled.sim_kN)
    # every offset is compared on one window, sized for the largest delay
    late = force_pair(sim, m, LossSpec(contact_offset_mm=0.3), offset_mm=-0.3)
    np.testing.assert_allclose(late.time_s, profiled.time_s)
    ds = load_dataset(dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv"})]))
    loss = evaluate_loss({"c1": sim}, ds, LossSpec(contact_offset_mm=0.3)).total
    assert np.all(loss < 0.01) and evaluate_loss({"c1": sim}, ds, LossSpec()).total[0] > 10.0


def test_a_contact_offset_beyond_the_range_stops_at_its_end(dh, tmp_path: Path) -> None:
    from smcbayes.data.loss import force_pair

    m, sim = _cubic_case(dh, tmp_path, 0.2)  # 0.8 mm later
    pair = force_pair(sim, m, LossSpec(contact_offset_mm=0.3))
    assert pair.offset_mm[0] == pytest.approx(0.3)
    m_early, sim_early = _cubic_case(dh, tmp_path, -0.2)  # the measured curve 0.8 mm earlier
    assert force_pair(sim_early, m_early, LossSpec(contact_offset_mm=0.3)).offset_mm[0] == pytest.approx(-0.3)


def test_a_contact_offset_needs_the_closing_speed(dh, tmp_path: Path) -> None:
    from dataclasses import replace

    from smcbayes.data.loss import force_pair

    m, sim = _cubic_case(dh, tmp_path, 0.05)
    with pytest.raises(DataError, match="set closing speed"):
        force_pair(sim, replace(m, speed_mm_s=None), LossSpec(contact_offset_mm=0.3))
    with pytest.raises(ValueError):
        LossSpec(contact_offset_mm=-0.1)


def test_an_unseen_trial_is_the_mean_of_its_curves_over_the_training_offsets(dh, tmp_path: Path) -> None:
    """Over offsets of -0.4 and +0.4 mm at 4 mm/s the simulated cubic comes 0.1 s early or
    late: the mixed curve is the mean of the two, each held at its switch, on the grid of
    the later one; it is not the curve at the mean offset, and (Jensen) its squared error is
    at most the mean of the two curves' own on the same grid."""
    from smcbayes.data.loss import force_pair, given_force_pair, mixed_force_pair

    m, sim = _cubic_case(dh, tmp_path, 0.0)
    spec = LossSpec()
    mixed = mixed_force_pair(sim, m, spec, [-0.4, 0.4])
    late = force_pair(sim, m, spec, offset_mm=0.4)
    np.testing.assert_allclose(mixed.time_s, late.time_s)
    grid = mixed.time_s[0]
    expected = np.mean([300 * (np.clip(grid - d, 0, 5) / 5) ** 3 for d in (-0.1, 0.1)], axis=0)
    np.testing.assert_allclose(mixed.sim_kN[0], expected, rtol=1e-3, atol=1e-3)  # linear interpolation
    assert mixed.offset_mm[0] == pytest.approx(0.0)
    at_mean = force_pair(sim, m, spec, offset_mm=0.0)
    assert np.max(np.abs(np.interp(grid, at_mean.time_s[0], at_mean.sim_kN[0]) - mixed.sim_kN[0])) > 1.0
    e_mixed = np.mean((mixed.sim_kN[0] - mixed.meas_kN[0]) ** 2)
    e_each = [np.mean((300 * (np.clip(grid - d, 0, 5) / 5) ** 3 - mixed.meas_kN[0]) ** 2)
              for d in (-0.1, 0.1)]
    assert 0.0 < e_mixed <= np.mean(e_each)
    # one offset, or the same one twice, is the pair at it; none is the nominal contact
    for given in ([0.4], (0.4, 0.4), 0.4):
        np.testing.assert_allclose(given_force_pair(sim, m, spec, given).sim_kN, late.sim_kN)
    np.testing.assert_allclose(mixed_force_pair(sim, m, spec, []).sim_kN, at_mean.sim_kN)
    ds = load_dataset(dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv"})]))
    loss = evaluate_loss({"c1": sim}, ds, spec, offsets_mm={"c1": (-0.4, 0.4)})
    assert loss.force_mse_kN2[0, 0] == pytest.approx(e_mixed)
    parts = force_breakdown({"c1": sim}, ds, spec, ["c1"], offsets_mm={"c1": (-0.4, 0.4)})
    total = parts.shift_kN2[0, 0] + parts.amplitude_kN2[0, 0] + parts.shape_kN2[0, 0]
    assert total == pytest.approx(e_mixed, rel=1e-9)
