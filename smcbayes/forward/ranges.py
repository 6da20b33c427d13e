"""Physical ranges of every parameter of the native model, with the reason for each limit.

A parameter's *search bounds* (:class:`~smcbayes.forward.parameters.Parameter` ``lower``/
``upper``, overridden per project in ``[parameters.NAME] bounds``) are where a calibration
looks; its *physical range* here is where a value still means what the model says it
means.  A calibrated value on a search bound that lies inside the physical range says
"widen the bound"; one on the physical limit says "the model lacks physics".  Values are
in the user units of each parameter (the unit suffix of its name).

The limits are orders of magnitude and structural limits (a Newtonian fluid, an empty
pore space, a frame that cannot be stiffer than its steel), not measured values of the
thesis's material.  Sources:

* Le Corre, Orgéas, Favier, Tourabi, Maazouz, Venet, "Shear and compression behaviour of
  sheet moulding compounds", Compos. Sci. Technol. 62 (2002) 571-577, and Dumont, Orgéas,
  Le Corre, Favier, "Anisotropic viscous behavior of sheet molding compounds (SMC) during
  compression molding", Int. J. Plasticity 19 (2003) 625-646: SMC is a shear-thinning
  power-law medium (power-law index below 1).
* Barone & Caulk, "Kinematics of flow in sheet molding compounds", Polym. Compos. 6 (1985)
  105-109, and "A model for the flow of a chopped fiber reinforced polymer compound in
  compression molding", J. Appl. Mech. 53 (1986) 361-371: plug flow of the bulk over a
  thin lubricating layer at the hot mould, hydrodynamic friction (slip velocity
  proportional to a power of the wall shear stress).
* Guiraud, Dumont, Orgéas, Favier, "Rheometry of compression moulded fibre-reinforced
  polymer composites: rheology, compressibility, and friction forces with mould surfaces",
  Compos. Part A 43 (2012) 2107-2119, and Hohberg, "Experimental investigation and process
  simulation of the compression molding process of SMC with local reinforcements", PhD
  thesis, KIT (2018): SMC charges are porous and compact under the moulding pressure.
* Toll & Manson, "Elastic compression of a fiber network", J. Appl. Mech. 62 (1995)
  223-226, and Toll, "Packing mechanics of fiber reinforcements", Polym. Eng. Sci. 38
  (1998) 1337-1350: compaction pressure of a fibre network ~ v^b with b = 3 (3-D random)
  to 5 (planar random); Gutowski, Morigaki, Cai, "The consolidation of laminate
  composites", J. Compos. Mater. 21 (1987) 172-188: divergence at the packing limit.
* Kamal & Sourour, "Kinetics and thermal characterization of thermoset cure", Polym. Eng.
  Sci. 13 (1973) 59-64; Castro & Macosko, AIChE J. 28 (1982) 250-260 (cure factor of
  the viscosity; gel conversions of epoxy and polyester systems 0.2-0.8).
* The thesis (``thesis.md``), section 4.4, for the Moldflow-card bounds of n, tau*, B,
  tau_c and m, and its data README: 1400 kN on the 305 x 305 mm plaque is a mean pressure
  of 15 MPa; consolidated CF-epoxy SMC at 60 wt% fibre is about 1.5 g/cm3.
"""

from __future__ import annotations

from dataclasses import dataclass

from smcbayes.errors import ConfigError


@dataclass(frozen=True)
class PhysicalRange:
    """Closed physical range of one parameter (user units) and why.

    Attributes:
        name: parameter name with its unit suffix.
        lower, upper: the limits, in the parameter's user unit.
        reason: one or two sentences: what sets each limit.
    """

    name: str
    lower: float
    upper: float
    reason: str

    def contains(self, value: float) -> bool:
        """Whether ``value`` lies in the range (limits included)."""
        return self.lower <= value <= self.upper


