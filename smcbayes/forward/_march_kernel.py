"""numba kernel of :mod:`smcbayes.forward.march_compiled` (imported on first use).

Scalar transcription, row by row, of :mod:`smcbayes.forward.march` with the hooks of the
five built-in effects inlined; names follow that module.  Per-row parameters ``rp``
``(P, 17)``: solid0, k_c (Pa), b, zeta (Pa s), 1/k (m/N), t_ramp (s, 0 = none), beta,
heating flag, T_start (K), kappa (m^2/s), T_b (K), curing flag, k1, k2 (1/s), c1, c2,
alpha_g.  ``geo`` ``(13,)``: planar, width, area0, area_mould, gap0, gap_full, force_limit,
hold, speed, jump_time, shape weight, fill0, T_mould (SI).  Row state ``st`` ``(8,)``:
t, gap, area, deflection, phase, switch time, temperature (K), degree of cure.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from smcbayes.forward.effects.thermal import CURE_E, GAS_CONSTANT, MAX_CURE_FACTOR, RK4_STEP
from smcbayes.forward.march import HOLD_NODE_TOL, MAX_STRETCH, STEP_GROWTH
from smcbayes.forward.result import PHASE_FLOW, PHASE_FORCE, PHASE_FULL

Array = NDArray[np.float64]
_NAN = math.nan
_INF = math.inf
# IEEE division (x / 0 -> inf or nan) as in NumPy, on which the algorithm relies
_jit = njit(cache=True, error_model="numpy")


@_jit
def _nmax(a: float, b: float) -> float:
    """np.maximum: NaN-propagating maximum."""
    if a != a or b != b:
        return _NAN
    return a if a > b else b


@_jit
def _ipow(v: float, p: float) -> float:
    if p == 2.0:
        return v * v
    return v * v * v


@_jit
def _interp(x: float, xs: Array, ys: Array) -> float:
    """np.interp with end values held."""
    n = xs.size
    if x <= xs[0]:
        return ys[0]
    if x >= xs[n - 1]:
        return ys[n - 1]
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if xs[mid] <= x:
            lo = mid
        else:
            hi = mid
    return ys[lo] + (x - xs[lo]) * (ys[hi] - ys[lo]) / (xs[hi] - xs[lo])


@_jit
def _shape(area: float, geo: Array, sx: Array, low: Array, high: Array) -> float:
    """layout.square_charge_factor at the fill area / area_mould; 1 when no table."""
    if sx.size == 0:
        return 1.0
    fill, fill0, w = area / geo[3], geo[11], geo[10]
    u = min(max((fill - fill0) / max(1.0 - fill0, 1e-12), 0.0), 1.0)
    x = -math.log10(max(1.0 - u, 1e-12))
    return math.exp((1.0 - w) * math.log(_interp(x, sx, low)) + w * math.log(_interp(x, sx, high)))


@_jit
def _shear_at(shear: Array, j: int, cure: float, ln_r: float) -> float:
    """MaterialTable.shear_at at node ``j``: c^2 K(tau_j / c), log-log interpolated."""
    if cure == 1.0:
        return shear[j]
    M = shear.size
    idx = j - math.log(cure) / ln_r
    lo = min(max(math.floor(idx), 0), M - 2)
    frac = idx - lo
    k0, k1 = math.log(max(shear[lo], 1e-300)), math.log(max(shear[lo + 1], 1e-300))
    return cure**2 * math.exp(k0 + frac * (k1 - k0))


@_jit
def _viscosity(st: Array, rp: Array, geo: Array) -> tuple[float, float]:
    """(viscosity factor, cure factor) of the heating and curing effects."""
    eta_f, cure = 1.0, 1.0
    if rp[7] > 0:
        eta_f = math.exp(rp[10] * (1.0 / st[6] - 1.0 / geo[12]))
    if rp[11] > 0:
        alpha, alpha_g = st[7], rp[16]
        g = alpha_g - alpha
        factor = (alpha_g / g) ** (rp[14] + rp[15] * alpha) if g > 0 else _INF
        cure = min(factor, MAX_CURE_FACTOR)
    return eta_f, cure


@_jit
def _cure_rate(alpha: float, k1: float, k2: float) -> float:
    a = min(max(alpha, 0.0), 1.0)
    u = 1.0 - a
    return (k1 + k2 * a) * (u * u)


@_jit
def _advance_state(st: Array, gap: float, dt: float, rp: Array, geo: Array) -> None:
    """EffectStack.advance of heating and curing over ``dt`` at the step's start gap."""
    T = st[6]
    if rp[11] > 0:
        shift = math.exp(-CURE_E / GAS_CONSTANT * (1.0 / T - 1.0 / geo[12])) if rp[7] > 0 else 1.0
        k1, k2 = rp[12] * shift, rp[13] * shift
        n_sub = max(min(math.ceil(dt * (k1 + k2) / RK4_STEP), 50.0), 1.0)
        h = dt / n_sub
        alpha = st[7]
        for _ in range(int(n_sub)):
            r1 = _cure_rate(alpha, k1, k2)
            r2 = _cure_rate(alpha + 0.5 * h * r1, k1, k2)
            r3 = _cure_rate(alpha + 0.5 * h * r2, k1, k2)
            r4 = _cure_rate(alpha + h * r3, k1, k2)
            alpha = min(alpha + (h / 6.0) * (r1 + 2.0 * (r2 + r3) + r4), 1.0)
        st[7] = alpha
    if rp[7] > 0:
        tau_h = gap**2 / (math.pi**2 * rp[9])
        st[6] = geo[12] + (T - geo[12]) * math.exp(-dt / tau_h)


