"""Tabulated flux law: closed-form squeeze flows (design 4.4), stress-grid convergence order,
and the sign of the force's dependence on each material parameter.

Forces are computed as the kinematic path of the 1-D solver does: material tables on the
solver's stress grid, flux at the gap, flow tables for the charge size, then the front
stress at which the spreading speed equals the closing speed.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from smcbayes.forward.flux import FlowTable, MaterialTable, log_grid
from smcbayes.forward.squeeze1d import Squeeze1DOptions

Array = NDArray[np.float64]
OPTIONS = Squeeze1DOptions()
TAU = log_grid(OPTIONS.tau_min_Pa, OPTIONS.tau_max_Pa, OPTIONS.per_decade)
W = 0.305  # m, mould width across the bar's flow


def squeeze_force(n: float, tau_star: float, eta0: float, a_s: float, tau_c: float, m: float,
                  planar: bool, length: Array | float, gap: Array | float, speed: float,
                  tau: Array = TAU) -> Array:
    """Squeeze force (N) of charges of half-length/radius ``length`` (m) at ``gap`` (m).

    ``length`` and ``gap`` broadcast to shape ``(P,)``; material parameters are SI scalars.
    """
    length, gap = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (length, gap))
    length, gap = np.broadcast_arrays(length, gap)
    one = np.ones(gap.shape)
    table = MaterialTable.build(tau, n * one, tau_star * one, a_s * one, tau_c * one, m * one)
    flow = FlowTable.build(table.flux(gap, eta0 * one), tau, planar, length, gap, W)
    sol = flow.solve(np.zeros(gap.size), one, speed * one)
    assert not np.any(sol.out_of_table), "state outside the stress grid"
    return sol.force


H, V, R, A = 5.0e-3, 0.5e-3, 0.11, 0.09  # gap, closing speed, disc radius, bar half-length (m)
NEWTONIAN = dict(n=0.5, tau_star=1e40, a_s=0.0, tau_c=0.0, m=1.5)


@pytest.mark.parametrize("mu", [1e3, 2e4, 1e5])
def test_stefan_disc(mu: float) -> None:
    force = squeeze_force(eta0=mu, planar=False, length=R, gap=H, speed=V, **NEWTONIAN)[0]
    exact = 3.0 * np.pi * mu * R**4 * V / (2.0 * H**3)
    assert force == pytest.approx(exact, rel=5e-3)


@pytest.mark.parametrize("mu", [1e3, 2e4, 1e5])
def test_planar_newtonian(mu: float) -> None:
    force = squeeze_force(eta0=mu, planar=True, length=A, gap=H, speed=V, **NEWTONIAN)[0]
    assert force == pytest.approx(8.0 * mu * W * A**3 * V / H**3, rel=5e-3)


def _power_law(n: float, K: float) -> dict[str, float]:
    eta0 = 1e30  # Newtonian plateau far below every stress on the grid
    return dict(n=n, eta0=eta0, tau_star=(K / eta0**n) ** (1.0 / (1.0 - n)), a_s=0.0, tau_c=0.0, m=1.5)


@pytest.mark.parametrize("n", [0.2, 0.35, 0.6, 0.8])
def test_scott_power_law_disc_and_planar(n: float) -> None:
    K = 2.0e4
    shear = ((2.0 * n + 1.0) * V / (2.0 * n)) ** n / H ** (2.0 * n + 1.0)
    disc = squeeze_force(planar=False, length=R, gap=H, speed=V, **_power_law(n, K))[0]
    assert disc == pytest.approx(2.0 ** (n + 1) * np.pi * K * R ** (n + 3) / (n + 3) * shear, rel=5e-3)
    bar = squeeze_force(planar=True, length=A, gap=H, speed=V, **_power_law(n, K))[0]
    assert bar == pytest.approx(2.0 ** (2 * n + 2) * K * W * A ** (n + 2) / (n + 2) * shear, rel=5e-3)


@pytest.mark.parametrize("m", [1.0, 1.5, 1.9])
def test_slip_dominated_plug_flow(m: float) -> None:
    """tau_c = 0 and a huge viscosity: the flux is plug slip v_s = a_s tau^m only."""
    a_s, s = 1e-8, 1.0 / m
    plug = dict(n=0.5, tau_star=1e40, eta0=1e40, a_s=a_s, tau_c=0.0, m=m)
    disc = squeeze_force(planar=False, length=R, gap=H, speed=V, **plug)[0]
    assert disc == pytest.approx(2 * np.pi * R ** (3 + s) / ((3 + s) * H) * (V / (2 * a_s * H)) ** s,
                                 rel=5e-3)
    bar = squeeze_force(planar=True, length=A, gap=H, speed=V, **plug)[0]
    assert bar == pytest.approx(4 * W * A ** (2 + s) / ((2 + s) * H) * (V / (a_s * H)) ** s, rel=5e-3)


# -- convergence in the stress-grid density ----------------------------------------------
THRESHOLD = dict(n=0.35, tau_star=3e4, eta0=2e4, a_s=1e-8, tau_c=0.05e6, m=1.5)


def stress_grid_errors(levels: tuple[int, ...], planar: bool, speed: float,
                       reference_per_decade: int = 400) -> Array:
    """RMS relative force error per grid density over 25 states of a closing 60 % charge.

    Averaging over states along the closing removes the dependence of a single state's
    error on where the slip threshold falls between grid nodes.
    """
    H0, A0 = 8e-3, 0.6 * W * W
    gap = np.linspace(H0, 0.62 * H0, 25)
    area = A0 * H0 / gap
    length = area / (2 * W) if planar else np.sqrt(area / np.pi)

    def forces(per_decade: int) -> Array:
        tau = log_grid(OPTIONS.tau_min_Pa, OPTIONS.tau_max_Pa, per_decade)
        return squeeze_force(planar=planar, length=length, gap=gap, speed=speed, tau=tau, **THRESHOLD)

    ref = forces(reference_per_decade)
    return np.array([np.sqrt(np.mean((forces(k) / ref - 1.0) ** 2)) for k in levels])


def observed_order(levels: tuple[int, ...], errors: Array) -> float:
    """Least-squares slope of log(error) against log(grid spacing)."""
    return float(-np.polyfit(np.log(np.asarray(levels, dtype=float)), np.log(errors), 1)[0])


@pytest.mark.parametrize(("planar", "speed"), [(True, 0.3e-3), (False, 0.3e-3), (True, 1.1e-3),
                                               (False, 1.1e-3)])
def test_stress_grid_convergence_order(planar: bool, speed: float) -> None:
    levels = (6, 12, 24, 48)
    errors = stress_grid_errors(levels, planar, speed)
    order = observed_order(levels, errors)
    shown = " ".join(f"{e:.2e}" for e in errors)
    print(f"\nstress grid ({'bar' if planar else 'disc'}, {speed * 1e3:g} mm/s): per_decade {levels} "
          f"RMS errors {shown}, observed order {order:.2f}")
    assert order >= 1.7
    assert errors[1] < 0.02  # default density (12 per decade) within 2 % on a threshold material


# -- sign of the parameter dependence, per regime ----------------------------------------
STATE = dict(length=0.6 * W / 2 * 8 / 6, gap=6e-3, speed=0.3e-3)  # 60 % bar closed to 6 mm


def _force(planar: bool = True, **material: float) -> float:
    base = dict(n=0.4, tau_star=1e4, eta0=1e4, a_s=1e-8, tau_c=0.05e6, m=1.5)
    base.update(material)
    return float(squeeze_force(planar=planar, **base, **STATE)[0])


@pytest.mark.parametrize("planar", [True, False])
def test_force_rises_with_viscosity_parameters_without_slip(planar: bool) -> None:
    """No slip: B and tau* raise the viscosity at every shear rate, so the force."""
    no_slip = dict(a_s=0.0)
    f_b = [_force(planar, eta0=b, **no_slip) for b in (1e3, 1e4, 1e5)]
    f_t = [_force(planar, tau_star=t, **no_slip) for t in (1e3, 1e4, 1e5)]
    assert f_b[0] < f_b[1] < f_b[2]
    assert f_t[0] < f_t[1] < f_t[2]


@pytest.mark.parametrize("planar", [True, False])
def test_force_with_n_depends_on_the_regime(planar: bool) -> None:
    """eta = eta0 / (1 + x^(1-n)), x = eta0 gdot / tau*: a larger n raises the viscosity where
    x > 1 (shear thinning) and lowers it where x < 1 (Newtonian plateau)."""
    thinning = [_force(planar, n=n, a_s=0.0, tau_star=1e3, eta0=1e5) for n in (0.2, 0.4, 0.6)]
    plateau = [_force(planar, n=n, a_s=0.0, tau_star=1e8, eta0=1e3) for n in (0.2, 0.4, 0.6)]
    assert thinning[0] < thinning[1] < thinning[2]
    assert plateau[0] > plateau[1] > plateau[2]


@pytest.mark.parametrize("planar", [True, False])
def test_force_rises_with_tau_c_and_falls_with_m_where_slip_dominates(planar: bool) -> None:
    """With slip dominant at wall stresses above 1 Pa, a larger m slips faster (lower force);
    a larger tau_c delays the slip onset (higher force)."""
    stiff = dict(n=0.6, tau_star=1e5, eta0=1e5)  # least shear flow within the thesis bounds
    f_m = [_force(planar, m=m, tau_c=5e3, **stiff) for m in (1.0, 1.45, 1.9)]
    f_c = [_force(planar, tau_c=c, **stiff) for c in (5e3, 5e4, 2e5, 1e6)]
    assert f_m[0] > f_m[1] > f_m[2]
    assert f_c[0] < f_c[1] < f_c[2] < f_c[3]
    # with slip, shear flow still adds to the flux: the force keeps rising with B and tau*
    f_b = [_force(planar, eta0=b, tau_c=5e3) for b in (1e3, 1e4, 1e5)]
    f_t = [_force(planar, tau_star=t, tau_c=5e3) for t in (1e3, 1e4, 1e5)]
    assert f_b[0] < f_b[1] < f_b[2]
    assert f_t[0] < f_t[1] < f_t[2]
