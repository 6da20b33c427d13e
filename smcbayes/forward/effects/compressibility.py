"""Compressible (porous) charge: the closing splits into spreading and pore compaction.

The charge enters with solid (consolidated) volume fraction

    s0 = (mass / (A0 H0)) / rho_solid

(about 0.58 for the thesis's 60 % charges: 388 g in 0.6 x 305 x 305 x 8 mm is
0.87 g/cm3 against about 1.5 g/cm3 consolidated).  A lumped model splits the closing
strain rate V/H into spreading, V_s/H (in-plane flow, the flow tables of the base model),
and compaction of the pores, V_c/H, both driven by the same mean pressure F/A:

    F / A = P_c(s) + zeta * V_c / H,   V = V_s + V_c,   s = s0 H0 A0 / (H A).

The compaction law combines the power law of Toll & Manson for the compaction of random
fibre networks (S. Toll, J.-A. E. Manson, "Elastic compression of a fiber network",
J. Appl. Mech. 62 (1995) 223-226: P ~ k (v^b - v0^b), exponent ~5 for planar random
networks) with a hyperbolic pore-closure factor that makes the pressure diverge as the
pores close, in the spirit of the fibre-bed law of Gutowski, Morigaki & Cai (J. Compos.
Mater. 21 (1987) 172-188), which diverges at the maximum packing:

    P_c(s) = k_c * ((s / s0)^b - 1) * (1 - s0) / (1 - s),   s0 <= s < 1.

zeta (optional, default 0) is a bulk viscosity: with it the charge creeps under force
control; without it compaction is rate-independent.  Once the cavity is full the closure
continues by compaction alone until the force limit.  s0 >= 1 (rho_solid at or below the
charge's apparent density) disables compaction and reproduces the incompressible model.
"""

from __future__ import annotations

import numpy as np

from smcbayes.errors import ConfigError
from smcbayes.forward import laws
from smcbayes.forward.case import Case
from smcbayes.forward.effects.base import Array, Effect, Params, register
from smcbayes.forward.parameters import Parameter
from smcbayes.units import G_CM3, MPA


def compaction_pressure(solid: Array, solid0: Array, modulus: Array, exponent: Array) -> Array:
    """P_c(s) (Pa) of :func:`smcbayes.forward.laws.compaction_pressure`, arrays of one
    shape: zero at s0, diverging as s -> 1; infinite where s0 >= 1 or s >= 1."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return laws.compaction_pressure(solid, solid0, modulus, exponent)


@register
class Compressibility(Effect):
    """Porous charge: pore compaction competes with in-plane flow."""

    name = "compressibility"
    description = ("porous charge: closing splits into spreading and pore compaction under a "
                   "common mean pressure; Toll-Manson power law with pore-closure divergence")
    parameters = (
        Parameter("rho_solid_g_cm3", "rho_solid", "g/cm3", G_CM3, 1.3, 1.8, False, 1.5,
                  (0.0, 20.0), "density of the fully consolidated charge"),
        Parameter("compaction_modulus_MPa", "compaction_modulus", "MPa", MPA, 0.01, 100.0, True,
                  1.0, (0.0, np.inf), "compaction modulus k_c"),
        Parameter("compaction_exponent", "compaction_exponent", "-", 1.0, 1.0, 15.0, False, 5.0,
                  (0.0, 100.0), "Toll-Manson exponent b"),
        Parameter("bulk_viscosity_MPa_s", "bulk_viscosity", "MPa s", MPA, 0.0, 500.0, False, 0.0,
                  (-1e-300, np.inf), "bulk viscosity of compaction (0: rate-independent)"),
    )
    # the initial solid fraction reaches the kernel through solid_fraction0
    kernel_slots = ("compaction_modulus", "compaction_exponent", "bulk_viscosity")

    def solid_fraction0(self, case: Case, p: Params, rows: int) -> Array:
        if case.mass is None:
            raise ConfigError(f"configuration '{case.id}': the compressibility effect needs "
                              "charge.mass_g")
        apparent = case.mass / (case.area0 * case.gap0)
        return np.broadcast_to(apparent / p["rho_solid"], (rows,)).astype(float)

    def compaction(self, case: Case, p: Params, solid: Array) -> tuple[Array, Array]:
        s0 = self.solid_fraction0(case, p, solid.size)
        pc = compaction_pressure(solid, s0, p["compaction_modulus"], p["compaction_exponent"])
        return pc, np.broadcast_to(p["bulk_viscosity"], solid.shape).astype(float)