@_jit
def _build(tau: Array, slip: Array, shear: Array, eta0: float, cure: float, gap: float, area: float,
           geo: Array, sx: Array, low: Array, high: Array, q: Array, cum: Array,
           force: Array) -> tuple[float, float, float]:
    """FlowTable.build (+ scaled) into ``q, cum, force`` ``(M,)``; returns (scale, kin, p)."""
    M = tau.size
    planar = geo[0] > 0.5
    p = 2.0 if planar else 3.0
    ln_r = math.log(tau[1] / tau[0])
    for j in range(M):
        q[j] = gap * slip[j] + (gap * gap) * (_shear_at(shear, j, cure, ln_r) / (2.0 * eta0 * tau[j] ** 2))
    s_acc = 0.0
    slope0 = 0.0
    for j in range(M - 1):
        slope = math.log(q[j + 1] / q[j]) * (p / ln_r)
        fx0, fx1 = _ipow(q[j], p) * tau[j], _ipow(q[j + 1], p) * tau[j + 1]
        seg = (fx1 - fx0) / (slope + 1.0)
        if not math.isfinite(seg) or abs(slope) < 1e-9:
            seg = 0.5 * (_ipow(q[j + 1], p) + _ipow(q[j], p)) * (tau[j + 1] - tau[j])
        if j == 0:
            slope0 = slope
        s_acc += seg
        cum[j + 1] = s_acc
    tail = _ipow(q[0], p) * tau[0] / (_nmax(slope0, 0.0) + 1.0)
    cum[0] = tail
    for j in range(1, M):
        cum[j] += tail
    if planar:
        length = area / (2.0 * geo[1])
        scale, kin = 2.0 * geo[1] * length**2 / gap, length
    else:
        length = math.sqrt(area / math.pi)
        scale, kin = (2.0 * math.pi / 3.0) * length**3 / gap, 0.5 * length
    factor = _shape(area, geo, sx, low, high)
    for j in range(M):
        force[j] = _nmax(tau[j] - cum[j] / _ipow(q[j], p), 0.0) * scale * factor
    return scale * factor, kin, p


@_jit
def _solve(tau: Array, q: Array, cum: Array, force: Array, scale: float, kin: float, p: float,
           alpha: float, beta: float, target: float) -> tuple[float, float, float, float]:
    """FlowTable.solve for one row: (tau_front, q_front, force, speed)."""
    M = tau.size
    mode = 0 if beta == 0.0 else (1 if alpha == 0.0 else 2)
    if mode == 0:
        target = target / alpha
    elif mode == 1:
        target = target * kin / beta
    count = 0
    for j in range(M):
        y = force[j] if mode == 0 else (q[j] if mode == 1 else alpha * force[j] + (beta / kin) * q[j])
        if y <= target:
            count += 1
    j = min(max(count - 1, 0), M - 2)
    if mode == 0:
        y0, y1 = force[j], force[j + 1]
    elif mode == 1:
        y0, y1 = q[j], q[j + 1]
    else:
        y0 = alpha * force[j] + (beta / kin) * q[j]
        y1 = alpha * force[j + 1] + (beta / kin) * q[j + 1]
    theta = math.log(max(target, 1e-300) / y0) / math.log(y1 / y0) if y0 > 0 and y1 > 0 else _NAN
    if not math.isfinite(theta):
        theta = 0.0
    ln_r = math.log(tau[1] / tau[0])
    tau_f = tau[j] * math.exp(theta * ln_r)
    q0, q1 = q[j], q[j + 1]
    k = math.log(q1 / q0) / ln_r
    q_f = q0 * math.exp(k * theta * ln_r)
    cum_f = cum[j] + (_ipow(q_f, p) * tau_f - _ipow(q0, p) * tau[j]) / (p * k + 1.0)
    f = scale * _nmax(tau_f - cum_f / _ipow(q_f, p), 0.0)
    if not target > 0:
        tau_f, q_f, f = 0.0, 0.0, 0.0
    return tau_f, q_f, f, q_f / kin


