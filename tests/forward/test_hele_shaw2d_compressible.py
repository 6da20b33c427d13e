"""2-D solver with the compressibility effect: a local solid fraction per cell."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import MaterialSpec, ProjectConfig, build_project
from smcbayes.forward.case import Case
from smcbayes.forward.compaction2d import CellCompaction
from smcbayes.forward.flux import MaterialTable
from smcbayes.forward.grid2d import FULL, Fluidity, Grid, Sink, solve_pressure
from smcbayes.forward.hele_shaw2d import HeleShaw2D, cell_compaction
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.parameters import to_si
from smcbayes.forward.result import SimulationResult
from smcbayes.forward.spill2d import spill_with
from smcbayes.forward.squeeze1d import material_table

PIECES = [{"x_mm": -40.0, "y_mm": 20.0, "length_mm": 80.0, "width_mm": 120.0},
          {"x_mm": 70.0, "y_mm": -60.0, "length_mm": 60.0, "width_mm": 50.0}]


def _project(shape: str, cells: int = 24, limit_kN: float = 1400.0, **charge: object) -> ProjectConfig:
    size = {} if shape == "layout" else {"coverage_pct": 60.0}
    spec = {"shape": shape, **size, "mass_g": 390.0, "stack_height_mm": 8.0} | charge
    raw = {"solver": {"cells_2d": cells, "closing_steps_2d": 60},
           "configuration": [{"id": "c", "charge": spec,
                              "press": {"speed_mm_s": 0.7, "hold_s": 30.0, "force_limit_kN": limit_kN}}]}
    return build_project(raw, "test.toml", Path("."))


def _run_rows(project: ProjectConfig, overrides: dict | None = None
              ) -> tuple[ForwardModel, Case, HeleShaw2D, MaterialTable, dict, CellCompaction | None]:
    """Incompressible and per-cell compressible runs of the single configuration."""
    model = ForwardModel(project, effects=["compressibility"], fidelity="2d", overrides=overrides)
    case, solver = model.cases["c"], model.solver
    si = to_si(model.space.batch(None), model.space.parameters)
    table = material_table(si, MaterialSpec(), solver.tau)
    comp = cell_compaction(case, si, model.effects, 0)
    return model, case, solver, table, si, comp


def _closing(res: SimulationResult, t_end: float) -> tuple[np.ndarray, ...]:
    t = np.linspace(0.0, t_end, 300)
    return tuple(np.interp(t, res.time_s[0], y[0]) for y in (res.force_kN, res.solid_fraction, res.gap_mm))


def _grid(n: int = 6, size: float = 0.1) -> Grid:
    faces = np.linspace(0.0, size, n + 1)
    return Grid(n, n, size / n, size / n, faces, faces, 1)


def test_spill_passes_the_solid_on_well_mixed_and_conserves_it() -> None:
    """Excess moves one cell per pass at the solid fraction of the cell it leaves: the
    corner's 0.5 (at s = 0.8) enters its two full neighbours (s = 0.6), which pass on
    their own excess at the mixed fraction (0.6 + 0.25 x 0.8) / 1.25 = 0.64."""
    h = np.zeros((4, 4))
    h[:2, :2] = 1.0
    h[0, 0] = 1.5
    sigma = 0.6 * h
    sigma[0, 0] = 0.8 * 1.5
    out, solid = spill_with(h, 1.0, sigma)
    assert out.sum() == pytest.approx(h.sum(), rel=1e-14)
    assert solid.sum() == pytest.approx(sigma.sum(), rel=1e-14)
    assert solid[0, 0] / out[0, 0] == pytest.approx(0.8, rel=1e-12)
    gained = (out > 0) & (h == 0)
    assert gained.sum() == 2 and np.allclose(solid[gained] / out[gained], 0.64, rtol=1e-12)
    assert np.allclose([solid[0, 1], solid[1, 0]], 0.64, rtol=1e-12)


def test_full_cavity_with_a_uniform_sink_takes_the_closing_by_compaction() -> None:
    """No front: the whole closing V A goes into the sinks, p = P + V A_cell / k
    everywhere (no flow), under speed control and under the equivalent force."""
    grid = _grid()
    tau = np.logspace(-2, 9, 133)
    fluidity = Fluidity(tau, 1e-9 * tau, 4e-3)
    threshold, k, V = 2e5, 1e-12, 1e-3
    sink = Sink(np.full((6, 6), threshold), np.full((6, 6), k))
    sol = solve_pressure(grid, np.ones((6, 6)), fluidity, V, None, sink=sink)
    expected = threshold + V * grid.cell_area / k
    assert np.allclose(sol.p, expected, rtol=1e-6)
    assert sol.sink.sum() == pytest.approx(V * grid.cell_area * 36, rel=1e-6)
    held = solve_pressure(grid, np.ones((6, 6)), fluidity, None, sol.force, sink=sink, speed_guess=0.3 * V)
    assert held.speed == pytest.approx(V, rel=1e-5)


def test_pore_free_charge_reproduces_the_incompressible_2d_run() -> None:
    project = _project("center")
    base = ForwardModel(project, fidelity="2d").simulate(None)["c"]
    dense = ForwardModel(project, effects=["compressibility"], fidelity="2d",
                         overrides={"rho_solid_g_cm3": 0.1}).simulate(None)["c"]  # s0 > 1: no pores
    assert np.allclose(dense.force_kN, base.force_kN, rtol=1e-12)
    assert np.all(dense.solid_fraction == 1.0)


@pytest.mark.parametrize("limit_kN", [1400.0, 40.0])
def test_per_cell_path_at_s0_one_reproduces_the_incompressible_run(limit_kN: float) -> None:
    """The per-cell machinery (sinks, solid transport, spill with solid, step retries)
    run with s0 = 1 gives the incompressible run node for node."""
    _, case, solver, table, si, comp = _run_rows(_project("center", limit_kN=limit_kN))
    B = float(si["B"][0])
    base = solver.run_row(case, table, B, 0, None)
    porefree = solver.run_row(case, table, B, 0, CellCompaction(1.0, comp.law))
    assert len(porefree.t) == len(base.t)
    assert np.allclose(porefree.t, base.t, rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(np.array(porefree.force) / np.array(base.force) - 1.0)) < 1e-6
    assert np.allclose(porefree.solid, 1.0, rtol=0.0, atol=1e-12)


@pytest.mark.parametrize(("shape", "limit_kN", "extra"), [
    ("center", 1400.0, {}),     # packs the cavity by compaction up to the limit
    ("center", 40.0, {}),       # force control while the charge still flows, then rests
    ("layout", 30.0, {"pieces": PIECES, "mass_g": 88.0}),  # asymmetric: the whole mould is solved
])
def test_solid_mass_is_conserved_over_a_whole_run(shape: str, limit_kN: float, extra: dict) -> None:
    _, case, solver, table, si, comp = _run_rows(_project(shape, limit_kN=limit_kN, **extra))
    run = solver.run_row(case, table, float(si["B"][0]), 0, comp)
    solid = np.array(run.solid_volume)
    assert run.status == "ok"
    assert abs(solid[0] / (comp.solid0 * case.area0 * case.gap0) - 1.0) < 1e-12
    assert np.max(np.abs(solid / solid[0] - 1.0)) < 1e-6
    after = np.array(run.t) > run.switch
    assert after.sum() >= 2 and np.allclose(np.array(run.force)[after], limit_kN * 1e3)
    assert run.solid[-1] > comp.solid0 + 0.02  # the pores did close
    assert np.all(np.diff(run.gap) <= 1e-15)


def test_high_fluidity_bar_approaches_the_lumped_1d_model() -> None:
    """With a very fluid charge the pressure is nearly uniform once it compacts, so the
    per-cell solution approaches the lumped (charge-mean) compaction of the 1-D march.
    Measured at 24 cells: 0.12 % RMS force, switch 1e-5, solid fraction 1.1e-3."""
    project = _project("bar")
    over = {"B_Pa_s": 100.0}
    r1 = ForwardModel(project, effects=["compressibility"], fidelity="1d", overrides=over).simulate(None)["c"]
    r2 = ForwardModel(project, effects=["compressibility"], fidelity="2d", overrides=over).simulate(None)["c"]
    assert abs(r2.switch_time_s[0] / r1.switch_time_s[0] - 1.0) < 1e-3
    f1, s1, _ = _closing(r1, r1.switch_time_s[0])
    f2, s2, _ = _closing(r2, r1.switch_time_s[0])
    assert np.sqrt(np.mean((f2 - f1) ** 2)) / np.sqrt(np.mean(f1**2)) < 0.01
    assert np.max(np.abs(s2 - s1)) < 2e-3
    assert abs(r2.solid_fraction[0, -1] - r1.solid_fraction[0, -1]) < 1e-3


def test_solid_fraction_is_highest_at_the_centre_where_the_pressure_is() -> None:
    project = _project("center")
    model = ForwardModel(project, effects=["compressibility"], fidelity="2d")
    res = model.simulate(None)["c"]
    history = model.solver.fields["c"][0]
    assert history.solid is not None and history.solid.shape == history.fill.shape
    s0 = res.solid_fraction[0, 0]
    k = int(np.searchsorted(history.time_s, 0.5 * res.switch_time_s[0]))  # flowing, not yet full
    solid, fill = history.solid[k], history.fill[k]
    nx, ny = solid.shape
    centre = solid[nx // 2 - 1: nx // 2 + 1, ny // 2 - 1: ny // 2 + 1]
    front = solid[(fill > 0.0) & (fill < FULL)]
    assert np.nanmax(solid) == pytest.approx(centre.max(), abs=1e-12)
    assert front.size > 0 and front.max() < centre.min() - 0.01
    assert np.all(front >= s0 - 1e-12) and np.all(np.isnan(solid[fill == 0.0]))
    half = solid[nx // 2:, ny // 2][fill[nx // 2:, ny // 2] > 0.0]  # centre -> front along x
    assert np.all(np.diff(half) <= 1e-9)


def test_bulk_viscosity_makes_the_packed_charge_creep() -> None:
    """Under force control in a full cavity a charge with a bulk viscosity keeps closing by
    viscous compaction; a rate-independent one closes only while mixture flows from the
    stiffer (more compacted) cells to the softer ones, much less.  Measured over the
    30 s hold at 300 kN: 0.90 mm against 0.015 mm.  The viscous one reaches the limit
    earlier: it resists fast compaction."""
    project = _project("center", limit_kN=300.0)
    hold_closing = {}
    switch = {}
    for zeta in (0.0, 200.0):
        res = ForwardModel(project, effects=["compressibility"], fidelity="2d",
                           overrides={"bulk_viscosity_MPa_s": zeta}).simulate(None)["c"]
        assert res.status == ["ok"]
        hold = res.time_s[0] >= res.switch_time_s[0]
        hold_closing[zeta] = res.gap_mm[0, hold][0] - res.gap_mm[0, -1]
        switch[zeta] = res.switch_time_s[0]
    assert hold_closing[200.0] > 0.5
    assert 0.0 <= hold_closing[0.0] < 0.05
    assert switch[200.0] < switch[0.0]


def test_compressible_centre_charge_packs_the_cavity_up_to_the_force_limit() -> None:
    project = _project("center")
    res = ForwardModel(project, effects=["compressibility"], fidelity="2d").simulate(None)["c"]
    closing = res.time_s[0] <= res.switch_time_s[0]
    assert res.status == ["ok"]
    assert abs(res.fill_fraction[0, -1] - 1.0) < 1e-9
    assert res.force_kN[0, closing].max() <= 1400.0 * (1 + 1e-3)
    assert res.solid_fraction[0, -1] > res.solid_fraction[0, 0] + 0.1
    # the final gap holds the solid volume at the final solid fraction in the full cavity
    case = ForwardModel(project).cases["c"]
    solid_volume = res.solid_fraction[0, 0] * case.area0 * case.gap0
    final = res.solid_fraction[0, -1] * case.area_mould * res.gap_mm[0, -1] * 1e-3
    assert abs(final / solid_volume - 1.0) < 1e-6


def test_compressible_bar_on_a_compliant_frame_matches_planar_1d() -> None:
    """Compaction up to the force limit on a frame of 300 kN/mm (4.7 mm of deflection at
    the limit): the frame's balance and the compaction's semi-implicit law together.  The 2-D
    bar follows the 1-D one and reaches the limit at its time; the frame moves the force far
    more.  Measured at 24 cells and 60 steps: 0.16 % RMS, the gap within 0.010 mm, the switch
    within 0.03 %."""
    project = _project("bar")
    over = {"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 2e4, "tau_c_MPa": 1.0, "k_press_kN_mm": 300.0}
    both = ["compressibility", "press_compliance"]
    r1 = ForwardModel(project, effects=both, fidelity="1d", overrides=over).simulate(None)["c"]
    r2 = ForwardModel(project, effects=both, fidelity="2d", overrides=over).simulate(None)["c"]
    over_rigid = {k: v for k, v in over.items() if k != "k_press_kN_mm"}
    rigid_model = ForwardModel(project, effects=["compressibility"], fidelity="2d", overrides=over_rigid)
    rigid = rigid_model.simulate(None)["c"]
    assert r1.status == r2.status == ["ok"]
    t_end = 0.99 * min(r1.switch_time_s[0], r2.switch_time_s[0])
    f1, _, g1 = _closing(r1, t_end)
    f2, _, g2 = _closing(r2, t_end)
    fr, _, _ = _closing(rigid, t_end)
    scale = np.sqrt(np.mean(f1**2))
    assert np.sqrt(np.mean((f2 - f1) ** 2)) / scale < 0.01
    assert np.sqrt(np.mean((fr - f1) ** 2)) / scale > 0.2
    assert np.max(np.abs(g2 - g1)) < 0.02
    assert r2.switch_time_s[0] == pytest.approx(r1.switch_time_s[0], rel=2e-3)


def test_a_cold_charge_whose_viscosity_falls_steeply_still_runs() -> None:
    """A prior draw of the thesis box: a charge at 18 C heating in a 135 C mould with an
    Arrhenius constant of 13,900 K, whose viscosity falls several-fold over a step.  Newton
    started from the last step's pressure went astray (the run failed after 0.3 s); it now
    starts again from zero stress, reaches the limit and conserves the solid."""
    raw = {"solver": {"cells_2d": 16},
           "configuration": [{"id": "c", "charge": {"shape": "center", "coverage_pct": 80.0, "mass_g": 542.0,
                                                    "stack_height_mm": 8.0},
                              "press": {"speed_mm_s": 0.3, "hold_s": 20.0},
                              "mould": {"temperature_C": 135.0}}]}
    project = build_project(raw, "test.toml", Path("."))
    over = {"n": 0.4255, "tau_star_Pa": 725.9, "B_Pa_s": 3.608e5, "tau_c_MPa": 0.9503, "m": 2.902,
            "compaction_modulus_MPa": 0.04, "compaction_exponent": 7.751, "rho_solid_g_cm3": 1.5,
            "T_start_C": 17.94, "diffusivity_mm2_s": 0.5996, "T_b_K": 13867.0}
    model = ForwardModel(project, effects=["compressibility", "heating"], fidelity="2d", overrides=over)
    res = model.simulate(None)["c"]
    assert res.status == ["ok"]
    case = model.cases["c"]
    pore_free_gap = res.solid_fraction[0, 0] * case.gap_full  # the ram cannot close past it
    assert 0.0 < res.switch_time_s[0] < (case.gap0 - pore_free_gap) / case.speed
    solid_volume = res.solid_fraction[0, 0] * case.area0 * case.gap0
    final = res.solid_fraction[0, -1] * case.area_mould * res.gap_mm[0, -1] * 1e-3
    assert abs(final / solid_volume - 1.0) < 1e-6
