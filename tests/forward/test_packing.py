"""The end-of-closing rise of a porous charge against a compliant frame, checked against
its closed form.

Once the cavity is full, a charge with rate-independent compaction (zeta = 0) carries
F = A_mould P_c(s) with s = s0 H0 A0 / (H A_mould) (mass conservation), and under speed
control the ram travels U t = (H0 - H) + F / k (frame deflection).  Both hold at every
output sample of the packing phase, on the compiled and the NumPy marching paths, whatever
the step sizes, so the rise is the compaction law seen through the frame and nothing else.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import load_project
from smcbayes.forward.effects.compressibility import compaction_pressure
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.result import PHASE_FULL

VALUES = {"n": 0.8, "tau_star_Pa": 2.7e4, "B_Pa_s": 7e4, "tau_c_MPa": 0.09, "m": 1.1,
          "rho_solid_g_cm3": 1.47, "compaction_modulus_MPa": 0.34, "compaction_exponent": 4.9,
          "bulk_viscosity_MPa_s": 0.0, "k_press_kN_mm": 2200.0}


@pytest.mark.parametrize("cid", ["60-bar-07", "80-center-03"])
@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "numpy"])
def test_packing_follows_the_compaction_law_through_the_frame(thesis_config: Path, cid: str,
                                                              compiled: bool) -> None:
    model = ForwardModel(load_project(thesis_config), effects=["compressibility", "press_compliance"])
    if not compiled:  # a subclass of an effect runs on the NumPy marching path
        from smcbayes.forward.effects.press import PressCompliance

        class Soft(PressCompliance):
            pass

        model.effects.effects = (model.effects.effects[0], Soft())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = model.simulate_params({k: [v] for k, v in VALUES.items()}, [cid])[cid]
    case = model.cases[cid]
    packing = res.phase[0] == PHASE_FULL
    assert packing.sum() >= 5
    t, gap, force = res.time_s[0, packing], res.gap_mm[0, packing] * 1e-3, res.force_kN[0, packing] * 1e3
    s0 = case.mass / (case.area0 * case.gap0) / (VALUES["rho_solid_g_cm3"] * 1e3)
    solid = s0 * case.gap0 * case.area0 / (gap * case.area_mould)
    np.testing.assert_allclose(res.solid_fraction[0, packing], solid, rtol=1e-9)
    pc = compaction_pressure(solid, np.full_like(solid, s0), np.full_like(solid, 0.34e6),
                             np.full_like(solid, 4.9))
    np.testing.assert_allclose(force, case.area_mould * pc, rtol=2e-3)
    ram = (case.gap0 - gap) + force / (VALUES["k_press_kN_mm"] * 1e6)
    np.testing.assert_allclose(ram, case.speed * t, rtol=2e-3)
    np.testing.assert_allclose(res.displacement_mm[0, packing] * 1e-3, ram, rtol=1e-6)
    # the rise is not vertical: 400 kN to the limit takes seconds, as measured
    closing = res.time_s[0] <= res.switch_time_s[0]
    t_all, f_all = res.time_s[0, closing], res.force_kN[0, closing]
    rise_s = res.switch_time_s[0] - t_all[np.argmax(f_all > 400.0)]
    assert rise_s > 0.5  # measured: 1.2-3.2 s
