"""ForwardModel: the thesis project end to end, determinism, batch consistency, errors."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import ProjectConfig, load_project
from smcbayes.errors import ConfigError, SmcBayesError
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.result import PHASE_CONTACT, PHASE_FORCE, SimulationResult

ALL_EFFECTS = ["compressibility", "curing", "heating", "press_compliance", "speed_ramp"]
CURVES = ("time_s", "gap_mm", "displacement_mm", "force_kN", "fill_fraction", "solid_fraction", "phase")


def test_thesis_config_simulates_all_twelve_configurations(thesis_config: Path) -> None:
    model = ForwardModel(load_project(thesis_config))
    assert len(model.ids("train")) == 9 and len(model.ids("validation")) == 3
    results = model.simulate()
    assert sorted(results) == sorted(model.config_ids) and len(results) == 12
    for cid, res in results.items():
        assert res.status == ["ok"], cid
        assert res.time_s.shape[1] >= 200
        assert np.all(np.diff(res.time_s[0]) > 0), cid
        assert res.phase[0, 0] == PHASE_CONTACT and res.phase[0, -1] == PHASE_FORCE
        assert res.force_kN[0, -1] == pytest.approx(1400.0)
        assert np.all(np.diff(res.gap_mm[0]) <= 1e-12), cid
        case = model.cases[cid]
        assert res.gap_mm[0, -1] == pytest.approx(case.gap_full * 1e3, rel=1e-9)  # incompressible stop


def _assert_same(a: SimulationResult, b: SimulationResult, rtol: float, rows: slice | int) -> None:
    for name in CURVES:
        np.testing.assert_allclose(getattr(a, name), getattr(b, name)[rows], rtol=rtol, atol=0, err_msg=name)
    np.testing.assert_allclose(a.switch_time_s, b.switch_time_s[rows], rtol=rtol, atol=0)


@pytest.mark.parametrize("effects", [[], ALL_EFFECTS], ids=["base", "all-effects"])
def test_same_input_gives_bitwise_the_same_output(
        effects: list[str], make_project: Callable[..., ProjectConfig]) -> None:
    model = ForwardModel(make_project(solver={"closing_steps": 80, "hold_steps": 20}), effects=effects)
    theta = model.space.from_unit(np.random.default_rng(3).random((4, model.space.dim)))
    first, second = model.simulate(theta)["bar"], model.simulate(theta)["bar"]
    _assert_same(first, second, 0.0, slice(None))


@pytest.mark.parametrize("effects", [[], ["press_compliance"], ALL_EFFECTS],
                         ids=["base", "compliance", "all-effects"])
def test_batch_rows_equal_single_runs(effects: list[str], make_project: Callable[..., ProjectConfig]) -> None:
    model = ForwardModel(make_project(solver={"closing_steps": 80, "hold_steps": 20}), effects=effects)
    theta = model.space.from_unit(np.random.default_rng(7).random((5, model.space.dim)))
    batch = model.simulate(theta)["bar"]
    assert all(s == "ok" for s in batch.status)
    for i in range(theta.shape[0]):
        single = model.simulate(theta[i:i + 1])["bar"]
        _assert_same(single, batch, 1e-12, slice(i, i + 1))


def test_parameter_space_round_trip(thesis_config: Path) -> None:
    space = ForwardModel(load_project(thesis_config)).space
    assert space.free_names == ["n", "tau_star_Pa", "B_Pa_s", "tau_c_MPa", "m"]
    u = np.random.default_rng(0).random((6, space.dim))
    np.testing.assert_allclose(space.to_unit(space.from_unit(u)), u, rtol=1e-12, atol=1e-12)
    theta = space.from_unit(u)
    assert np.all(theta[:, 0] >= 0.2) and np.all(theta[:, 0] <= 1.0)  # bounds of n in the project


def test_library_errors_are_smcbayes_errors(make_project: Callable[..., ProjectConfig]) -> None:
    project = make_project()
    with pytest.raises(ConfigError, match="n=-1"):
        ForwardModel(project, overrides={"n": -1.0})
    with pytest.raises(ConfigError, match="did you mean 'tau_c_MPa'"):
        ForwardModel(project, overrides={"tau_c_Mpa": 0.1})
    with pytest.raises(ConfigError, match="did you mean 'heating'"):
        ForwardModel(project, effects=["heatng"])
    model = ForwardModel(project)
    with pytest.raises(SmcBayesError, match="did you mean 'bar'"):
        model.simulate(None, ["baar"])
    with pytest.raises(SmcBayesError, match="columns"):
        model.simulate(np.ones((2, 3)))
    bad = model.space.batch(np.array([[0.4, 1e4, 1e4, 0.05, 1.5], [0.0, 1e4, 1e4, 0.05, 1.5]]))
    with pytest.raises(ConfigError, match="n=0.0"):
        model.simulate_params(bad)


def test_compressibility_needs_the_charge_mass(make_project: Callable[..., ProjectConfig]) -> None:
    raw_project = make_project(charge={"mass_g": None})
    model = ForwardModel(raw_project, effects=["compressibility"])
    with pytest.raises(ConfigError, match="mass_g"):
        model.simulate()


def test_effect_parameter_tables_apply_only_with_their_effect(thesis_config: Path) -> None:
    project = load_project(thesis_config)
    assert project.parameters["rho_solid_g_cm3"].fixed
    base = ForwardModel(project)
    assert "rho_solid_g_cm3" not in base.space.names
    on = ForwardModel(project, effects=["compressibility"])
    assert on.space.fixed == {"rho_solid_g_cm3": 1.5, "bulk_viscosity_MPa_s": 0.0}
    assert "compaction_modulus_MPa" in on.space.free_names
    typo = project.model_copy(update={"parameters": {
        **project.parameters, "rho_solid_g_cm": project.parameters["rho_solid_g_cm3"]}})
    with pytest.raises(ConfigError, match="did you mean 'rho_solid_g_cm3'"):
        ForwardModel(typo)
