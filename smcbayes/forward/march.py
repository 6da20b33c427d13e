"""Time-marching path of the 1-D solver, for effects that carry state.

Each step solves, per parameter set, the closing-rate balance of the current state

    spreading speed V_s (flow tables)  +  compaction speed V_c  =  gap closing speed V,
    V + F / (k dt) + U_set beta F / F_limit = U_set + delta / dt     (speed control),
    F / A = P_c(s) + zeta V_c / H  while the charge compacts,         F = F_limit (force control),

where k is the press stiffness (frame deflection delta = F / k, integrated by backward
Euler), U_set the free ram speed with load sensitivity beta (speed ramp), P_c(s) the
compaction pressure and zeta the bulk viscosity (compressibility).  Every case reduces to
one monotone table solve ``alpha F + beta V = target`` (see
:meth:`~smcbayes.forward.flux.FlowTable.solve`).  Gap, charge area and effect states then
advance by explicit Euler; the charge area is updated as A (H/H')^(V_s/V), which keeps
A H constant to round-off when the charge does not compact, and the solid fraction is
derived from mass conservation, s = s0 H0 A0 / (H A), so solid mass is conserved exactly.
Switching to force control and filling the cavity are located inside a step by
interpolation.  Speed-controlled steps are the nominal step (1/steps of the nominal
closing), stretched up to 4x while the ram and the force move slowly; force-controlled
steps follow a geometric schedule over the hold, capped in gap change.

:mod:`smcbayes.forward.march_compiled` runs the same algorithm compiled for the built-in
effects; this module is the reference and serves any other effect.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.case import AT_REST, Case, shape_factor
from smcbayes.forward.effects.base import EffectStack
from smcbayes.forward.flux import FlowTable, MaterialTable
from smcbayes.forward.nodes import Nodes
from smcbayes.forward.programme import (
    STEP_GROWTH,
    MarchOptions,
    PressProgramme,
    closing_stretch,
    fills_and_stops,
    frame_load,
    hold_step,
    load_time,
    load_travel,
    step_deflection,
)
from smcbayes.forward.result import PHASE_FLOW, PHASE_FORCE, PHASE_FULL, STATUS_OK

Array = NDArray[np.float64]


@dataclass
class _State:
    """Per-row state, every field ``(P,)`` (extra: effect states by name)."""

    t: Array
    gap: Array
    area: Array
    delta: Array
    phase: NDArray[np.int8]
    switch: Array
    extra: dict[str, Array] = field(default_factory=dict)

    def copy(self) -> _State:
        return _State(self.t.copy(), self.gap.copy(), self.area.copy(), self.delta.copy(),
                      self.phase.copy(), self.switch.copy(), {k: v.copy() for k, v in self.extra.items()})

    def blend(self, other: _State, theta: Array, rows: NDArray[np.bool_]) -> None:
        """Move ``rows`` to ``self + theta (other - self)``; area interpolated in log."""
        th = np.where(rows, theta, 0.0)
        for name in ("t", "gap", "delta"):
            a, b = getattr(self, name), getattr(other, name)
            setattr(self, name, np.where(rows, a + th * (b - a), a))
        self.area = np.where(rows, self.area * (other.area / self.area) ** th, self.area)
        for k, v in self.extra.items():
            self.extra[k] = np.where(rows, v + th * (other.extra[k] - v), v)


@dataclass
class _Rates:
    """Result of one balance solve, every field ``(P,)``: force (N), gap speed V,
    spreading speed V_s and ram speed (m/s), and the force of the closing balance (N): the
    force with the compaction pressure taken at the end of the step (see
    :func:`_compaction`), which sets the frame deflection; it equals ``force`` except
    while the charge compacts."""

    force: Array
    speed: Array
    spread: Array
    ram: Array | None = None
    balance: Array | None = None


@dataclass(frozen=True)
class _Context:
    """Everything constant over a run."""

    case: Case
    press: PressProgramme
    p: dict[str, Array]
    effects: EffectStack
    table: MaterialTable
    solid0: Array
    compressible: NDArray[np.bool_]
    inv_k: Array
    dt_close: Array
    gap_end: Array
    v_ref: float
    t_close: Array
    travel: Array
    shape_correction: bool = True

    def solid(self, gap: Array, area: Array) -> Array:
        c = self.case
        return self.solid0 * c.gap0 * c.area0 / (gap * area)


def _flow_table(ctx: _Context, st: _State, rows: NDArray[np.int64]) -> FlowTable:
    eta_f, cure = ctx.effects.viscosity_factors(ctx.case, ctx.p, st.extra, st.t.size)
    table = ctx.table.take(rows)
    q = table.flux(st.gap[rows], (ctx.p["B"] * eta_f)[rows], cure[rows])
    c = ctx.case
    ft = FlowTable.build(q, table.tau, c.planar, c.front(st.area[rows]), st.gap[rows], c.width)
    factor = shape_factor(c, st.area[rows]) if ctx.shape_correction else None
    return ft if factor is None else ft.scaled(factor)


def _compaction(ctx: _Context, st: _State, dt: Array) -> tuple[Array, Array, Array]:
    """Compaction pressure P_c (Pa), bulk viscosity zeta and its effective value over a
    step ``dt`` (Pa s), each ``(P,)``.

    The pressure enters the closing balance at the end of the step, linearised:
    zeta_eff = zeta + dt s P_c'(s) (P_c' by a forward difference; the law has a kink at
    s0).  Taken at the start of the step instead, a stiff compaction law makes the split
    between spreading and compaction, or the gap and a compliant frame, chatter from step
    to step (rate-independent compaction, zeta = 0, is the default).
    """
    P = st.t.size
    if not ctx.compressible.any():
        return np.full(P, np.inf), np.zeros(P), np.zeros(P)
    solid = np.minimum(ctx.solid(st.gap, st.area), 1.0)
    pc, zeta = ctx.effects.compaction(ctx.case, ctx.p, solid)
    # a step may end at the pore-free state to round-off; no compaction is left there
    pc = np.where(solid >= 1.0 - 1e-9, np.inf, pc)
    ds = 1e-6 * (1.0 - solid)
    pc_up, _ = ctx.effects.compaction(ctx.case, ctx.p, solid + ds)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        stiff = np.where(np.isfinite(pc) & np.isfinite(pc_up), solid * (pc_up - pc) / ds, np.inf)
    return pc, zeta, zeta + dt * stiff


def _speed_control(ft: FlowTable, a0: Array, t0: Array, pc: Array, zeta: Array, zeta_eff: Array,
                   area: Array, gap: Array) -> _Rates:
    """Speed-controlled spreading (rows of ``ft``), with compaction where it is active;
    ``zeta_eff`` is the effective bulk viscosity of the step (see :func:`_compaction`)."""
    one, zero = np.ones(a0.size), np.zeros(a0.size)
    s0 = ft.solve(a0, one, t0)
    force = s0.force
    # the closing speed comes from the balance a0 F + V = t0, not from the table: with a
    # stiff frame a0 F >> V and the table's interpolation error in F would swamp V
    spread = np.maximum(t0 - a0 * force, 0.0)
    speed = spread.copy()
    balance = force
    comp = force > area * pc
    if np.any(comp):
        visc = zeta_eff > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(visc, gap / (zeta_eff * area), 0.0)
            s1 = ft.solve(a0 + r, one, t0 + np.where(visc, pc * gap / zeta_eff, 0.0))
            v1 = np.maximum(t0 - a0 * s1.force, s1.speed)
            # the force of the present state: without the end-of-step part of P_c
            f1 = s1.force - area * (zeta_eff - zeta) * (v1 - s1.speed) / gap
            f2 = np.where(comp, area * pc, 1.0)
        # a flat compaction law without bulk viscosity: the pressure holds at P_c
        rigid = comp & ~visc
        s2_speed = ft.solve(one, zero, f2).speed if np.any(rigid) else spread
        balance = np.where(comp, np.where(visc, s1.force, f2), force)
        force = np.where(comp, np.where(visc, f1, f2), force)
        spread = np.where(comp, np.where(visc, s1.speed, s2_speed), spread)
        speed = np.where(comp, np.where(visc, v1, t0 - a0 * f2), speed)
    return _Rates(force, speed, spread, None, balance)


def _evaluate(ctx: _Context, st: _State, dt: Array) -> _Rates:
    """Force and speeds of every row at state ``st`` for a closing step ``dt`` (s).

    Rows fall in five groups: spreading under speed control; an incompressible charge
    that has just filled the cavity (its last flow force); a compressible charge packing
    a full cavity under speed control; force control while spreading; force control in a
    full cavity (no closure, or creep through the bulk viscosity).
    """
    c, P = ctx.case, st.t.size
    full = st.area >= c.area_mould * (1.0 - 1e-12)
    fc = st.phase == PHASE_FORCE
    pc, zeta, zeta_eff = _compaction(ctx, st, dt)
    free, beta = ctx.effects.ram_speed(c, ctx.p, st.t, c.set_speed(st.t))
    a0 = ctx.inv_k / dt + free * beta / c.force_limit
    t0 = free + st.delta / dt
    force, speed, spread = np.full(P, c.force_limit), np.zeros(P), np.zeros(P)
    balance = force.copy()
    rows = np.nonzero(~full | (~fc & ~ctx.compressible))[0]
    if rows.size:
        ft = _flow_table(ctx, st, rows)
        sc_rows, fc_rows = ~fc[rows], fc[rows]
        if np.any(sc_rows):
            sc = _speed_control(ft, a0[rows], t0[rows], pc[rows], zeta[rows], zeta_eff[rows],
                                st.area[rows], st.gap[rows])
            idx = rows[sc_rows]
            force[idx], speed[idx], spread[idx] = sc.force[sc_rows], sc.speed[sc_rows], sc.spread[sc_rows]
            balance[idx] = sc.balance[sc_rows]
        if np.any(fc_rows):
            limit = np.full(rows.size, c.force_limit)
            spread[rows[fc_rows]] = ft.solve(np.ones(rows.size), np.zeros(rows.size), limit).speed[fc_rows]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        creep = np.where((zeta > 0) & np.isfinite(pc),
                         np.maximum(c.force_limit / st.area - pc, 0.0) * st.gap / zeta, 0.0)
    speed = np.where(fc, spread + creep, speed)
    packing = full & ~fc & ctx.compressible
    if np.any(packing):
        f_pack, f_balance, v = _packing(ctx, st, pc, zeta, zeta_eff, a0, t0)
        force = np.where(packing, f_pack, force)
        balance = np.where(packing, f_balance, balance)
        speed = np.where(packing, v, speed)
        spread = np.where(packing, 0.0, spread)
    balance = np.where(fc, force, balance)
    return _Rates(force, speed, spread, free * (1.0 - beta * balance / c.force_limit), balance)


def _packing(ctx: _Context, st: _State, pc: Array, zeta: Array, zeta_eff: Array, a0: Array,
             t0: Array) -> tuple[Array, Array, Array]:
    """A full cavity compacting under speed control: F / A = P_c + zeta_eff V / H with
    a0 F + V = t0.  Returns the force of the present state and of the balance (N) and the
    closing speed (m/s), all ``(P,)`` (meaningless in rows that are not packing)."""
    a_m = ctx.case.area_mould
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        v = np.maximum((t0 - a0 * a_m * pc) / (1.0 + a0 * a_m * zeta_eff / st.gap), 0.0)
        v = np.where(np.isfinite(v), v, 0.0)
        moving = v > 0
        balance = np.where(moving, a_m * (pc + zeta_eff * v / st.gap), a_m * pc)
        force = np.where(moving, a_m * (pc + zeta * v / st.gap), a_m * pc)
    return force, balance, v


def _setup(case: Case, p: dict[str, Array], effects: EffectStack, table: MaterialTable,
           options: MarchOptions) -> _Context:
    steps = options.closing_steps
    P = p["n"].shape[0]
    s0 = effects.solid_fraction0(case, p, P)
    solid0 = np.ones(P) if s0 is None else np.minimum(np.asarray(s0, float), 1.0)
    # a row whose charge has no pores (s0 >= 1) runs exactly as the incompressible model
    compressible = solid0 < 1.0
    gap_end = solid0 * case.gap_full
    v_ref = case.speed if case.profile is None else case.profile.pace(case.gap0 - float(np.min(gap_end)))
    dt_close = (case.gap0 - gap_end) / (v_ref * steps)
    inv_k = effects.compliance(case, p, P)
    return _Context(case, PressProgramme.of(case, options.jump_time_s), p, effects, table, solid0,
                    compressible, inv_k, dt_close, gap_end, v_ref, dt_close * steps,
                    1.0 + case.force_limit * inv_k / (case.gap0 - gap_end),
                    getattr(options, "shape_correction", True))


def _closing_step(ctx: _Context, ram: Array, force_rate: Array, ram_rate: Array) -> Array:
    """Speed-controlled step (s), ``(P,)``: the nominal step, stretched up to
    :data:`~smcbayes.forward.programme.MAX_STRETCH` times while the ram, its speed and the force
    all move slowly.

    The nominal step covers 1/steps of the nominal closing; a ram slowing under load or a
    soft frame would otherwise spend thousands of steps creeping to the force limit.  The
    stretch keeps the change per step of the ram position (share of its travel to the
    limit, gap travel + F_limit / k), of the ram speed (share of the set speed) and of the
    force (share of the limit) at or below what the nominal step allows.  Only the ram
    speed U (1 - beta F / F_limit) and the force enter, not the gap speed: with a stiff
    frame the solved gap speed is a small difference of large terms, and a step size
    driven by its round-off would make results depend on it.  Rates are ``(P,)`` absolute
    values over the last step (inf or NaN: none yet).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        stretch = closing_stretch(ram, force_rate, ram_rate, ctx.travel, ctx.t_close, ctx.v_ref,
                                  ctx.press.force_limit)
    return ctx.dt_close * stretch


