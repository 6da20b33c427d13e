"""numba kernel of :mod:`smcbayes.forward.march_compiled` (imported on first use).

Scalar transcription, row by row, of :mod:`smcbayes.forward.march`; names follow that
module.  The laws of the effects (:mod:`smcbayes.forward.laws`) and the decisions of the
press programme and the step control (:mod:`smcbayes.forward.programme`) are not written
here: the same functions are compiled and called on one row's floats.  The flat arrays
follow the named layouts of :mod:`smcbayes.forward.kernel_layout`: per-row parameters
``rp`` ``(P, len(ROW))``, configuration ``geo`` ``(len(GEO),)`` and row state ``st``
``(len(STATE),)``; the slot indices below are compile-time constants.

numba's disk cache is keyed on this file only: after changing ``laws``, ``programme`` or
``kernel_layout``, :func:`smcbayes.forward.march_compiled` notices the change and
recompiles (see ``march_compiled._kernel``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import overload
from numpy.typing import NDArray

from smcbayes.forward import laws, programme
from smcbayes.forward.kernel_layout import GEO, INTERPOLATED, ROW, STATE
from smcbayes.forward.laws import MAX_CURE_FACTOR
from smcbayes.forward.programme import STEP_GROWTH
from smcbayes.forward.result import PHASE_FLOW, PHASE_FORCE, PHASE_FULL

Array = NDArray[np.float64]
_NAN = math.nan
_INF = math.inf
# IEEE division (x / 0 -> inf or nan) as in NumPy, on which the algorithm relies
_jit = njit(cache=True, error_model="numpy")



@overload(laws.select, jit_options={"cache": True})
def _select_scalar(condition, a, b):  # type: ignore[no-untyped-def]  # numba matches the signatures
    """:func:`laws.select` on floats: a branch (numba's ``np.where`` gives 0-d arrays)."""

    def impl(condition, a, b):  # type: ignore[no-untyped-def]
        return a if condition else b

    return impl


_compaction_pressure = _jit(laws.compaction_pressure)
_relax_temperature = _jit(laws.mould_temperature_relaxation)
_arrhenius = _jit(laws.arrhenius_factor)
_cure_shift = _jit(laws.cure_rate_shift)
_cure_substeps = _jit(laws.cure_substeps)
_cure_rk4_step = _jit(laws.cure_rk4_step)
_cure_factor = _jit(laws.cure_factor)
_ramp_speed = _jit(laws.ramp_speed)
_reaches_limit = _jit(programme.reaches_limit)
_crossing = _jit(programme.crossing_fraction)
_hold_over = _jit(programme.hold_over)
_fills_and_stops = _jit(programme.fills_and_stops)
_load_travel = _jit(programme.load_travel)
_hold_step = _jit(programme.hold_step)
_stretch = _jit(programme.closing_stretch)
_deflection = _jit(programme.step_deflection)
_frame_load = _jit(programme.frame_load)

DISPATCHERS = (_compaction_pressure, _relax_temperature, _arrhenius, _cure_shift, _cure_substeps,
               _cure_rk4_step, _cure_factor, _ramp_speed, _reaches_limit, _crossing, _hold_over,
               _fills_and_stops, _load_travel, _hold_step, _stretch, _deflection,
               _frame_load)
"""Compiled shared functions (their caches go with the kernel's, see the module docstring)."""

# row parameters
R_SOLID0, R_INV_K = ROW["solid0"], ROW["inv_k"]
R_K_C, R_B, R_ZETA = ROW["compaction_modulus"], ROW["compaction_exponent"], ROW["bulk_viscosity"]
R_RAMP_ON, R_T_RAMP, R_BETA = ROW["on:speed_ramp"], ROW["ramp_time"], ROW["load_slowdown"]
R_HEAT_ON, R_KAPPA, R_T_B, R_T0 = ROW["on:heating"], ROW["diffusivity"], ROW["T_b"], ROW["temperature0"]
R_CURE_ON, R_K1, R_K2 = ROW["on:curing"], ROW["k1"], ROW["k2"]
R_C1, R_C2, R_ALPHA_G, R_ALPHA0 = ROW["c1"], ROW["c2"], ROW["alpha_g"], ROW["cure0"]
# configuration and press programme
G_PLANAR, G_WIDTH, G_AREA0, G_AREA_M = GEO["planar"], GEO["width"], GEO["area0"], GEO["area_mould"]
G_GAP0, G_GAP_FULL, G_F_LIM, G_HOLD = GEO["gap0"], GEO["gap_full"], GEO["force_limit"], GEO["hold"]
G_SPEED, G_JUMP, G_SHAPE_W, G_FILL0 = GEO["speed"], GEO["jump_time"], GEO["shape_weight"], GEO["fill0"]
G_T_MOULD = GEO["T_mould"]
# row state
S_T, S_GAP, S_AREA, S_DELTA = STATE["t"], STATE["gap"], STATE["area"], STATE["delta"]
S_PHASE, S_SWITCH, S_TEMP, S_CURE = STATE["phase"], STATE["switch"], STATE["temperature"], STATE["cure"]
N_STATE = len(STATE)
N_REC = 6
"""node records: time, gap, area, force, deflection, solid"""


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
    fill, fill0, w = area / geo[G_AREA_M], geo[G_FILL0], geo[G_SHAPE_W]
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
    if rp[R_HEAT_ON] > 0:
        eta_f = _arrhenius(st[S_TEMP], geo[G_T_MOULD], rp[R_T_B])
    if rp[R_CURE_ON] > 0:
        cure = _cure_factor(st[S_CURE], rp[R_ALPHA_G], rp[R_C1], rp[R_C2], MAX_CURE_FACTOR)
    return eta_f, cure


@_jit
def _advance_state(st: Array, gap: float, dt: float, rp: Array, geo: Array) -> None:
    """EffectStack.advance of heating and curing over ``dt`` at the step's start gap."""
    T = st[S_TEMP]
    if rp[R_CURE_ON] > 0:
        shift = _cure_shift(T, geo[G_T_MOULD]) if rp[R_HEAT_ON] > 0 else 1.0
        k1, k2 = rp[R_K1] * shift, rp[R_K2] * shift
        n_sub = _cure_substeps(dt, k1, k2)
        h = dt / n_sub
        alpha = st[S_CURE]
        for _ in range(int(n_sub)):
            alpha = _cure_rk4_step(alpha, k1, k2, h)
        st[S_CURE] = alpha
    if rp[R_HEAT_ON] > 0:
        st[S_TEMP] = _relax_temperature(T, geo[G_T_MOULD], gap, rp[R_KAPPA], dt)


@_jit
def _build(tau: Array, slip: Array, shear: Array, eta0: float, cure: float, gap: float, area: float,
           geo: Array, sx: Array, low: Array, high: Array, q: Array, cum: Array,
           force: Array) -> tuple[float, float, float]:
    """FlowTable.build (+ scaled) into ``q, cum, force`` ``(M,)``; returns (scale, kin, p)."""
    M = tau.size
    planar = geo[G_PLANAR] > 0.5
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
        length = area / (2.0 * geo[G_WIDTH])
        scale, kin = 2.0 * geo[G_WIDTH] * length**2 / gap, length
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
def _compaction(gap: float, area: float, dt: float, rp: Array, geo: Array) -> tuple[float, float, float]:
    """march._compaction for one row: (P_c, zeta, zeta_eff); (inf, 0, 0) if incompressible."""
    s0 = rp[R_SOLID0]
    if s0 >= 1.0:
        return _INF, 0.0, 0.0
    k_c, b = rp[R_K_C], rp[R_B]
    solid = min(s0 * geo[G_GAP0] * geo[G_AREA0] / (gap * area), 1.0)
    pc = _compaction_pressure(solid, s0, k_c, b)
    if solid >= 1.0 - 1e-9:
        pc = _INF
    ds = 1e-6 * (1.0 - solid)
    pc_up = _compaction_pressure(solid + ds, s0, k_c, b)
    stiff = solid * (pc_up - pc) / ds if math.isfinite(pc) and math.isfinite(pc_up) else _INF
    return pc, rp[R_ZETA], rp[R_ZETA] + dt * stiff


@_jit
def _evaluate(st: Array, dt: float, tau: Array, slip: Array, shear: Array, eta0: float, rp: Array,
              geo: Array, sx: Array, low: Array, high: Array, q: Array, cum: Array,
              force_t: Array) -> tuple[float, float, float, float, float]:
    """march._evaluate for one row.

    Returns (force N, gap speed V, spreading speed V_s, ram speed (m/s), balance force N)."""
    t, gap, area, delta = st[S_T], st[S_GAP], st[S_AREA], st[S_DELTA]
    a_m, f_lim = geo[G_AREA_M], geo[G_F_LIM]
    full = area >= a_m * (1.0 - 1e-12)
    fc = st[S_PHASE] == PHASE_FORCE
    compressible = rp[R_SOLID0] < 1.0
    pc, zeta, zeta_eff = _compaction(gap, area, dt, rp, geo)
    free = _ramp_speed(geo[G_SPEED], t, rp[R_T_RAMP]) if rp[R_RAMP_ON] > 0 else geo[G_SPEED]
    a0 = rp[R_INV_K] / dt + free * rp[R_BETA] / f_lim
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
    return force, speed, spread, free * (1.0 - rp[R_BETA] * balance / f_lim), balance


@_jit
def _packing(gap: float, pc: float, zeta: float, zeta_eff: float, a0: float, t0: float,
             geo: Array) -> tuple[float, float, float]:
    """march._packing for one row: (force, balance force, closing speed)."""
    a_m = geo[G_AREA_M]
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
    a_m = geo[G_AREA_M]
    gap0, area0 = st[S_GAP], st[S_AREA]
    solved_dt = dt
    gap = gap0 - speed * dt
    ratio = spread / speed if speed > 0 else 0.0
    area = area0 * (gap0 / gap) ** ratio
    fills = area > a_m and area0 < a_m
    if fills:
        gap = gap0 * (area0 / a_m) ** (1.0 / ratio)
        dt = (gap0 - gap) / speed
        area = a_m
    area = min(area, a_m)
    s0 = rp[R_SOLID0]
    mass = s0 * geo[G_GAP0] * geo[G_AREA0]
    if s0 < 1.0 and gap * area < mass and ratio < 1.0:
        gap_s1 = (mass / (area0 * gap0**ratio)) ** (1.0 / (1.0 - ratio))
        area = min(area0 * (gap0 / gap_s1) ** ratio, a_m)
        dt = min(max((gap0 - gap_s1) / speed, 0.0), dt)
        gap = gap_s1
    st[S_T] += dt
    st[S_GAP], st[S_AREA] = gap, area
    _advance_state(st, gap0, dt, rp, geo)
    if st[S_PHASE] != PHASE_FORCE:
        st[S_DELTA] = _deflection(st[S_DELTA], balance * rp[R_INV_K], dt, solved_dt)
        if fills and s0 < 1.0:
            st[S_PHASE] = PHASE_FULL


@_jit
def _switch(st: Array, prev: Array, prev_force: float, force: float, first: bool, rp: Array,
            geo: Array) -> bool:
    """march._switch for one row, in place; True if the row switched."""
    f_lim = geo[G_F_LIM]
    if st[S_PHASE] == PHASE_FORCE or not _reaches_limit(force, f_lim):
        return False
    if not first:
        theta = _crossing(prev_force, force, f_lim)
        for i in INTERPOLATED:
            st[i] = prev[i] + theta * (st[i] - prev[i])
        st[S_AREA] = prev[S_AREA] * (st[S_AREA] / prev[S_AREA]) ** theta
    st[S_PHASE] = PHASE_FORCE
    st[S_SWITCH] = st[S_T]
    st[S_DELTA] = f_lim * rp[R_INV_K]
    return True


@_jit
def _start(st: Array, rp: Array, geo: Array) -> None:
    """State of a row at first contact."""
    st[:] = 0.0
    st[S_GAP], st[S_AREA], st[S_PHASE], st[S_SWITCH] = geo[G_GAP0], geo[G_AREA0], PHASE_FLOW, _NAN
    st[S_TEMP], st[S_CURE] = rp[R_T0], rp[R_ALPHA0]


@_jit
def _record(rec: Array, r: int, it: int, st: Array, force: float, rp: Array, geo: Array) -> None:
    """Node ``it`` of row ``r``: time, gap, area, force, deflection, solid fraction."""
    rec[0, r, it], rec[1, r, it], rec[2, r, it] = st[S_T], st[S_GAP], st[S_AREA]
    rec[3, r, it], rec[4, r, it] = force, force * rp[R_INV_K]
    s0 = min(rp[R_SOLID0], 1.0)
    rec[5, r, it] = s0 * geo[G_GAP0] * geo[G_AREA0] / (st[S_GAP] * st[S_AREA])


@_jit
def _rate(value: float, prev: float, elapsed: float) -> float:
    """|value - prev| / elapsed; NaN (no change) or inf when no time elapsed."""
    if elapsed > 0:
        return abs(value - prev) / elapsed
    return _NAN if value == prev else _INF


@_jit
def _march_row(r: int, tau: Array, slip: Array, shear: Array, eta0: float, rp: Array, geo: Array,
               sx: Array, low: Array, high: Array, steps: int, hold_steps: int, rec: Array,
               work: Array) -> tuple[int, bool, float]:
    """march.march for row ``r``: fills ``rec[:, r]``; returns (valid nodes, finished,
    switch time (s))."""
    q, cum, force_t = work[0], work[1], work[2]
    st, prev = np.empty(N_STATE), np.empty(N_STATE)
    s0 = min(rp[R_SOLID0], 1.0)
    gap_end = s0 * geo[G_GAP_FULL]
    travel = geo[G_GAP0] - gap_end
    v_ref, f_lim, hold = geo[G_SPEED], geo[G_F_LIM], geo[G_HOLD]
    dt0 = travel / (v_ref * steps)
    t_close = dt0 * steps
    ram_travel = 1.0 + f_lim * rp[R_INV_K] / travel
    _start(st, rp, geo)
    prev[:] = st
    prev_force, prev_ram, closing = 0.0, 0.0, dt0
    for it in range(rec.shape[2]):
        out = _evaluate(st, closing, tau, slip, shear, eta0, rp, geo, sx, low, high, q, cum, force_t)
        if _switch(st, prev, prev_force, out[0], it == 0, rp, geo):
            out = _evaluate(st, closing, tau, slip, shear, eta0, rp, geo, sx, low, high, q, cum, force_t)
        force, speed, spread, ram, balance = out
        _record(rec, r, it, st, force, rp, geo)
        fc = st[S_PHASE] == PHASE_FORCE
        jump = _fills_and_stops(s0 >= 1.0, st[S_AREA], geo[G_AREA_M], fc)
        if jump:
            free = _ramp_speed(geo[G_SPEED], st[S_T], rp[R_T_RAMP]) if rp[R_RAMP_ON] > 0 else geo[G_SPEED]
            free = _nmax(free, 1e-6 * geo[G_SPEED])
            # programme.load_time, whose call of load_travel numba would not see
            loaded = _frame_load(force, st[S_DELTA], rp[R_INV_K])
            st[S_T] += _nmax(_load_travel(loaded, f_lim, rp[R_INV_K], rp[R_BETA]) / free, geo[G_JUMP])
            st[S_PHASE] = PHASE_FORCE
            st[S_SWITCH] = st[S_T]
        elif fc and _hold_over(st[S_T], st[S_SWITCH], hold):
            return it + 1, True, st[S_SWITCH]
        if st[S_PHASE] == PHASE_FORCE and hold > 0:
            dt = _hold_step(st[S_T], st[S_SWITCH], speed, dt0, hold, float(hold_steps), travel / steps)
        else:
            dt = closing
        elapsed = st[S_T] - prev[S_T] if st[S_T] > prev[S_T] else 0.0
        force_rate, ram_rate = _rate(force, prev_force, elapsed), _rate(ram, prev_ram, elapsed)
        prev[:] = st
        prev_force, prev_ram = force, ram
        if not jump:
            _advance(st, balance, speed, spread, dt, rp, geo)
        closing = min(max(dt0 * _stretch(ram, force_rate, ram_rate, ram_travel, t_close, v_ref, f_lim),
                          closing / STEP_GROWTH), closing * STEP_GROWTH)
    return rec.shape[2], False, st[S_SWITCH]


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
    rec = np.empty((N_REC, P, max_iter))
    count = np.zeros(P, dtype=np.int64)
    switch = np.full(P, _NAN)
    done = np.zeros(P, dtype=np.bool_)
    work = np.empty((3, M))
    for r in range(P):
        n, finished, t_switch = _march_row(r, tau, slip[r], shear[r], eta0[r], rp[r], geo, sx, low, high,
                                           steps, hold_steps, rec, work)
        count[r], done[r], switch[r] = n, finished, t_switch
        for k in range(N_REC):
            rec[k, r, n:] = rec[k, r, n - 1]
    return rec, count, switch, done