@_jit
def _compaction_at(solid: float, rp: Array) -> float:
    """compaction_pressure P_c(s) (Pa) of the compressibility effect (no end-of-range cut)."""
    s0 = rp[0]
    if s0 >= 1.0 or solid >= 1.0:
        return _INF
    grow = max(solid / s0, 1.0) ** rp[2] - 1.0
    return max(rp[1] * grow * (1.0 - s0) / (1.0 - solid), 0.0)


@_jit
def _compaction(gap: float, area: float, dt: float, rp: Array, geo: Array) -> tuple[float, float, float]:
    """march._compaction for one row: (P_c, zeta, zeta_eff); (inf, 0, 0) if incompressible."""
    s0 = rp[0]
    if s0 >= 1.0:
        return _INF, 0.0, 0.0
    solid = min(s0 * geo[4] * geo[2] / (gap * area), 1.0)
    pc = _compaction_at(solid, rp)
    if solid >= 1.0 - 1e-9:
        pc = _INF
    ds = 1e-6 * (1.0 - solid)
    pc_up = _compaction_at(solid + ds, rp)
    stiff = solid * (pc_up - pc) / ds if math.isfinite(pc) and math.isfinite(pc_up) else _INF
    return pc, rp[3], rp[3] + dt * stiff


@_jit
def _evaluate(st: Array, dt: float, tau: Array, slip: Array, shear: Array, eta0: float, rp: Array,
              geo: Array, sx: Array, low: Array, high: Array, q: Array, cum: Array,
              force_t: Array) -> tuple[float, float, float, float, float]:
    """march._evaluate for one row.

    Returns (force N, gap speed V, spreading speed V_s, ram speed (m/s), balance force N)."""
    t, gap, area, delta = st[0], st[1], st[2], st[3]
    a_m, f_lim = geo[3], geo[6]
    full = area >= a_m * (1.0 - 1e-12)
    fc = st[4] == PHASE_FORCE
    compressible = rp[0] < 1.0
    pc, zeta, zeta_eff = _compaction(gap, area, dt, rp, geo)
    free = geo[8] * -math.expm1(-t / rp[5]) if rp[5] > 0.0 else geo[8]
    a0 = rp[4] / dt + free * rp[6] / f_lim
    t0 = free + delta / dt
    force, speed, spread = f_lim, 0.0, 0.0
    balance = force
    if (not full) or (not fc and not compressible):
        eta_f, cure = _viscosity(st, rp, geo)
        scale, kin, p = _build(tau, slip, shear, eta0 * eta_f, cure, gap, area, geo, sx, low, high, q,
                               cum, force_t)
        if not fc:
            force, speed, spread, balance = _speed_control(tau, q, cum, force_t, scale, kin, p, a0, t0,
                                                           pc, zeta, zeta_eff, area, gap)
        else:
            spread = _solve(tau, q, cum, force_t, scale, kin, p, 1.0, 0.0, f_lim)[3]
    creep = 0.0
    if zeta > 0 and math.isfinite(pc):
        creep = _nmax(f_lim / area - pc, 0.0) * gap / zeta
    if fc:
        speed = spread + creep
    if compressible and full and not fc:
        force, balance, speed = _packing(gap, pc, zeta, zeta_eff, a0, t0, geo)
        spread = 0.0
    if fc:
        balance = force
    return force, speed, spread, free * (1.0 - rp[6] * balance / f_lim), balance


@_jit
def _packing(gap: float, pc: float, zeta: float, zeta_eff: float, a0: float, t0: float,
             geo: Array) -> tuple[float, float, float]:
    """march._packing for one row: (force, balance force, closing speed)."""
    a_m = geo[3]
    v = _nmax((t0 - a0 * a_m * pc) / (1.0 + a0 * a_m * zeta_eff / gap), 0.0)
    if not math.isfinite(v):
        v = 0.0
    if v > 0:
        return a_m * (pc + zeta * v / gap), a_m * (pc + zeta_eff * v / gap), v
    return a_m * pc, a_m * pc, v


