"""Whole runs of the 1-D solver: analytic Newtonian bar, time-step convergence orders of the
kinematic and marching paths, agreement of the two paths, and the effect of the speed."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest
from numpy.typing import NDArray

from smcbayes.config import MaterialSpec, ProjectConfig
from smcbayes.forward.case import Case, SpeedProfile
from smcbayes.forward.effects import EffectStack, get_effect
from smcbayes.forward.march import march
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.nodes import Nodes
from smcbayes.forward.result import PHASE_FORCE
from smcbayes.forward.squeeze1d import Squeeze1D, Squeeze1DOptions, material_table
from smcbayes.units import KN, MM

Array = NDArray[np.float64]
# a Cross + slip material with a slip threshold inside the flow's stress range
THRESHOLD_SI = {"n": np.array([0.35]), "tau_star": np.array([3e4]), "B": np.array([2e4]),
                "tau_c": np.array([0.05e6]), "m": np.array([1.5])}
MATERIAL = MaterialSpec()  # slip coefficient 1e-8 m/s/Pa^m, threshold exponent 10


def newtonian(mu: float) -> dict[str, list[float]]:
    """User-unit batch of a Newtonian fluid (tau* -> infinity; Cross n = 1 would halve eta0)."""
    return {"n": [0.5], "tau_star_Pa": [1e40], "B_Pa_s": [mu], "tau_c_MPa": [0.05], "m": [1.5]}


def test_newtonian_bar_whole_run_matches_the_analytic_curve(
        make_project: Callable[..., ProjectConfig]) -> None:
    """No slip: F = 8 mu W a^3 V / H^3 with a = a0 H0 / H under speed control; under force
    control dH/dt = -F_lim H^6 / C, C = 8 mu W (a0 H0)^3, until the cavity is full."""
    mu = 1e5
    model = ForwardModel(make_project(material={"slip_coefficient": 0.0}))
    res = model.simulate_params(newtonian(mu))["bar"]
    case = model.cases["bar"]
    assert res.status == ["ok"]
    W, H0, V, F_lim = case.width, case.gap0, case.speed, case.force_limit
    a0 = case.area0 / (2 * W)
    C = 8 * mu * W * (a0 * H0) ** 3
    t, gap, force = res.time_s[0], res.gap_mm[0] * MM, res.force_kN[0] * KN
    closing = res.phase[0] != PHASE_FORCE
    H = H0 - V * t[closing]
    np.testing.assert_allclose(gap[closing], H, rtol=1e-6)
    np.testing.assert_allclose(force[closing], C * V / H**6, rtol=1e-3)
    H_switch = (C * V / F_lim) ** (1 / 6)
    assert H_switch > case.gap_full  # the limit is reached by flow, before the cavity fills
    assert res.switch_time_s[0] == pytest.approx((H0 - H_switch) / V, rel=1e-4)
    hold = ~closing
    H_hold = (H_switch**-5 + 5 * F_lim * (t[hold] - res.switch_time_s[0]) / C) ** -0.2
    np.testing.assert_allclose(gap[hold], np.maximum(H_hold, case.gap_full), rtol=2e-3)
    np.testing.assert_allclose(force[hold], F_lim, rtol=1e-12)


def _case(make_project: Callable[..., ProjectConfig], force_limit_kN: float = 40.0) -> Case:
    """The 60 % bar with a force limit low enough that force control starts near 6.4 mm."""
    case = ForwardModel(make_project()).cases["bar"]
    return dataclasses.replace(case, force_limit=force_limit_kN * KN)


def _kinematic_nodes(case: Case, **options: int) -> Nodes:
    # the fill time is a node of the solver, not an output sample: read it from the nodes
    solver = Squeeze1D(Squeeze1DOptions(**options))
    table = material_table(THRESHOLD_SI, MATERIAL, solver.tau)
    return solver._kinematic(case, THRESHOLD_SI, table)


def _marching_nodes(case: Case, closing_steps: int, stiffness: float = 1e20) -> Nodes:
    """Marching path, forced by a press frame so stiff that it deflects by round-off."""
    solver = Squeeze1D(Squeeze1DOptions(closing_steps=closing_steps))
    table = material_table(THRESHOLD_SI, MATERIAL, solver.tau)
    params = {**THRESHOLD_SI, "k_press": np.array([stiffness])}
    return march(case, params, EffectStack([get_effect("press_compliance")]), table, solver.options)


def _fill_time(nodes: Nodes, case: Case) -> float:
    """Time (s) at which the charge first covers the cavity."""
    n = nodes.count[0]
    full = nodes.area[0, :n] >= case.area_mould * (1 - 1e-12)
    assert full.any()
    return float(nodes.time[0, np.argmax(full)])


def richardson_order(values: list[float]) -> list[float]:
    """Observed orders from results at step counts doubling each time."""
    d = np.abs(np.diff(values))
    return list(np.log2(d[:-1] / d[1:]))


def test_force_control_fill_time_converges_at_second_order_in_hold_steps(
        make_project: Callable[..., ProjectConfig]) -> None:
    case = _case(make_project)
    levels = [8, 16, 32, 64, 128]
    fill = []
    for k in levels:
        nodes = _kinematic_nodes(case, hold_steps=k)
        assert nodes.switch[0] < _fill_time(nodes, case)  # filled under force control
        fill.append(_fill_time(nodes, case))
    orders = richardson_order(fill)
    print(f"\nkinematic path: time to fill vs hold_steps {levels}: {np.round(fill, 5)}, "
          f"orders {np.round(orders, 2)}")
    assert min(orders[1:]) >= 1.7 and max(orders) <= 2.6


def test_marching_fill_time_converges_at_first_order_in_closing_steps(
        make_project: Callable[..., ProjectConfig]) -> None:
    case = _case(make_project)
    levels = [100, 200, 400, 800]
    fill = []
    for k in levels:
        nodes = _marching_nodes(case, k)
        assert nodes.status == ["ok"] and nodes.switch[0] < _fill_time(nodes, case)
        fill.append(_fill_time(nodes, case))
    orders = richardson_order(fill)
    print(f"\nmarching path: time to fill vs closing_steps {levels}: {np.round(fill, 4)}, "
          f"orders {np.round(orders, 2)}")
    assert all(0.8 <= p <= 1.3 for p in orders)
    # both paths converge to the same fill time
    reference = _fill_time(_kinematic_nodes(case, hold_steps=256, closing_steps=1200), case)
    assert fill[-1] == pytest.approx(reference, rel=5e-3)


def test_marching_and_kinematic_paths_agree_under_speed_control(
        make_project: Callable[..., ProjectConfig]) -> None:
    case = _case(make_project)
    kin, mar = _kinematic_nodes(case, closing_steps=300), _marching_nodes(case, 300)
    assert mar.switch[0] == pytest.approx(kin.switch[0], rel=1e-6)
    n = int(np.searchsorted(kin.time[0], kin.switch[0]))  # nodes strictly before the switch
    np.testing.assert_allclose(mar.force[0, :n], kin.force[0, :n], rtol=1e-9)
    np.testing.assert_allclose(mar.gap[0, :n], kin.gap[0, :n], rtol=1e-9)


def test_a_ram_profile_logged_into_the_hold_paces_the_closing_by_its_own_speed(
        make_project: Callable[..., ProjectConfig]) -> None:
    """A measured profile at the set speed whose log runs on through a long hold gives the
    constant-speed run: its steps follow the closing's mean speed, not the whole log's
    (paced by the log, 300 steps became 6 nodes before the limit here, and the limit came
    0.03 s early)."""
    case = _case(make_project)
    closing_s = (case.gap0 - case.gap_full) / case.speed
    log_s = np.array([0.0, 1.5 * closing_s, 1.5 * closing_s + 500.0])
    log_m = np.array([0.0, 1.5 * closing_s * case.speed, 1.5 * closing_s * case.speed])
    profiled = dataclasses.replace(case, profile=SpeedProfile(log_s, log_m))
    steady, logged = _marching_nodes(case, 300), _marching_nodes(profiled, 300)
    assert logged.switch[0] == pytest.approx(steady.switch[0], rel=1e-9)
    n = int(steady.count[0])
    np.testing.assert_array_equal(logged.count, steady.count)
    np.testing.assert_allclose(logged.force[0, :n], steady.force[0, :n], rtol=1e-9)


def test_a_ram_profile_that_ends_at_rest_fails_at_once(make_project: Callable[..., ProjectConfig]) -> None:
    # 1 mm of travel and the log is over: the limit (near 1.6 mm) is never reached.  Rigid
    # frame: the stiff frame of _marching_nodes makes the balance of a ram at rest degenerate
    case = _case(make_project)
    log = SpeedProfile(np.array([0.0, 4.0, 5.0]), np.array([0.0, 1e-3, 1e-3]))
    solver = Squeeze1D(Squeeze1DOptions(closing_steps=300))
    table = material_table(THRESHOLD_SI, MATERIAL, solver.tau)
    nodes = march(dataclasses.replace(case, profile=log), THRESHOLD_SI, EffectStack([]), table,
                  solver.options)
    assert nodes.status[0] == "failed: the measured ram profile ends at rest before the force limit"
    assert nodes.count[0] < 400  # stopped where the log ends, not at the iteration budget


def test_the_time_a_ram_profile_takes_for_a_further_travel() -> None:
    """Closes 2 mm in 2 s, pauses 1 s, opens 0.5 mm (a pause for the closing), recloses at
    1 mm/s; past the log it runs on at its last speed, or not at all."""
    log = SpeedProfile(np.array([0.0, 2.0, 3.0, 4.0, 5.0]), np.array([0.0, 2.0, 2.0, 1.5, 2.5]) * 1e-3)
    mm = 1e-3
    assert log.time_after(0.0, 1.0 * mm) == pytest.approx(1.0)
    assert log.time_after(1.5, 0.5 * mm) == pytest.approx(2.0)  # exactly at a sample
    assert log.time_after(1.5, 1.0 * mm) == pytest.approx(4.5)  # the pause and the opening pass
    assert log.time_after(4.5, 1.0 * mm) == pytest.approx(5.5)  # past the log at 1 mm/s
    assert log.time_after(6.0, 0.5 * mm) == pytest.approx(6.5)  # starting past the log
    assert log.time_after(2.5, 0.0) == 2.5
    assert np.isnan(log.time_after(np.nan, 1.0 * mm)) and np.isnan(log.time_after(1.0, np.nan))
    at_rest = SpeedProfile(np.array([0.0, 2.0, 3.0]), np.array([0.0, 2.0, 2.0]) * 1e-3)
    assert at_rest.time_after(1.0, 1.0 * mm) == pytest.approx(2.0)  # the last of the log
    assert at_rest.time_after(1.0, 1.5 * mm) == np.inf


def test_slower_speed_reaches_the_limit_later(make_project: Callable[..., ProjectConfig]) -> None:
    batch = {"n": [0.4], "tau_star_Pa": [1e4], "B_Pa_s": [1e5], "tau_c_MPa": [1.0], "m": [1.0]}
    switch, gap = {}, {}
    for speed in (0.3, 0.7, 1.1):
        model = ForwardModel(make_project(press={"speed_mm_s": speed, "force_limit_kN": 150.0}))
        res = model.simulate_params(batch)["bar"]
        assert res.status == ["ok"]
        switch[speed] = res.switch_time_s[0]
        gap[speed] = np.interp(switch[speed], res.time_s[0], res.gap_mm[0])
        assert gap[speed] > model.cases["bar"].gap_full / MM  # limit reached by flow
    assert switch[0.3] > switch[0.7] > switch[1.1]
    # slower closing needs less force at the same gap, so it also closes further
    assert gap[0.3] < gap[0.7] < gap[1.1]
