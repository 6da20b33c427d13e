"""Material laws: Cross viscosity limits and inversion, slip law, Arrhenius, cure factor."""

from __future__ import annotations

import numpy as np

from smcbayes.forward.material import (
    cross_shear_rate,
    cross_stress,
    cross_viscosity,
    cure_factor,
    slip_velocity,
    zero_shear_viscosity,
)


def test_cross_with_n_one_is_half_eta0() -> None:
    gdot = np.logspace(-3, 4, 15)
    for tau_star in (1e2, 1e4, 1e40):
        np.testing.assert_allclose(cross_viscosity(gdot, 7.0e3, tau_star, 1.0), 3.5e3, rtol=1e-14)


def test_cross_newtonian_limit_for_huge_tau_star() -> None:
    gdot = np.logspace(-3, 4, 15)
    for n in (0.2, 0.4, 0.6):
        np.testing.assert_allclose(cross_viscosity(gdot, 2.0e4, 1e40, n), 2.0e4, rtol=1e-9)


def test_cross_power_law_limit() -> None:
    """eta0 huge and tau* = (K / eta0^n)^(1/(1-n)) give eta = K gdot^(n-1)."""
    K, eta0, gdot = 3.0e4, 1e30, np.logspace(-2, 3, 11)
    for n in (0.3, 0.5, 0.7):
        tau_star = (K / eta0**n) ** (1.0 / (1.0 - n))
        np.testing.assert_allclose(cross_viscosity(gdot, eta0, tau_star, n), K * gdot ** (n - 1.0),
                                   rtol=1e-9)


def test_cross_shear_rate_inverts_cross_stress() -> None:
    gdot = np.logspace(-6, 6, 49)[None, :]
    n = np.array([[0.2], [0.35], [0.6], [1.0]])
    tau = cross_stress(gdot, 2.0e4, 3.0e4, n)
    np.testing.assert_allclose(cross_shear_rate(tau, 2.0e4, 3.0e4, n), np.broadcast_to(gdot, tau.shape),
                               rtol=1e-10)


def test_slip_law_threshold_and_power() -> None:
    tau = np.array([1e3, 1e4, 5e4, 1e5, 1e6])
    v = slip_velocity(tau, 1e-8, 5e4, 1.5)
    np.testing.assert_allclose(v[2], 0.5 * 1e-8 * 5e4**1.5, rtol=1e-14)  # half speed at tau_c
    assert v[0] < 1e-12 * 1e-8 * 1e3**1.5  # (tau_c / tau)^10 suppresses slip below tau_c
    np.testing.assert_allclose(v[-1], 1e-8 * 1e6**1.5, rtol=1e-9)
    np.testing.assert_allclose(slip_velocity(tau, 2e-8, 0.0, 1.2), 2e-8 * tau**1.2, rtol=1e-14)


def test_arrhenius_is_relative_to_the_mould_temperature() -> None:
    assert zero_shear_viscosity(1e4, 5000.0, 408.15, 408.15) == 1e4
    assert (zero_shear_viscosity(1e4, 5000.0, 353.15, 408.15) > 1e4
            > zero_shear_viscosity(1e4, 5000.0, 420.0, 408.15))


def test_cure_factor_grows_and_diverges_at_gelation() -> None:
    alpha = np.linspace(0.0, 0.49, 50)
    f = cure_factor(alpha, 0.5, 3.0, 5.0)
    assert f[0] == 1.0
    assert np.all(np.diff(f) > 0)
    assert np.isinf(cure_factor(0.5, 0.5, 3.0, 5.0)) and np.isinf(cure_factor(0.7, 0.5, 3.0, 5.0))