@_jit
def _speed_control(tau: Array, q: Array, cum: Array, force_t: Array, scale: float, kin: float,
                   p: float, a0: float, t0: float, pc: float, zeta: float, zeta_eff: float,
                   area: float, gap: float) -> tuple[float, float, float, float]:
    """march._speed_control for one row: (force, speed, spread, balance force)."""
    force = _solve(tau, q, cum, force_t, scale, kin, p, a0, 1.0, t0)[2]
    spread = _nmax(t0 - a0 * force, 0.0)
    speed = spread
    if force > area * pc:
        if zeta_eff > 0:
            r = gap / (zeta_eff * area)
            s1 = _solve(tau, q, cum, force_t, scale, kin, p, a0 + r, 1.0, t0 + pc * gap / zeta_eff)
            v1 = _nmax(t0 - a0 * s1[2], s1[3])
            f1 = s1[2] - area * (zeta_eff - zeta) * (v1 - s1[3]) / gap
            return f1, v1, s1[3], s1[2]
        f2 = area * pc
        s2 = _solve(tau, q, cum, force_t, scale, kin, p, 1.0, 0.0, f2)
        return f2, t0 - a0 * f2, s2[3], f2
    return force, speed, spread, force


@_jit
def _advance(st: Array, balance: float, speed: float, spread: float, dt: float, rp: Array,
             geo: Array) -> None:
    """march._advance for one active row, in place."""
    a_m = geo[3]
    gap0, area0 = st[1], st[2]
    gap = gap0 - speed * dt
    ratio = spread / speed if speed > 0 else 0.0
    area = area0 * (gap0 / gap) ** ratio
    fills = area > a_m and area0 < a_m
    if fills:
        gap = gap0 * (area0 / a_m) ** (1.0 / ratio)
        dt = (gap0 - gap) / speed
        area = a_m
    area = min(area, a_m)
    s0 = rp[0]
    mass = s0 * geo[4] * geo[2]
    if s0 < 1.0 and gap * area < mass and ratio < 1.0:
        gap_s1 = (mass / (area0 * gap0**ratio)) ** (1.0 / (1.0 - ratio))
        area = min(area0 * (gap0 / gap_s1) ** ratio, a_m)
        dt = min(max((gap0 - gap_s1) / speed, 0.0), dt)
        gap = gap_s1
    st[0] += dt
    st[1], st[2] = gap, area
    _advance_state(st, gap0, dt, rp, geo)
    if st[4] != PHASE_FORCE:
        st[3] = balance * rp[4]
        if fills and s0 < 1.0:
            st[4] = PHASE_FULL


@_jit
def _switch(st: Array, prev: Array, prev_force: float, force: float, first: bool, rp: Array,
            geo: Array) -> bool:
    """march._switch for one row, in place; True if the row switched."""
    f_lim = geo[6]
    if st[4] == PHASE_FORCE or not force >= f_lim:
        return False
    if not first:
        theta = (f_lim - prev_force) / (force - prev_force)
        if math.isinf(force) or theta != theta:
            theta = 1.0
        theta = min(max(theta, 0.0), 1.0)
        for i in (0, 1, 3, 6, 7):
            st[i] = prev[i] + theta * (st[i] - prev[i])
        st[2] = prev[2] * (st[2] / prev[2]) ** theta
    st[4] = PHASE_FORCE
    st[5] = st[0]
    st[3] = f_lim * rp[4]
    return True


@_jit
def _hold_step(st: Array, speed: float, dt0: float, travel: float, hold_steps: int, steps: int,
               hold: float) -> float:
    """Force-controlled step of march._step_size: geometric schedule capped in gap change."""
    ratio = max(hold / dt0, 1.0 + 1e-9)
    elapsed = max(st[0] - st[5], 0.0)
    node = hold_steps * math.log(max(elapsed, dt0 * 1e-3) / dt0) / math.log(ratio)
    if node != node:
        node = -1.0
    k = min(max(math.floor(node + HOLD_NODE_TOL) + 1.0, 0.0), float(hold_steps))
    target = st[5] + dt0 * ratio ** (k / hold_steps)
    dt = min(target, st[5] + hold) - st[0]
    cap = travel / steps / speed if speed > 0 else _INF
    return max(min(dt, cap), 1e-12)