_RANGES: tuple[PhysicalRange, ...] = (
    # -- base model: modified Cross law (thesis eq. 3.1-3.2) and Moldflow slip law (eq. 3.3)
    PhysicalRange("n", 0.1, 1.0,
                  "power-law index: 1 is Newtonian, SMC is shear-thinning (Le Corre et al. 2002, "
                  "Dumont et al. 2003); the thesis card's 0.2-0.6 is the paste's range, but with "
                  "slip-dominated plug flow the bulk's index is weakly identified and up to 1 "
                  "remains physical"),
    PhysicalRange("tau_star_Pa", 1e2, 1e6,
                  "Cross transition stress: below 1e2 Pa the bulk thins from practically zero "
                  "stress (a pure power law), above 1e6 Pa it stays Newtonian over every wall "
                  "shear stress a 15 MPa mean pressure can produce"),
    PhysicalRange("B_Pa_s", 1e2, 1e7,
                  "zero-shear viscosity at the mould temperature: from the thickened resin paste "
                  "heated to 135 C (order 1e2-1e4 Pa s) up to the compressive viscosities of "
                  "fibre-laden SMC at low strain rates (order 1e5-1e7 Pa s, Dumont et al. 2003, "
                  "Guiraud et al. 2012)"),
    PhysicalRange("tau_c_MPa", 1e-3, 5.0,
                  "critical wall shear stress of the slip law: from slip at practically zero stress "
                  "(a lubricating layer, Barone & Caulk 1986) up to a friction coefficient of about "
                  "0.3 times the 15 MPa mean pressure at the force limit (above it slip never starts)"),
    PhysicalRange("m", 0.3, 3.0,
                  "slip exponent: a lubricating layer of index n_l gives m = 1/n_l >= 1 (m = 1 for a "
                  "Newtonian layer, Barone & Caulk 1986); with the slip coefficient fixed, m also "
                  "sets the slip magnitude, so m below 1 stands for a lower slip coefficient"),
    # -- compressibility
    PhysicalRange("rho_solid_g_cm3", 1.2, 2.1,
                  "density of the pore-free charge: about 1.2 for an unreinforced resin, up to "
                  "1.9-2.0 for filled glass-fibre SMC; 60 wt% carbon fibre (1.75-1.80 g/cm3) in "
                  "epoxy (1.15-1.25 g/cm3) gives 1.45-1.55 g/cm3, and as the model keeps the mass "
                  "lost as flash (4-9 % in the thesis trials) the effective value may reach 1.65"),
    PhysicalRange("compaction_modulus_MPa", 1e-3, 100.0,
                  "pressure scale k_c of the compaction law: a porous charge compacts partly at the "
                  "spreading pressures of the press, 0.1-2 MPa (Guiraud et al. 2012, Hohberg 2018); "
                  "at 100 MPa it is practically incompressible below a 15 MPa force limit"),
    PhysicalRange("compaction_exponent", 1.0, 15.0,
                  "Toll-Manson exponent b: 3 for 3-D and 5 for planar random fibre networks (Toll & "
                  "Manson 1995, Toll 1998); larger values stand for a stiffer approach to the "
                  "packing limit"),
    PhysicalRange("bulk_viscosity_MPa_s", 0.0, 500.0,
                  "bulk viscosity of compaction: 0 is rate-independent compaction; at 1 mm/s in a "
                  "3 mm gap 500 MPa s would alone exceed the 15 MPa of the force limit"),
    # -- press
    PhysicalRange("k_press_kN_mm", 50.0, 20000.0,
                  "press frame stiffness: 28 mm to 0.07 mm of deflection at 1400 kN, from a soft "
                  "frame to a stiff four-column press; in the thesis's trials the final parts "
                  "(2.6/3.5 mm) are about as thick as 8 mm minus the ram travel, which leaves a "
                  "few tenths of a mm of deflection at most (k of a few thousand kN/mm or more)"),
    PhysicalRange("ramp_time_s", 0.01, 5.0,
                  "time constant of the ram's acceleration to the set speed: servo-hydraulic "
                  "presses reach the set speed within 0.01-1 s; 5 s is a generous upper limit"),
    PhysicalRange("load_slowdown", 0.0, 0.9,
                  "share of the set speed lost at the force limit: 0 is an ideal speed control, "
                  "0.9 a pump nearly stalled by the load"),
    # -- thermal effects
    PhysicalRange("T_start_C", 15.0, 135.0,
                  "charge temperature at first contact: room temperature up to the mould's"),
    PhysicalRange("diffusivity_mm2_s", 0.05, 2.0,
                  "through-thickness thermal diffusivity: about 0.1 mm2/s for an epoxy paste, "
                  "0.3-0.6 mm2/s for consolidated carbon-fibre epoxy; pores lower it"),
    PhysicalRange("T_b_K", 1000.0, 15000.0,
                  "Arrhenius activation temperature E/R of the viscosity: 8-125 kJ/mol"),
    PhysicalRange("k1_1_s", 1e-5, 1e-1,
                  "Kamal-Sourour rate constant k1 at the mould temperature (Kamal & Sourour 1973): "
                  "from a latent system to gelation within tens of seconds"),
    PhysicalRange("k2_1_s", 1e-4, 1.0,
                  "autocatalytic rate constant k2 at the mould temperature (Kamal & Sourour 1973)"),
    PhysicalRange("c1", 0.0, 10.0, "cure-factor exponent c1 (Castro & Macosko 1982; thesis eq. 3.1)"),
    PhysicalRange("c2", 0.0, 20.0, "cure-factor exponent c2 (Castro & Macosko 1982; thesis eq. 3.1)"),
    PhysicalRange("alpha_g", 0.2, 0.9,
                  "degree of cure at gelation: 0.2-0.8 for polyester and epoxy systems "
                  "(Castro & Macosko 1982)"),
)

PHYSICAL_RANGES: dict[str, PhysicalRange] = {r.name: r for r in _RANGES}
"""Physical range of every parameter of the base model and the built-in effects, by name."""


def physical_range(name: str) -> PhysicalRange:
    """The physical range of parameter ``name``; unknown names raise :class:`ConfigError`."""
    try:
        return PHYSICAL_RANGES[name]
    except KeyError:
        raise ConfigError(f"no physical range is recorded for parameter '{name}'") from None


def ranges_table() -> str:
    """The ranges as a Markdown table (name, lower, upper, reason)."""
    rows = ["| parameter | lower | upper | reason |", "|---|---|---|---|"]
    rows += [f"| {r.name} | {r.lower:g} | {r.upper:g} | {r.reason} |" for r in _RANGES]
    return "\n".join(rows)