def _step_size(ctx: _Context, st: _State, speed: Array, hold_steps: int, steps: int,
               closing: Array) -> Array:
    """``closing`` (s) under speed control; under force control the hold schedule of
    :func:`~smcbayes.forward.programme.hold_step`, capped in gap change."""
    if ctx.press.hold <= 0:
        return closing
    with np.errstate(divide="ignore", invalid="ignore"):
        dt_hold = hold_step(st.t, st.switch, speed, ctx.dt_close, ctx.press.hold, float(hold_steps),
                            (ctx.case.gap0 - ctx.gap_end) / steps)
    return np.where(st.phase == PHASE_FORCE, dt_hold, closing)


def _advance(ctx: _Context, st: _State, rates: _Rates, dt: Array, active: NDArray[np.bool_]) -> _State:
    """Euler step of ``dt`` for ``active`` rows, stopping exactly at the cavity fill."""
    c = ctx.case
    new = st.copy()
    dt = np.where(active, dt, 0.0)
    solved_dt = dt
    gap = st.gap - rates.speed * dt
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(rates.speed > 0, rates.spread / rates.speed, 0.0)
        area = st.area * (st.gap / gap) ** ratio
    fills = (area > c.area_mould) & (st.area < c.area_mould) & active
    if np.any(fills):
        with np.errstate(divide="ignore", invalid="ignore"):
            gap_fill = st.gap * (st.area / c.area_mould) ** (1.0 / ratio)
            dt_fill = (st.gap - gap_fill) / rates.speed
        gap = np.where(fills, gap_fill, gap)
        area = np.where(fills, c.area_mould, area)
        dt = np.where(fills, dt_fill, dt)
    area = np.minimum(area, c.area_mould)
    # like the fill, the pore-free state (s = 1) ends a step: solve s0 H0 A0 = H' A (H/H')^r
    dense = ctx.compressible & active & (gap * area < ctx.solid0 * c.gap0 * c.area0) & (ratio < 1.0)
    if np.any(dense):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            gap_s1 = (ctx.solid0 * c.gap0 * c.area0 / (st.area * st.gap**ratio)) ** (1.0 / (1.0 - ratio))
            area_s1 = np.minimum(st.area * (st.gap / gap_s1) ** ratio, c.area_mould)
            dt_s1 = (st.gap - gap_s1) / rates.speed
        gap, area = np.where(dense, gap_s1, gap), np.where(dense, area_s1, area)
        dt = np.where(dense, np.clip(dt_s1, 0.0, dt), dt)
    new.t, new.gap, new.area = st.t + dt, gap, area
    new.delta = np.where(active & (st.phase != PHASE_FORCE),
                         step_deflection(st.delta, rates.balance * ctx.inv_k, dt, solved_dt), st.delta)
    new.extra = ctx.effects.advance(c, ctx.p, st.extra, st.gap, dt)
    if ctx.compressible.any():
        new.phase = np.where(fills & ctx.compressible & (st.phase != PHASE_FORCE), PHASE_FULL,
                             new.phase).astype(np.int8)
    return new