@_jit
def _stretch(ram: float, force_rate: float, ram_rate: float, v_ref: float, t_close: float,
             f_lim: float, travel: float) -> float:
    """march._closing_step's stretch factor."""
    rate = _nmax(_nmax(ram / travel, ram_rate * t_close) / v_ref, force_rate * t_close / f_lim)
    inv = 1.0 / rate
    if inv != inv:
        inv = 1.0
    elif math.isinf(inv):
        inv = MAX_STRETCH
    return min(max(inv, 1.0), MAX_STRETCH)


@_jit
def march_rows(tau: Array, slip: Array, shear: Array, eta0: Array, rp: Array, geo: Array, sx: Array,
               low: Array, high: Array, steps: int, hold_steps: int,
               max_iter: int) -> tuple[Array, Array, Array, Array]:
    """march.march for every row.

    Returns:
        ``(rec, count, switch, done)``: node records ``(6, P, max_iter)`` (time, gap, area,
        force, deflection, solid; padded with each row's last node), valid nodes per row,
        switch time (s) and finished flag per row.
    """
    P, M = slip.shape
    rec = np.empty((6, P, max_iter))
    count = np.zeros(P, dtype=np.int64)
    switch = np.full(P, _NAN)
    done = np.zeros(P, dtype=np.bool_)
    q, cum, force_t = np.empty(M), np.empty(M), np.empty(M)
    gap0, area0, f_lim, hold, v_ref = geo[4], geo[2], geo[6], geo[7], geo[8]
    st, prev = np.empty(8), np.empty(8)
    for r in range(P):
        s0 = min(rp[r, 0], 1.0)
        gap_end = s0 * geo[5]
        dt0 = (gap0 - gap_end) / (v_ref * steps)
        t_close = dt0 * steps
        travel = 1.0 + f_lim * rp[r, 4] / (gap0 - gap_end)
        st[0], st[1], st[2], st[3], st[4], st[5] = 0.0, gap0, area0, 0.0, PHASE_FLOW, _NAN
        st[6], st[7] = rp[r, 8], 0.0
        prev[:] = st
        prev_force, prev_ram, closing = 0.0, 0.0, dt0
        last = 0
        for it in range(max_iter):
            force, speed, spread, ram, balance = _evaluate(st, closing, tau, slip[r], shear[r], eta0[r],
                                                           rp[r], geo, sx, low, high, q, cum, force_t)
            if _switch(st, prev, prev_force, force, it == 0, rp[r], geo):
                force, speed, spread, ram, balance = _evaluate(st, closing, tau, slip[r], shear[r],
                                                               eta0[r], rp[r], geo, sx, low, high, q,
                                                               cum, force_t)
            rec[0, r, it], rec[1, r, it], rec[2, r, it] = st[0], st[1], st[2]
            rec[3, r, it], rec[4, r, it] = force, force * rp[r, 4]
            rec[5, r, it] = s0 * gap0 * area0 / (st[1] * st[2])
            last = it
            count[r] = it + 1
            jump = s0 >= 1.0 and st[2] >= geo[3] * (1 - 1e-12) and st[4] != PHASE_FORCE
            if jump:
                st[0] += geo[9]
                st[4] = PHASE_FORCE
                st[5] = st[0]
            elif st[4] == PHASE_FORCE and st[0] >= st[5] + hold - 1e-9:
                done[r] = True
                break
            if st[4] == PHASE_FORCE and hold > 0:
                dt = _hold_step(st, speed, dt0, gap0 - gap_end, hold_steps, steps, hold)
            else:
                dt = closing
            elapsed = st[0] - prev[0] if st[0] > prev[0] else 0.0
            force_rate = abs(force - prev_force) / elapsed if elapsed > 0 else (
                _NAN if force == prev_force else _INF)
            ram_rate = abs(ram - prev_ram) / elapsed if elapsed > 0 else (
                _NAN if ram == prev_ram else _INF)
            prev[:] = st
            prev_force, prev_ram = force, ram
            if not jump:
                _advance(st, balance, speed, spread, dt, rp[r], geo)
            closing = min(max(dt0 * _stretch(ram, force_rate, ram_rate, v_ref, t_close, f_lim, travel),
                              closing / STEP_GROWTH), closing * STEP_GROWTH)
        switch[r] = st[5]
        for k in range(6):
            rec[k, r, last + 1:] = rec[k, r, last]
    return rec, count, switch, done
