"""Effects of the 1-D solver: solid-mass conservation in every combination, the
incompressible limit of the compressible charge, and the direction of each effect."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from smcbayes.config import ProjectConfig, load_project
from smcbayes.errors import ConfigError, SmcBayesError
from smcbayes.forward import programme
from smcbayes.forward.case import SpeedProfile
from smcbayes.forward.effects import available, get_effect
from smcbayes.forward.effects.thermal import Curing
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.parameters import to_si
from smcbayes.forward.result import PHASE_FORCE, SimulationResult
from smcbayes.units import ZERO_C_K

Array = NDArray[np.float64]
EFFECTS = ("compressibility", "curing", "heating", "press_compliance", "speed_ramp")
# shear flow matters here (slip starts late), so viscosity effects show in the force
SHEAR = {"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 2e4, "tau_c_MPa": 1.0, "m": 1.5}


def run(project: ProjectConfig, effects: tuple[str, ...] = (), rows: int = 1,
        **values: float | list[float]) -> SimulationResult:
    """Simulate the project's bar with effect defaults and ``values`` (user units)."""
    model = ForwardModel(project, effects=list(effects))
    batch = {k: np.full(rows, v) for k, v in model.space.defaults().items()}
    for name, value in values.items():
        batch[name] = np.broadcast_to(np.asarray(value, dtype=float), (rows,)).copy()
    res = model.simulate_params(batch)["bar"]
    assert all(s == "ok" for s in res.status), res.status
    return res


def closing(res: SimulationResult, row: int = 0) -> NDArray[np.bool_]:
    """Samples before force control."""
    return res.phase[row] != PHASE_FORCE


def test_registry_holds_the_five_effects() -> None:
    assert set(EFFECTS) <= set(available())
    for name in EFFECTS:
        effect = get_effect(name)
        assert effect.description and effect.parameters
        for p in effect.parameters:
            assert p.lower < p.default <= p.upper or p.lower <= p.default < p.upper, p.name


def test_unknown_effect_suggests_the_closest_name() -> None:
    with pytest.raises(ConfigError, match="did you mean 'compressibility'") as err:
        get_effect("compresibility")
    assert isinstance(err.value, SmcBayesError)


@pytest.mark.parametrize("subset", [s for r in range(1, 6) for s in itertools.combinations(EFFECTS, r)],
                         ids=lambda s: "+".join(s))
def test_solid_mass_is_conserved_in_every_combination(
        subset: tuple[str, ...], make_project: Callable[..., ProjectConfig]) -> None:
    """s H A over whole runs (closing, filling, force control, hold), two parameter rows; with
    compressibility one row has a bulk viscosity, so the charge creeps under force control."""
    project = make_project(solver={"closing_steps": 60, "hold_steps": 20})
    extra = {"bulk_viscosity_MPa_s": [0.0, 50.0]} if "compressibility" in subset else {}
    res = run(project, subset, rows=2, **extra)
    solid_volume = res.solid_fraction * res.gap_mm * res.fill_fraction
    np.testing.assert_allclose(solid_volume, solid_volume[:, :1] * np.ones_like(solid_volume), rtol=1e-6)
    assert np.all(res.phase[:, -1] == PHASE_FORCE)
    assert np.all((res.solid_fraction > 0) & (res.solid_fraction <= 1.0 + 1e-12))
    assert np.all(res.fill_fraction <= 1.0)


@pytest.mark.parametrize("values", [{}, SHEAR], ids=["defaults", "shear"])
def test_compressibility_with_solid_fraction_one_is_the_incompressible_model(
        values: dict[str, float], make_project: Callable[..., ProjectConfig]) -> None:
    project = make_project()
    case = ForwardModel(project).cases["bar"]
    apparent_g_cm3 = case.mass / (case.area0 * case.gap0) / 1e3
    base = run(project, **values)
    comp = run(project, ("compressibility",), rho_solid_g_cm3=apparent_g_cm3, **values)
    np.testing.assert_allclose(comp.force_kN, base.force_kN, rtol=1e-6)
    np.testing.assert_allclose(comp.time_s, base.time_s, rtol=1e-6)
    np.testing.assert_allclose(comp.solid_fraction, 1.0, rtol=1e-12)


