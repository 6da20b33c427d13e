"""Tabulated flux law of thin-cavity flow with wall slip, batched over parameter sets.

For a gap H, pressure gradient G and wall shear stress tau_w = G H / 2, the flux per unit
width of generalised Hele-Shaw flow with slip is (design 4.2)

    q(tau_w) = H v_s(tau_w) + (H^2 / (2 tau_w^2)) * I(tau_w),
    I(tau_w) = integral_0^tau_w tau * gdot(tau) dtau.

Everything is tabulated on one log-spaced grid of wall stresses tau_j (shape ``(M,)``),
one row per parameter set (shape ``(P, M)``).  Between nodes every tabulated quantity is
treated as a local power law (linear in log-log), so integrals of power laws are exact:
Newtonian, power-law and pure plug-slip materials are integrated without discretisation
error and smooth transitions (Cross knee, slip threshold) converge at second order in the
grid spacing.

Squeeze flow of a charge of half-length a (planar, full width W) or radius R
(axisymmetric) at a spreading speed V has the kinematic flux q = V x (planar) or
q = V r / 2 (axisymmetric).  Changing the integration variable from position to the wall
stress and integrating by parts gives the force as an explicit function of the wall
stress at the flow front, tau_L:

    F = C L^d / H * Phi(tau_L),   Phi(tau) = tau - Q_p(tau) / q(tau)^p,
    Q_p(tau) = integral_0^tau q^p dtau',

with (C, d, p) = (2 W, 2, 2) planar and (2 pi / 3, 3, 3) axisymmetric.  Phi increases
with tau, so speed -> force and force -> speed are both one monotone table look-up.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.material import cross_shear_rate, slip_velocity

Array = NDArray[np.float64]


def log_grid(tau_min_Pa: float = 1.0, tau_max_Pa: float = 1e8,
             per_decade: int = 12) -> Array:
    """Log-spaced wall-stress grid (Pa), shape ``(M,)``."""
    decades = np.log10(tau_max_Pa) - np.log10(tau_min_Pa)
    count = int(round(decades * per_decade)) + 1
    return np.logspace(np.log10(tau_min_Pa), np.log10(tau_max_Pa), count)


def _ipow(values: Array, power: float) -> Array:
    """``values**power``, with plain multiplications for the integer powers used here."""
    if power == 1.0:
        return values
    if power == 2.0:
        return values * values
    if power == 3.0:
        return values * values * values
    return values**power


def _power_law_segments(values: Array, x: Array, power: float) -> tuple[Array, Array]:
    """Integral of ``values**power`` over each grid interval, local power law in x.

    Args:
        values: positive increasing tabulated function, shape ``(P, M)``.
        x: log-spaced positive grid, shape ``(M,)``.
        power: exponent applied to ``values``.

    Returns:
        ``(segments, tail)``: integrals over the ``M-1`` intervals, shape ``(P, M-1)``, and
        the integral from 0 to ``x[0]``, shape ``(P,)``.
    """
    ln_r = np.log(x[1] / x[0])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        slope = np.log(values[:, 1:] / values[:, :-1])
        slope *= power / ln_r  # now p * k, the local exponent of values**power
        fx = _ipow(values, power) * x
        seg = (fx[:, 1:] - fx[:, :-1]) / (slope + 1.0)
    # a flat stretch (slope 0 to rounding) is integrated by the trapezoid rule instead
    flat = ~np.isfinite(seg) | (np.abs(slope) < 1e-9)
    if np.any(flat):
        trap = 0.5 * (_ipow(values[:, 1:], power) + _ipow(values[:, :-1], power)) * np.diff(x)
        seg = np.where(flat, trap, seg)
    tail = fx[:, 0] / (np.maximum(slope[:, 0], 0.0) + 1.0)
    return seg, tail


def cumulative_power_integral(values: Array, x: Array, power: float) -> Array:
    """integral_0^x_j values(x')**power dx' at every node, shape ``(P, M)``."""
    seg, tail = _power_law_segments(values, x, power)
    out = np.empty_like(values)
    out[:, 0] = tail
    np.cumsum(seg, axis=1, out=out[:, 1:])
    out[:, 1:] += tail[:, None]
    return out


@dataclass(frozen=True)
class MaterialTable:
    """Stress-grid tables of one batch of materials; built once per parameter batch.

    Attributes:
        tau: wall-stress grid (Pa), shape ``(M,)``.
        slip: slip velocity v_s(tau_j) (m/s), shape ``(P, M)``.
        shear: I(tau_j) * eta0 (Pa^3), the shear integral at unit zero-shear viscosity and
            cure factor 1, shape ``(P, M)``; divide by eta0 to get I (Pa^2/s).
    """

    tau: Array
    slip: Array
    shear: Array

    @classmethod
    def build(cls, tau: Array, n: Array, tau_star: Array, a_s: Array, tau_c: Array,
              m: Array, threshold_exponent: float = 10.0) -> MaterialTable:
        """Tabulate slip and shear laws; all parameters SI, shape ``(P,)``."""
        def col(v: Array) -> Array:
            return np.asarray(v, dtype=float)[:, None]

        rate = cross_shear_rate(tau[None, :], 1.0, col(tau_star), col(n))  # eta0 * gdot
        shear = cumulative_power_integral(rate * tau[None, :], tau, 1.0)
        slip = slip_velocity(tau[None, :], col(a_s), col(tau_c), col(m), threshold_exponent)
        return cls(tau=tau, slip=np.broadcast_to(slip, shear.shape), shear=shear)

    def take(self, rows: NDArray[np.int64]) -> MaterialTable:
        """The tables of a subset of parameter sets."""
        return MaterialTable(self.tau, self.slip[rows], self.shear[rows])

    def shear_at(self, cure: Array) -> Array:
        """I*eta0 with a cure factor c: c^2 K(tau/c), log-log interpolated; ``(P, M)``.

        Args:
            cure: cure factor per row, shape ``(P,)`` (>= 1).
        """
        if np.all(cure == 1.0):
            return self.shear
        ln_r = np.log(self.tau[1] / self.tau[0])
        shift = np.log(cure)[:, None] / ln_r  # fractional index shift
        idx = np.arange(self.tau.size)[None, :] - shift
        lo = np.clip(np.floor(idx).astype(int), 0, self.tau.size - 2)
        frac = idx - lo
        ln_k = np.log(np.maximum(self.shear, 1e-300))
        rows = np.arange(self.shear.shape[0])[:, None]
        out = ln_k[rows, lo] + frac * (ln_k[rows, lo + 1] - ln_k[rows, lo])
        return cure[:, None] ** 2 * np.exp(out)

    def flux(self, gap: Array, eta0: Array, cure: Array | None = None) -> Array:
        """Flux per unit width q(tau_j) (m^2/s) at gap ``gap`` (m), shape ``(P, M)``.

        Args:
            gap: gap H per row (m), shape ``(P,)``, or ``(P, N)`` for N gaps per row (the
                result is then ``(P, N, M)``).
            eta0: zero-shear viscosity per row (Pa s), shape ``(P,)``.
            cure: cure factor per row, shape ``(P,)``; ``None`` for 1.
        """
        shear = self.shear if cure is None else self.shear_at(cure)
        slip, coeff = self.slip, shear / (2.0 * eta0[:, None] * self.tau**2)
        if gap.ndim == 2:
            slip, coeff = slip[:, None, :], coeff[:, None, :]
        h = gap[..., None]
        return h * slip + (h * h) * coeff


@dataclass(frozen=True)
class FlowSolution:
    """Flow at the front for one solve; every field has shape ``(P,)``.

    Attributes:
        tau_front: wall shear stress at the flow front (Pa).
        flux_front: flux per unit width at the front (m^2/s).
        force: squeeze force (N).
        speed: spreading speed V_s such that the front flux is kinematic (m/s).
        out_of_table: the solution lies beyond the stress grid (extrapolated).
    """

    tau_front: Array
    flux_front: Array
    force: Array
    speed: Array
    out_of_table: NDArray[np.bool_]


@dataclass(frozen=True)
class FlowTable:
    """Force and speed along the stress grid for the current gap and charge size.

    Attributes:
        tau: stress grid (Pa), ``(M,)``.
        q: flux per unit width (m^2/s), ``(P, M)``.
        cum: Q_p, integral of q^p from 0 to tau_j, ``(P, M)``.
        force: F_j, force if the front stress were tau_j (N), ``(P, M)``.
        power: p (2 planar, 3 axisymmetric).
        force_scale: C L^d / H (m), ``(P,)``.
        kin: q_front = speed * kin; L (planar) or R / 2 (axisymmetric), ``(P,)``.
    """

    tau: Array
    q: Array
    cum: Array
    force: Array
    power: float
    force_scale: Array
    kin: Array

    @classmethod
    def build(cls, q: Array, tau: Array, planar: bool, length: Array, gap: Array,
              width: float) -> FlowTable:
        """Tables for a charge of half-length or radius ``length`` (m), ``(P,)``."""
        power = 2.0 if planar else 3.0
        cum = cumulative_power_integral(q, tau, power)
        if planar:
            scale = 2.0 * width * length**2 / gap
            kin = length
        else:
            scale = (2.0 * np.pi / 3.0) * length**3 / gap
            kin = 0.5 * length
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            phi = tau[None, :] - cum / _ipow(q, power)
        force = np.maximum(phi, 0.0, out=phi)
        force *= scale[:, None]
        return cls(tau, q, cum, force, power, scale, kin)

    def scaled(self, factor: Array) -> FlowTable:
        """The same tables with every force multiplied by ``factor`` ``(P,)``."""
        return replace(self, force=self.force * factor[:, None], force_scale=self.force_scale * factor)

    @property
    def speed(self) -> Array:
        """V_j, the spreading speed that gives front stress tau_j (m/s), ``(P, M)``."""
        return self.q / self.kin[:, None]

    def solve(self, alpha: Array, beta: Array, target: Array) -> FlowSolution:
        """Find the front stress where ``alpha * F + beta * V = target``.

        ``alpha`` (1/N) and ``beta`` (s/m) are non-negative and not both zero, so the
        left-hand side increases with the front stress and the root is unique.  All
        arguments have shape ``(P,)``.
        """
        if not np.any(beta):
            y, target = self.force, target / alpha
        elif not np.any(alpha):
            y, target = self.q, target * self.kin / beta
        else:
            y = alpha[:, None] * self.force + (beta / self.kin)[:, None] * self.q
        count = np.count_nonzero(y <= target[:, None], axis=1)
        j = np.clip(count - 1, 0, self.tau.size - 2)
        rows = np.arange(y.shape[0])
        y0, y1 = y[rows, j], y[rows, j + 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = np.log(np.maximum(target, 1e-300) / y0) / np.log(y1 / y0)
        theta = np.where(np.isfinite(theta), theta, 0.0)
        out = (count == 0) | (count == self.tau.size)
        ln_r = np.log(self.tau[1] / self.tau[0])
        tau_f = self.tau[j] * np.exp(theta * ln_r)
        q0, q1 = self.q[rows, j], self.q[rows, j + 1]
        k = np.log(q1 / q0) / ln_r
        q_f = q0 * np.exp(k * theta * ln_r)
        p = self.power
        with np.errstate(divide="ignore", invalid="ignore"):
            cum = self.cum[rows, j] + (_ipow(q_f, p) * tau_f - _ipow(q0, p) * self.tau[j]) / (p * k + 1.0)
            force = self.force_scale * np.maximum(tau_f - cum / _ipow(q_f, p), 0.0)
        # a zero target (press at rest) means no flow and no force
        rest = ~(target > 0)
        if np.any(rest):
            tau_f, q_f, force = (np.where(rest, 0.0, v) for v in (tau_f, q_f, force))
        return FlowSolution(tau_f, q_f, force, q_f / self.kin, out & ~rest)
