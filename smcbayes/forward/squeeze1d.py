"""Fast 1-D squeeze-flow solver (``squeeze1d``), batched over parameter sets.

Planar flow of a full-width bar (exact) or axisymmetric flow of the equal-area disc of a
centre charge, with the generalised Hele-Shaw flux law of :mod:`smcbayes.forward.flux`.
The press closes at the set speed until the force reaches the limit, then holds the force
(force control) for the hold time.  An incompressible charge that fills the cavity stops
the press: the force goes to the limit (in ``jump_time_s``), as in the thesis's Moldflow
runs.  Every path takes these decisions from :mod:`smcbayes.forward.programme`.

Two paths share node placement and resampling, so they agree to round-off where both
apply:

* the *kinematic* path (base model, constant set speed): under speed control gap and
  charge size are known in closed form, so the whole closing is one batched table solve
  of shape ``(P x N, M)``; under force control t(H) = t_switch + integral dH / V(H) is a
  quadrature in the gap;
* the *marching* path (:mod:`smcbayes.forward.march`) steps in time and carries the state
  of effects (compaction, temperature, cure, frame deflection, ram speed); for the
  built-in effects at a constant set speed it runs compiled
  (:mod:`smcbayes.forward.march_compiled`, same results), otherwise in NumPy, which
  :class:`~smcbayes.forward.model.ForwardModel` reports with a
  :class:`~smcbayes.errors.SlowPathWarning` unless ``compiled=False`` asked for it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import MaterialSpec
from smcbayes.forward import march_compiled
from smcbayes.forward.case import Case, shape_factor
from smcbayes.forward.effects.base import EffectStack
from smcbayes.forward.flux import FlowTable, MaterialTable, log_grid
from smcbayes.forward.march import march
from smcbayes.forward.nodes import Nodes, to_result
from smcbayes.forward.programme import PressProgramme
from smcbayes.forward.result import STATUS_OK, SimulationResult

__all__ = ["Squeeze1D", "Squeeze1DOptions", "material_table", "shape_factor"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Squeeze1DOptions:
    """Discretisation of the 1-D solver.

    Attributes:
        closing_steps: nodes over the speed-controlled closing (to the fill gap, or to the
            fully consolidated gap of a compressible charge).
        hold_steps: nodes over the force-controlled phase.
        per_decade: stress-grid points per decade of wall stress.
        tau_min_Pa, tau_max_Pa: stress-grid range.
        output_closing_points, output_hold_points: samples per output curve.
        jump_time_s: time for the force to reach the limit once an incompressible charge
            fills the cavity, on a rigid frame (a compliant one takes the ram's time to load
            it, :func:`~smcbayes.forward.programme.load_time`).
        shape_correction: multiply the axisymmetric force of a centred square charge in a
            square mould by :func:`~smcbayes.forward.layout.square_charge_factor`.
        chunk_rows: parameter sets per batched table solve (cache-sized blocks).
        compiled: run the marching path compiled (numba) when the enabled effects allow
            it (:mod:`smcbayes.forward.march_compiled`); same results, ~30x faster for a
            single parameter set.
    """

    closing_steps: int = 300
    hold_steps: int = 60
    per_decade: int = 12
    tau_min_Pa: float = 1e-2
    tau_max_Pa: float = 1e9
    output_closing_points: int = 200
    output_hold_points: int = 50
    jump_time_s: float = 0.05
    shape_correction: bool = True
    chunk_rows: int = 12
    compiled: bool = True


def material_table(p: dict[str, Array], material: MaterialSpec, tau: Array) -> MaterialTable:
    """Stress-grid tables for an SI parameter batch (symbols n, tau_star, tau_c, m)."""
    rows = p["n"].shape[0]
    return MaterialTable.build(tau, p["n"], p["tau_star"], np.full(rows, material.slip_coefficient),
                               p["tau_c"], p["m"], material.slip_threshold_exponent)


class Squeeze1D:
    """The 1-D solver plug-in: ``solve(case, params, effects, material) -> result``."""

    name: ClassVar[str] = "1d"

    def __init__(self, options: Squeeze1DOptions | None = None) -> None:
        self.options = options or Squeeze1DOptions()
        o = self.options
        self.tau = log_grid(o.tau_min_Pa, o.tau_max_Pa, o.per_decade)
        self.last_path = ""
        """Path of the last :meth:`solve`: ``kinematic``, ``compiled`` or ``numpy``."""

    def path(self, case: Case, effects: EffectStack) -> str:
        """Path :meth:`solve` takes: ``kinematic`` (base model at a constant set speed),
        ``compiled`` (marching in the numba kernel) or ``numpy`` (NumPy marching)."""
        if not effects.effects and case.profile is None:
            return "kinematic"
        if self.options.compiled and march_compiled.supports(effects, case):
            return "compiled"
        return "numpy"

    def slow_path(self, case: Case, effects: EffectStack) -> list[str]:
        """What sends ``case`` to the NumPy marching path although compiled runs were
        asked for (empty: nothing, or ``compiled=False``)."""
        if self.path(case, effects) != "numpy" or not self.options.compiled:
            return []
        return march_compiled.unsupported(effects, case)

    def solve(self, case: Case, p: dict[str, Array], effects: EffectStack,
              material: MaterialSpec) -> SimulationResult:
        """Simulate one configuration for a batch of parameter sets.

        Args:
            case: the configuration in SI.
            p: SI parameters by symbol, each ``(P,)`` (base and effect parameters).
            effects: the enabled effects (empty for the base model).
            material: fixed material constants (slip coefficient and threshold exponent).
        """
        table = material_table(p, material, self.tau)
        self.last_path = self.path(case, effects)
        if self.last_path == "compiled":
            nodes = march_compiled.march_compiled(case, p, effects, table, self.options)
        elif self.last_path == "numpy":
            nodes = march(case, p, effects, table, self.options)
        else:
            nodes = self._kinematic(case, p, table)
        o = self.options
        return to_result(case, nodes, o.output_closing_points, o.output_hold_points,
                         tuple(effects.names))

    def flow_table(self, case: Case, table: MaterialTable, eta0: Array, gap: Array,
                   area: Array) -> FlowTable:
        """Flow tables for ``P x N`` states; ``gap`` and ``area`` have shape ``(P, N)``."""
        q = table.flux(gap, eta0)
        rows = gap.size
        ft = FlowTable.build(q.reshape(rows, -1), self.tau, case.planar,
                             case.front(area).reshape(rows), gap.reshape(rows), case.width)
        factor = shape_factor(case, area.reshape(rows)) if self.options.shape_correction else None
        return ft if factor is None else ft.scaled(factor)

    def _solve_chunked(self, case: Case, table: MaterialTable, eta0: Array, gap: Array,
                       area: Array, by_force: bool) -> Array:
        """Force at the set speed (or speed at the force limit) for ``(P, N)`` states.

        Rows are processed in blocks of ``chunk_rows`` parameter sets so that the
        ``(rows x N, M)`` tables stay cache-sized.
        """
        P, N = gap.shape
        out = np.empty((P, N))
        step = max(1, self.options.chunk_rows)
        for lo in range(0, P, step):
            sl = slice(lo, min(lo + step, P))
            idx = np.arange(sl.start, sl.stop)
            ft = self.flow_table(case, table.take(idx), eta0[sl], gap[sl], area[sl])
            n = ft.q.shape[0]
            if by_force:
                sol = ft.solve(np.ones(n), np.zeros(n), np.full(n, case.force_limit)).speed
            else:
                sol = ft.solve(np.zeros(n), np.ones(n), np.full(n, case.speed)).force
            out[sl] = sol.reshape(-1, N)
        return out

    def _kinematic(self, case: Case, p: dict[str, Array], table: MaterialTable) -> Nodes:
        o = self.options
        press = PressProgramme.of(case, o.jump_time_s)
        P, N = p["n"].shape[0], o.closing_steps
        V, H0, H_end = press.speed, case.gap0, case.gap_full
        dt = (H0 - H_end) / (V * N)
        t = np.arange(N + 1) * dt
        H = np.broadcast_to(H0 - V * t, (P, N + 1)).copy()
        H[:, -1] = H_end
        A = case.area0 * H0 / H
        eta0 = p["B"]
        F = self._solve_chunked(case, table, eta0, H, A, by_force=False)
        over = press.reaches_limit(F)
        hit = over.any(axis=1)
        first = np.argmax(over, axis=1)
        prev = np.maximum(first - 1, 0)
        rows = np.arange(P)
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = press.crossing(F[rows, prev], F[rows, first])
        theta = np.where(first == 0, 0.0, theta)
        # a charge that fills the cavity before the limit stops the press there
        t_sw = np.where(hit, t[prev] + theta * dt * (first > 0), t[-1] + press.jump_time)
        fc = self._force_controlled(case, table, eta0, np.where(hit, H0 - V * t_sw, H_end))
        return self._assemble(case, press, t, H, A, F, hit, first, t_sw, fc)

    def _force_controlled(self, case: Case, table: MaterialTable, eta0: Array,
                          gap_switch: Array) -> tuple[Array, Array]:
        """Gap and time after the switch, flowing at the force limit until the cavity fills.

        Returns:
            ``(gap, elapsed)``, each ``(P, K)``: gaps from ``gap_switch`` down to the fill
            gap and the time since the switch (trapezoid rule on dt/dH = -1/V(H)).
        """
        K = max(self.options.hold_steps, 8)
        P = gap_switch.shape[0]
        u = np.linspace(0.0, 1.0, K)
        H = gap_switch[:, None] + u[None, :] * (case.gap_full - gap_switch[:, None])
        A = case.area0 * case.gap0 / H
        inv_v = 1.0 / self._solve_chunked(case, table, eta0, H, A, by_force=True)
        dH = -np.diff(H, axis=1)
        elapsed = np.concatenate([np.zeros((P, 1)),
                                  np.cumsum(0.5 * (inv_v[:, 1:] + inv_v[:, :-1]) * dH, axis=1)], axis=1)
        return H, elapsed

    def _assemble(self, case: Case, press: PressProgramme, t: Array, H: Array, A: Array, F: Array,
                  hit: NDArray[np.bool_],
                  first: NDArray[np.int64], t_sw: Array, fc: tuple[Array, Array]) -> Nodes:
        """Concatenate speed-control nodes, the switch, force-control nodes and the hold end."""
        P, N1 = H.shape
        H_fc, el = fc
        K = H_fc.shape[1]
        S = N1 + K + 2
        out = {k: np.zeros((P, S)) for k in ("t", "H", "A", "F")}
        count = np.zeros(P, dtype=np.int64)
        F_lim, t_end = press.force_limit, t_sw + press.hold
        area_of = case.area0 * case.gap0
        for r in range(P):
            n_sc = first[r] if hit[r] else N1
            parts_t = [t[:n_sc], [t_sw[r]]]
            parts_H = [H[r, :n_sc], [H_fc[r, 0]]]
            parts_F = [F[r, :n_sc], [F_lim]]
            if hit[r]:
                tt = t_sw[r] + el[r, 1:]
                keep = tt < t_end[r]
                parts_t.append(tt[keep])
                parts_H.append(H_fc[r, 1:][keep])
                parts_F.append(np.full(keep.sum(), F_lim))
                last_H = np.interp(t_end[r], t_sw[r] + el[r], H_fc[r]) if not keep.all() else H_fc[r, -1]
            else:
                last_H = H[r, -1]
            parts_t.append([max(t_end[r], parts_t[-1][-1] if len(parts_t[-1]) else t_sw[r])])
            parts_H.append([last_H])
            parts_F.append([F_lim])
            tr, Hr, Fr = (np.concatenate([np.asarray(x, float) for x in parts])
                          for parts in (parts_t, parts_H, parts_F))
            n = tr.size
            count[r] = n
            for key, val in (("t", tr), ("H", Hr), ("F", Fr)):
                out[key][r, :n] = val
                out[key][r, n:] = val[-1]
            out["A"][r] = np.minimum(area_of / np.maximum(out["H"][r], 1e-300), case.area_mould)
        status = [STATUS_OK] * P
        zeros = np.zeros((P, S))
        return Nodes(time=out["t"], gap=out["H"], area=out["A"], force=out["F"], deflection=zeros,
                     solid=np.ones((P, S)), count=count, switch=t_sw, status=status)