def test_press_compliance(make_project: Callable[..., ProjectConfig]) -> None:
    """Ram displacement = gap change + F / k; the gap closes slower than the ram while the
    force rises, so the limit is reached later than with a rigid press."""
    k_kN_mm = 100.0
    project = make_project(press={"force_limit_kN": 500.0})
    rigid = run(project, **SHEAR)
    soft = run(project, ("press_compliance",), k_press_kN_mm=k_kN_mm, **SHEAR)
    c = closing(soft)
    t, gap, force = soft.time_s[0, c], soft.gap_mm[0, c], soft.force_kN[0, c]
    rising = np.diff(force) > 0
    gap_speed = -np.diff(gap) / np.diff(t)
    assert rising.sum() > 0.9 * rising.size
    assert np.all(gap_speed[rising] < 0.3)
    # the ram keeps its set speed; the recorded frame deflection is the backward-Euler one,
    # one step ahead, so the ram position is off by at most one step's change of F / k
    step_change = max(force[0], np.max(np.diff(force))) / k_kN_mm
    np.testing.assert_allclose(soft.displacement_mm[0, c], 0.3 * t, rtol=0, atol=1.01 * step_change)
    assert np.all(gap[1:] >= np.interp(t[1:], rigid.time_s[0], rigid.gap_mm[0]) - 1e-12)
    assert soft.switch_time_s[0] > rigid.switch_time_s[0]


@pytest.mark.parametrize("beta", [0.0, 0.5])
def test_a_full_cavity_loads_a_compliant_frame_as_the_ram_runs_on(
        make_project: Callable[..., ProjectConfig], beta: float) -> None:
    """An incompressible charge that fills the cavity well below the limit: the gap stops,
    but the ram runs on and loads the frame, so the limit comes (F_limit - F_fill) / (k U)
    after the fill (with the load slowdown, the closed form of
    :func:`~smcbayes.forward.programme.load_time`), not a jump; the ram's travel keeps
    following the ram through the loading.  On a rigid frame the jump remains."""
    k_kN_mm, limit_kN = 200.0, 500.0
    project = make_project(press={"force_limit_kN": limit_kN})
    fluid = {**SHEAR, "B_Pa_s": 1e3, "tau_c_MPa": 0.01}
    rigid = run(project, ("speed_ramp",), ramp_time_s=0.01, load_slowdown=beta, **fluid)
    soft = run(project, ("press_compliance", "speed_ramp"), k_press_kN_mm=k_kN_mm, ramp_time_s=0.01,
               load_slowdown=beta, **fluid)
    case = ForwardModel(project).cases["bar"]
    for res in (rigid, soft):
        assert res.gap_mm[0, -1] == pytest.approx(case.gap_full / 1e-3, rel=1e-9)
    t_sw = soft.switch_time_s[0]
    full = (soft.gap_mm[0] <= case.gap_full / 1e-3 * (1.0 + 1e-9)) & (soft.time_s[0] <= t_sw)
    t_fill = soft.time_s[0, full][0]
    f_fill = float(np.interp(t_fill, soft.time_s[0], soft.force_kN[0]))
    assert f_fill < 0.3 * limit_kN
    expected = float(programme.load_time(f_fill * 1e3, limit_kN * 1e3, 1e-6 / k_kN_mm, 0.3e-3, beta, 0.05))
    assert expected > 1.0  # seconds, where the rigid frame takes 0.05
    # the fill is known to the output grid's spacing, so the loading time to about two of them
    spacing = t_sw / 200
    assert t_sw - t_fill == pytest.approx(expected, abs=2.5 * spacing)
    loading = soft.time_s[0] <= t_sw
    if beta == 0.0:
        np.testing.assert_allclose(soft.displacement_mm[0, loading], 0.3 * soft.time_s[0, loading],
                                   atol=0.3 * spacing + 0.02)
    rigid_fill = rigid.time_s[0, np.argmax(rigid.gap_mm[0] <= case.gap_full / 1e-3 * (1.0 + 1e-9))]
    assert rigid.switch_time_s[0] - rigid_fill < 0.05 + rigid.switch_time_s[0] / 200