def _switch(ctx: _Context, st: _State, prev: _State, prev_force: Array, rates: _Rates,
            first: bool, done: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Move rows whose force passed the limit back to the crossing; returns those rows
    (never a row that is ``done``: a failed one keeps its state)."""
    press = ctx.press
    hit = ~done & (st.phase != PHASE_FORCE) & press.reaches_limit(rates.force)
    if not np.any(hit):
        return hit
    if not first:
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = press.crossing(prev_force, rates.force)
        back = prev.copy()
        back.blend(st, theta, hit)
        for name in ("t", "gap", "area", "delta"):
            setattr(st, name, np.where(hit, getattr(back, name), getattr(st, name)))
        for k in st.extra:
            st.extra[k] = np.where(hit, back.extra[k], st.extra[k])
    st.phase = np.where(hit, PHASE_FORCE, st.phase).astype(np.int8)
    st.switch = np.where(hit, st.t, st.switch)
    st.delta = np.where(hit, press.force_limit * ctx.inv_k, st.delta)
    return hit


def march(case: Case, p: dict[str, Array], effects: EffectStack, table: MaterialTable,
          options: MarchOptions) -> Nodes:
    """Run the press programme for every parameter set; returns the node histories.

    Args:
        case: configuration in SI.
        p: SI parameters by symbol, each ``(P,)``.
        effects: enabled effects.
        table: stress-grid tables of the batch.
        options: :class:`~smcbayes.forward.squeeze1d.Squeeze1DOptions`.
    """
    steps, hold_steps = options.closing_steps, options.hold_steps
    ctx = _setup(case, p, effects, table, options)
    P = p["n"].shape[0]
    st = _State(np.zeros(P), np.full(P, case.gap0), np.full(P, case.area0), np.zeros(P),
                np.full(P, PHASE_FLOW, dtype=np.int8), np.full(P, np.nan),
                effects.initial_state(case, p, P))
    done, count = np.zeros(P, dtype=bool), np.zeros(P, dtype=np.int64)
    at_rest = np.zeros(P, dtype=bool)
    rec: dict[str, list[Array]] = {k: [] for k in ("t", "gap", "area", "force", "delta", "solid")}
    prev, prev_force, prev_ram = st.copy(), np.zeros(P), np.zeros(P)
    # a soft frame (F_limit / (k U) up to ~6x the nominal closing time) or a ram slowing
    # under load needs a generous budget; rows that finish stop advancing
    closing = ctx.dt_close
    for it in range(12 * (steps + hold_steps) + 20):
        rates = _evaluate(ctx, st, closing)
        if np.any(_switch(ctx, st, prev, prev_force, rates, it == 0, done)):
            rates = _evaluate(ctx, st, closing)
        _record(rec, ctx, st, rates.force)
        count[~done] = it + 1
        jump = _fill_stops(ctx, st, rates.force, done, at_rest)
        done |= (st.phase == PHASE_FORCE) & ctx.press.hold_over(st.t, st.switch) & ~jump
        if case.profile is not None:  # a log over with the ram at rest: it never gets further
            at_rest |= ~done & (st.phase != PHASE_FORCE) & case.profile.ends_at_rest(st.t)
            done |= at_rest
        if done.all():
            break
        dt = _step_size(ctx, st, rates.speed, hold_steps, steps, closing)
        with np.errstate(divide="ignore", invalid="ignore"):
            elapsed = np.where(st.t > prev.t, st.t - prev.t, 0.0)
            force_rate = np.abs(rates.force - prev_force) / elapsed
            ram_rate = np.abs(rates.ram - prev_ram) / elapsed
        prev, prev_force, prev_ram = st.copy(), rates.force, rates.ram
        st = _advance(ctx, st, rates, dt, ~done & ~jump)
        # the next balance is solved for the step it will take, so the step is set here
        # consecutive steps differ by at most STEP_GROWTH: smooth steps, and a step size
        # that cannot feed back on the force it is computed from
        closing = np.clip(_closing_step(ctx, rates.ram, force_rate, ram_rate),
                          closing / STEP_GROWTH, closing * STEP_GROWTH)
    stalled = ("failed: the press programme did not finish within the step limit (press stalled before "
               "the force limit?)")
    status = [f"failed: {AT_REST}" if rest else STATUS_OK if ok else stalled
              for ok, rest in zip(done, at_rest, strict=True)]
    stack = {k: np.stack(v, axis=1) for k, v in rec.items()}
    return Nodes(time=stack["t"], gap=stack["gap"], area=stack["area"], force=stack["force"],
                 deflection=stack["delta"], solid=stack["solid"], count=count,
                 switch=st.switch, status=status)


def _fill_stops(ctx: _Context, st: _State, force: Array, done: NDArray[np.bool_],
                at_rest: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Rows whose incompressible charge has just filled the cavity under speed control: they
    switch to force control once the frame is loaded (:func:`_frame_loading`); a row whose
    measured log ends at rest before that fails (``at_rest`` and ``done`` are updated in
    place).  Returns the rows that switched."""
    c = ctx.case
    jump = ~done & fills_and_stops(~ctx.compressible, st.area, c.area_mould, st.phase == PHASE_FORCE)
    if not np.any(jump):
        return jump
    loading = _frame_loading(ctx, st, force, jump)
    at_rest |= jump & np.isinf(loading)
    done |= at_rest
    jump &= ~at_rest
    st.t = np.where(jump, st.t + loading, st.t)
    st.phase = np.where(jump, PHASE_FORCE, st.phase).astype(np.int8)
    st.switch = np.where(jump, st.t, st.switch)
    return jump


def _frame_loading(ctx: _Context, st: _State, force: Array, rows: NDArray[np.bool_]) -> Array:
    """Time (s) from a fill of the cavity (incompressible charge, at ``force`` N on a rigid
    frame, at the load of its deflection on a compliant one,
    :func:`~smcbayes.forward.programme.frame_load`) to the force limit, ``(P,)``
    (``jump_time`` outside ``rows``): the gap stops, the ram runs on and loads the frame (a
    jump of ``jump_time`` on a rigid one; :func:`~smcbayes.forward.programme.load_travel`),
    at its free speed at the fill, or along the measured profile with the speed ramp's
    factor at the fill held (inf where the log ends at rest before the limit)."""
    c = ctx.case
    force = frame_load(force, st.delta, ctx.inv_k)
    free, beta = ctx.effects.ram_speed(c, ctx.p, st.t, c.set_speed(st.t))
    if c.profile is None:
        with np.errstate(divide="ignore", invalid="ignore"):
            return load_time(force, c.force_limit, ctx.inv_k, np.maximum(free, 1e-6 * c.speed), beta,
                             ctx.press.jump_time)
    factor = ctx.effects.ram_speed(c, ctx.p, st.t, np.ones_like(st.t))[0]  # the ramp's, on the log
    travel = load_travel(force, c.force_limit, ctx.inv_k, beta) / np.maximum(factor, 1e-6)
    out = np.full(st.t.shape, ctx.press.jump_time)
    for r in np.flatnonzero(rows):
        out[r] = max(c.profile.time_after(float(st.t[r]), float(travel[r])) - st.t[r], ctx.press.jump_time)
    return out


def _record(rec: dict[str, list[Array]], ctx: _Context, st: _State, force: Array) -> None:
    rec["t"].append(st.t.copy())
    rec["gap"].append(st.gap.copy())
    rec["area"].append(st.area.copy())
    rec["force"].append(force.copy())
    rec["delta"].append(force * ctx.inv_k)
    rec["solid"].append(ctx.solid(st.gap, st.area))
