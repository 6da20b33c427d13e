"""2-D solver with the compressibility effect (lumped pore compaction) against the 1-D solver."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smcbayes.config import build_project
from smcbayes.forward.model import ForwardModel


def _project(shape: str, cells: int = 24):
    raw = {"solver": {"cells_2d": cells, "closing_steps_2d": 60},
           "configuration": [{"id": "c", "charge": {"shape": shape, "coverage_pct": 60.0, "mass_g": 390.0,
                                                    "stack_height_mm": 8.0},
                              "press": {"speed_mm_s": 0.7, "hold_s": 30.0}}]}
    return build_project(raw, "test.toml", Path("."))


def _closing(res, t_end: float) -> tuple[np.ndarray, ...]:
    t = np.linspace(0.0, t_end, 300)
    return tuple(np.interp(t, res.time_s[0], y[0]) for y in (res.force_kN, res.solid_fraction, res.gap_mm))


def test_compressible_bar_follows_the_1d_march_over_the_closing() -> None:
    project = _project("bar")
    r1 = ForwardModel(project, effects=["compressibility"], fidelity="1d").simulate(None)["c"]
    r2 = ForwardModel(project, effects=["compressibility"], fidelity="2d").simulate(None)["c"]
    assert abs(r2.switch_time_s[0] / r1.switch_time_s[0] - 1.0) < 0.01
    f1, s1, _ = _closing(r1, 0.98 * r1.switch_time_s[0])
    f2, s2, _ = _closing(r2, 0.98 * r1.switch_time_s[0])
    assert np.sqrt(np.mean((f2 - f1) ** 2)) / np.sqrt(np.mean(f1**2)) < 0.02
    assert np.max(np.abs(s2 - s1)) < 2e-3
    assert s2[0] < 0.7 and np.all(np.diff(s2) >= -1e-12)


def test_pore_free_charge_reproduces_the_incompressible_2d_run() -> None:
    project = _project("center")
    base = ForwardModel(project, fidelity="2d").simulate(None)["c"]
    dense = ForwardModel(project, effects=["compressibility"], fidelity="2d",
                         overrides={"rho_solid_g_cm3": 0.1}).simulate(None)["c"]  # s0 > 1: no pores
    assert np.allclose(dense.force_kN, base.force_kN, rtol=1e-12)
    assert np.all(dense.solid_fraction == 1.0)


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