def test_heating_lowers_the_force_at_the_same_gap(make_project: Callable[..., ProjectConfig]) -> None:
    """Against an isothermal run at the charge's start temperature, i.e. the base model with
    B multiplied by exp(T_b (1/T_start - 1/T_mould))."""
    T_start_C, T_b = 80.0, 5000.0
    project = make_project(press={"force_limit_kN": 5000.0})
    T_mould = 135.0 + ZERO_C_K
    factor = np.exp(T_b * (1 / (T_start_C + ZERO_C_K) - 1 / T_mould))
    iso = run(project, **{**SHEAR, "B_Pa_s": SHEAR["B_Pa_s"] * factor})
    hot = run(project, ("heating",), T_start_C=T_start_C, T_b_K=T_b, **SHEAR)
    c = closing(hot) & closing(iso)
    gap = hot.gap_mm[0, c]
    iso_force = np.interp(-gap, -iso.gap_mm[0], iso.force_kN[0])
    np.testing.assert_allclose(hot.force_kN[0, 0], iso.force_kN[0, 0], rtol=1e-9)  # same start
    assert np.all(hot.force_kN[0, c][1:] < iso_force[1:])
    assert hot.force_kN[0, c][-1] < 0.6 * iso_force[-1]  # the charge has heated by then


def test_curing_raises_the_force_once_cure_builds_up(make_project: Callable[..., ProjectConfig]) -> None:
    project = make_project(press={"force_limit_kN": 5000.0})
    base = run(project, **SHEAR)
    cured = run(project, ("curing",), k1_1_s=1e-2, **SHEAR)
    np.testing.assert_allclose(cured.force_kN[0, 0], base.force_kN[0, 0], rtol=1e-9)
    t = cured.time_s[0, closing(cured)]
    ratio = cured.force_kN[0, closing(cured)] / np.interp(t, base.time_s[0], base.force_kN[0])
    assert np.all(ratio[1:] > 1.0)
    assert ratio[-1] > 1.3 and ratio[-1] > ratio[len(ratio) // 2] > ratio[1]


def test_degree_of_cure_is_monotone_and_bounded() -> None:
    effect = Curing()
    p = {"k1": np.array([1e-3, 1e-2, 1e-1]), "k2": np.array([2e-2, 0.2, 1.0])}
    state = effect.initial_state(None, p, 3)  # type: ignore[arg-type]  # the case is unused
    history = [state["cure"]]
    for dt in [0.0, 0.1, 1.0, 10.0, 100.0, 1000.0]:
        state = effect.advance(None, p, state, np.full(3, 5e-3), np.full(3, dt))  # type: ignore[arg-type]
        history.append(state["cure"])
    h = np.array(history)
    np.testing.assert_array_equal(h[1], h[0])  # a zero step leaves the cure unchanged
    assert np.all(np.diff(h[1:], axis=0) > 0) and np.all(h <= 1.0)
    assert np.all(h[-1] > 0.9)


def test_cure_step_satisfies_the_exact_kamal_sourour_solution() -> None:
    # for m_c = 1, n_c = 2 the kinetics integrate in closed form: with K = k1 + k2,
    # G(alpha) = 1 / (K (1 - alpha)) + (k2 / K^2) ln((k1 + k2 alpha) / (1 - alpha)) grows
    # by exactly dt over a step
    def invariant(alpha: np.ndarray, k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
        K = k1 + k2
        return 1.0 / (K * (1.0 - alpha)) + k2 / K**2 * np.log((k1 + k2 * alpha) / (1.0 - alpha))

    effect = Curing()
    p = {"k1": np.array([1e-5, 1e-3, 1e-2, 1e-1, 1e-3]), "k2": np.array([1.0, 2e-2, 0.2, 1.0, 1e-4])}
    for dt in (0.01, 0.1, 1.0, 5.0, 10.0):
        start = {"cure": np.array([0.0, 0.0, 0.05, 0.1, 0.0])}
        end = effect.advance(None, p, start, np.full(5, 5e-3),  # type: ignore[arg-type]
                             np.full(5, dt))["cure"]
        elapsed = invariant(end, p["k1"], p["k2"]) - invariant(start["cure"], p["k1"], p["k2"])
        np.testing.assert_allclose(elapsed, dt, rtol=1e-4)


def test_speed_ramp_delays_the_limit_and_lowers_the_early_force(
        make_project: Callable[..., ProjectConfig]) -> None:
    project = make_project(press={"force_limit_kN": 100.0})
    base = run(project)
    ramp = run(project, ("speed_ramp",), ramp_time_s=1.0)
    assert ramp.switch_time_s[0] > base.switch_time_s[0]
    early = (ramp.time_s[0] > 0) & (ramp.time_s[0] < 2.0)
    assert early.sum() >= 5
    base_force = np.interp(ramp.time_s[0, early], base.time_s[0], base.force_kN[0])
    assert np.all(ramp.force_kN[0, early] < base_force)


def test_compressible_charge_closes_past_the_fill_gap_and_creeps(
        make_project: Callable[..., ProjectConfig]) -> None:
    project = make_project()
    fill_gap = ForwardModel(project).cases["bar"].gap_full / 1e-3
    res = run(project, ("compressibility",), rows=2, bulk_viscosity_MPa_s=[0.0, 50.0])
    for row in range(2):
        gap_at_limit = np.interp(res.switch_time_s[row], res.time_s[row], res.gap_mm[row])
        assert gap_at_limit < fill_gap
    hold = res.phase[1] == PHASE_FORCE
    creep = -np.diff(res.gap_mm[1, hold])
    assert np.all(creep[:10] > 0) and np.all(creep >= -1e-12)
    assert res.gap_mm[1, -1] < res.gap_mm[1, hold][0] - 0.05
    still = res.phase[0] == PHASE_FORCE
    assert np.ptp(res.gap_mm[0, still]) < 1e-9  # rate-independent compaction: no creep
    # the creep tends to the same equilibrium P_c(s) = F_limit / A
    assert res.gap_mm[1, -1] == pytest.approx(res.gap_mm[0, -1], rel=0.01)


def test_compressible_60_bar_closes_below_4_mm_with_a_late_steep_rise(thesis_config: Path) -> None:
    """Hand-chosen parameters inside the thesis's bounds (benchmarks/compressible_60bar.py)."""
    values = {"n": 0.45, "tau_star_Pa": 1e5, "B_Pa_s": 1e5, "tau_c_MPa": 0.5, "m": 1.2,
              "rho_solid_g_cm3": 1.8, "compaction_modulus_MPa": 0.2, "compaction_exponent": 2.0,
              "bulk_viscosity_MPa_s": 0.0}
    model = ForwardModel(load_project(thesis_config), effects=["compressibility"])
    for p in model.space.parameters:
        assert p.lower <= values[p.name] <= p.upper, p.name
    res = model.simulate_params({k: [v] for k, v in values.items()}, ["60-bar-03"])["60-bar-03"]
    t_limit = res.switch_time_s[0]
    assert np.interp(t_limit, res.time_s[0], res.gap_mm[0]) < 4.0
    assert 15.0 < t_limit < 21.0  # measured 17.9 s
    force = lambda share: np.interp(share * t_limit, res.time_s[0], res.force_kN[0])  # noqa: E731
    assert force(0.6) < 0.1 * 1400.0 < force(0.9)


def test_packing_against_a_soft_frame_rises_smoothly(thesis_config: Path) -> None:
    # rate-independent compaction near the pore-free state is stiffer than the frame; an
    # explicit compaction pressure made gap and frame deflection overshoot each other
    # (force increments alternating between zero and double)
    from smcbayes.forward.march import march
    from smcbayes.forward.parameters import to_si
    from smcbayes.forward.squeeze1d import material_table

    project = load_project(thesis_config)
    model = ForwardModel(project, effects=["compressibility", "press_compliance"])
    batch = {k: np.array([v]) for k, v in model.space.defaults().items()}
    batch["k_press_kN_mm"] = np.array([500.0])
    p = to_si(batch, model.space.parameters)
    case = model.cases["60-bar-03"]
    nodes = march(case, p, model.effects, material_table(p, project.material, model.solver.tau),
                  model.solver.options)
    n = nodes.count[0]
    packing = (nodes.area[0, :n] >= case.area_mould * (1 - 1e-12)) & (nodes.time[0, :n] < nodes.switch[0])
    rise = np.diff(nodes.force[0, :n][packing])
    assert rise.size > 50 and np.all(rise > 0)
    assert np.all((rise[1:] / rise[:-1] > 0.5) & (rise[1:] / rise[:-1] < 2.0))


def test_the_switch_on_a_compliant_frame_moves_smoothly_as_the_fill_crosses_a_step(
        make_project: Callable[..., ProjectConfig]) -> None:
    """An incompressible charge that fills the cavity well below the limit, on a soft frame
    and a ram that slows under load: as the viscosity rises, the fill moves across the ends
    of the marching steps, and the switch time (the fill plus the frame's loading) must
    follow smoothly.  When the step cut short at the fill loaded the frame by a whole
    step's worth, the switch time jumped by up to 30 ms here each time the fill crossed a
    step's end; when the loading started from the force balanced for the next step, by a
    few tenths of a ms."""
    project = make_project(press={"force_limit_kN": 500.0})
    b_Pa_s = np.linspace(1.0e3, 2.0e3, 121)
    res = run(project, ("press_compliance", "speed_ramp"), rows=len(b_Pa_s), k_press_kN_mm=50.0,
              ramp_time_s=0.01, load_slowdown=0.5, **{**SHEAR, "B_Pa_s": list(b_Pa_s), "tau_c_MPa": 0.01})
    t_switch = res.switch_time_s
    trend = abs(t_switch[-1] - t_switch[0])
    assert trend > 0.002
    # over 121 close steps of a smooth trend the second differences are tiny; jumps are not
    assert np.max(np.abs(np.diff(t_switch, 2))) < 2e-3 * trend


@pytest.mark.parametrize("path", ["compiled", "numpy", "profile"])
def test_a_fill_below_the_limit_switches_once_the_ram_has_closed_the_gap_and_loaded_the_frame(
        make_project: Callable[..., ProjectConfig], path: str) -> None:
    """At a constant ram speed U without a load slowdown the ram runs the gap's travel to
    the fill, then the frame's F_limit / k, whatever the flow before the fill:
    t_switch = (H0 - H_full + F_limit / k) / U for every viscosity, on the compiled and the
    NumPy marching paths and along a measured profile at the set speed."""
    k_kN_mm, limit_kN = 200.0, 500.0
    model = ForwardModel(make_project(press={"force_limit_kN": limit_kN}), effects=["press_compliance"])
    case = model.cases["bar"]
    if path != "compiled":
        model.solver.options = dataclasses.replace(model.solver.options, compiled=False)
    if path == "profile":
        case = dataclasses.replace(case, profile=SpeedProfile(np.array([0.0, 1000.0]),
                                                              np.array([0.0, 1000.0 * case.speed])))
    b_Pa_s = np.linspace(1.0e3, 2.0e3, 31)
    values = {**model.space.defaults(), **SHEAR, "tau_c_MPa": 0.01, "k_press_kN_mm": k_kN_mm}
    batch = {k: np.full(len(b_Pa_s), v) for k, v in values.items()}
    batch["B_Pa_s"] = b_Pa_s
    res = model.solver.solve(case, to_si(batch, model.space.parameters),
                             model.effects, model.project.material)
    assert model.solver.last_path == ("compiled" if path == "compiled" else "numpy")
    assert all(s == "ok" for s in res.status)
    expected = (case.gap0 - case.gap_full + limit_kN * 1e3 / (k_kN_mm * 1e6)) / case.speed
    np.testing.assert_allclose(res.switch_time_s, expected, rtol=1e-9)
