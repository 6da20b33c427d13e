"""The loss between simulated and measured curves (thesis eq. 3.5-3.7), batched.

For configuration k and parameter row p, force is compared over the closing window:

* ``clip="none"``: [0, max(t_switch_sim, t_end_meas)]; the simulated force up to its
  switch to force control, then held at its end value; the measured curve (which ends at
  the limit) held at its last value;
* ``clip="flow_stop"`` (the thesis's clipped loss): [0, t_flow_stop], the time at which the
  ram reaches the incompressible flow-stop gap h_flow = A_cov/A_mould h_init (eq. 4.1) at
  the set speed;
* ``clip="force_limit"``: like ``none`` but both curves cut where they first reach the
  force limit and capped at it (removes the controller's overshoot from the comparison).

Both curves are linearly interpolated onto ``grid_points`` uniform points of the window.
The hold displacement is compared over [0, max(hold_end_sim, hold_end_meas)] relative to
the hold start (closing negative; the measurement is taken as 0 at the hold start).

e_k^F = mean squared force error (kN^2), e_k^D = mean squared displacement error (mm^2),
L = (1/p) sum_k (w_F e_k^F + w_D e_k^D).  A row whose simulation failed gives NaN.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.config.specs import LossSpec
from smcbayes.data.curve import Curve
from smcbayes.data.dataset import Dataset, Measurement
from smcbayes.data.preprocess import crossing_time
from smcbayes.errors import DataError
from smcbayes.forward.nodes import interp_rows
from smcbayes.forward.result import PHASE_FORCE, SimulationResult

Array = NDArray[np.float64]

__all__ = ["LossSpec", "LossResult", "evaluate_loss", "ForcePair", "force_pair", "best_offsets_mm",
           "contact_offsets_mm", "contact_beyond_bound", "end_state_offsets_mm", "trial_offsets_mm",
           "mixed_force_pair", "given_force_pair", "interp_rows"]


@dataclass(frozen=True)
class LossResult:
    """Loss of ``P`` simulated parameter rows against a dataset.

    Attributes:
        ids: configurations, the order of the columns ``K``.
        total: global loss L, shape ``(P,)``; NaN where a simulation failed.
        force_mse_kN2: e_k^F, shape ``(P, K)``.
        displacement_mse_mm2: e_k^D, shape ``(P, K)``; NaN without a measured hold.
        ok: rows whose simulations all succeeded, shape ``(P,)``.
        w_force, w_displacement: the weights used.
    """

    ids: list[str]
    total: Array
    force_mse_kN2: Array
    displacement_mse_mm2: Array
    ok: NDArray[np.bool_]
    w_force: float = 1.0
    w_displacement: float = 0.0

    def per_config(self) -> dict[str, Array]:
        """Configuration id -> weighted error w_F e^F + w_D e^D, shape ``(P,)``."""
        out = {}
        for k, cid in enumerate(self.ids):
            e = self.w_force * self.force_mse_kN2[:, k]
            if self.w_displacement > 0:
                e = e + self.w_displacement * self.displacement_mse_mm2[:, k]
            out[cid] = e
        return out


def _safe(res: SimulationResult) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
    """Time, force, displacement with failed rows replaced by a dummy ramp (later NaN)."""
    ok = res.ok & np.all(np.isfinite(res.time_s), axis=1) & np.all(np.isfinite(res.force_kN), axis=1)
    t = np.where(ok[:, None], res.time_s, np.arange(res.time_s.shape[1])[None, :])
    f = np.where(ok[:, None], res.force_kN, 0.0)
    d = np.where(ok[:, None], res.displacement_mm, 0.0)
    return t, f, np.nan_to_num(d), ok


def _switch(res: SimulationResult, t: Array, ok: NDArray[np.bool_]) -> Array:
    """Switch time per row (s); the end of the simulation where it is unknown (NaN).

    A switch at t = 0 (a charge too stiff to move: the limit at first contact) is a switch:
    taken as 'never reached', it would compare the whole hold at the limit against the
    measured curve held at its limit and score such a row as a near-perfect fit."""
    ts = res.switch_time_s
    return np.where(ok & np.isfinite(ts), ts, t[:, -1])


@dataclass(frozen=True)
class ForcePair:
    """Simulated and measured force of one configuration on the common grid.

    Attributes:
        time_s: grid, shape ``(P, N)``.
        sim_kN, meas_kN: forces on the grid, shape ``(P, N)``.
        phase: the simulation's phase code at each grid time, shape ``(P, N)``.
        ok: rows with a usable simulation, shape ``(P,)``.
        offset_mm: each row's contact offset (mm; the simulated closing delayed by offset /
            set speed), shape ``(P,)``: zeros unless the loss profiles it or it was given;
            the mean of the offsets a curve was averaged over (:func:`mixed_force_pair`).
    """

    time_s: Array
    sim_kN: Array
    meas_kN: Array
    phase: NDArray[np.int8]
    ok: NDArray[np.bool_]
    offset_mm: Array


OFFSET_STEPS = 9
"""Contact offsets tried per row when the loss profiles them (evenly over
+-``contact_offset_mm``); the best is refined by the parabola through it and its neighbours."""


def force_pair(res: SimulationResult, m: Measurement, spec: LossSpec,
               offset_mm: Array | float | None = None) -> ForcePair:
    """Resample simulated and measured closing force onto the comparison window's grid.

    Args:
        offset_mm: contact offset (mm) of every row, or one per row ``(P,)``: a charge that
            much thicker than nominal meets the ram earlier, and since the data's clock
            starts at first contact the simulated closing comes offset / set speed later
            (to first order).  None: the offset ``spec.contact_mode`` gives the trial
            (:func:`trial_offsets_mm`).
    """
    if m.force is None:
        raise DataError(f"configuration '{m.config_id}' has no measured force curve; "
                        "leave it out of the loss or add data.force")
    if offset_mm is None:
        offset_mm = trial_offsets_mm(res, m, spec)
    offsets = np.broadcast_to(np.asarray(offset_mm, dtype=float), (res.rows,)).copy()
    grid, t, sim, meas, ts, ok = _compare(res, m, m.force, spec, offsets)
    return ForcePair(grid, sim, meas, _phase_on(res, grid, t, ts), ok, offsets)


def _phase_on(res: SimulationResult, grid: Array, t: Array, ts: Array) -> NDArray[np.int8]:
    """The simulation's phase code ``(P, N)`` at each grid time of its (delayed) times ``t``
    ``(P, T)``; force control beyond the (delayed) switch ``ts`` ``(P,)``."""
    idx = np.clip((interp_rows(grid, t, np.broadcast_to(np.arange(t.shape[1], dtype=float), t.shape))
                   + 1e-9).astype(int), 0, t.shape[1] - 1)
    phase = np.take_along_axis(res.phase.astype(np.int8), idx, axis=1)
    return np.where(grid > ts[:, None], np.int8(PHASE_FORCE), phase).astype(np.int8)


def mixed_force_pair(res: SimulationResult, m: Measurement, spec: LossSpec,
                     offsets_mm: Sequence[float]) -> ForcePair:
    """The comparison of a trial whose contact is unknown (held out, or not yet pressed):
    the mean of the simulated force over the contact offsets ``offsets_mm`` (mm, ``(S,)``:
    the training trials' own), each equally likely, against the measured force.

    The offset is a nuisance that varies from trial to trial (the charge's stack height);
    with the training trials' offsets as its sample, this mean is the curve's expectation
    over it, the best point forecast under squared error (Gneiting 2011, "Making and
    evaluating point forecasts", J. Am. Stat. Assoc. 106:746-762), where the curve at the
    mean offset keeps one timing of a near-vertical end of closing.  Every offset is
    compared on the grid of the latest one, so the window holds each delayed switch.
    ``offset_mm`` of the result is the mean offset; its phase is the curve's there.  One
    offset gives :func:`force_pair` at it; none, the nominal contact.
    """
    offs = np.asarray(offsets_mm, dtype=float).ravel()
    if not np.all(np.isfinite(offs)):
        raise DataError(f"configuration '{m.config_id}': contact offsets must be finite, "
                        f"got {offs.tolist()}")
    if offs.size == 0 or np.ptp(offs) == 0 or m.force is None:  # force_pair says what is missing
        return force_pair(res, m, spec, float(offs[0]) if offs.size else 0.0)
    t0, f, _, ok = _safe(res)
    ts0 = _switch(res, t0, ok)
    delays = _delay_s(m, offs)
    latest = np.full(res.rows, float(np.max(delays)))
    grid, meas = _window(m.force, m, spec, ts0 + _window_delay(m, spec, latest))
    sim = np.mean([_sim_on_grid(grid, t0 + d, f, ts0 + d, m, spec) for d in delays], axis=0)
    mid = float(np.mean(delays))
    phase = _phase_on(res, grid, t0 + mid, ts0 + mid)
    return ForcePair(grid, sim, meas, phase, ok, np.full(res.rows, float(np.mean(offs))))


def given_force_pair(res: SimulationResult, m: Measurement, spec: LossSpec,
                     given: float | Sequence[float] | None) -> ForcePair:
    """:func:`force_pair` at one given offset (mm, a number: every row at it),
    :func:`mixed_force_pair` over a sequence of offsets (the curve averaged over them, not
    one offset per row: pass those to :func:`force_pair`), or at the trial's own
    (``None``)."""
    if given is None or np.ndim(given) == 0:
        return force_pair(res, m, spec, offset_mm=given)
    return mixed_force_pair(res, m, spec, given)


def _delay_s(m: Measurement, offsets_mm: Array) -> Array:
    """The delay (s) of the simulated closing for each contact offset (mm)."""
    if not np.any(offsets_mm):
        return np.zeros_like(offsets_mm)
    if not m.speed_mm_s:
        raise DataError(f"configuration '{m.config_id}': a contact offset needs the set closing speed")
    return offsets_mm / m.speed_mm_s


def _window_delay(m: Measurement, spec: LossSpec, delay: Array) -> Array:
    """The delay (s) the comparison window is sized for: where the loss profiles contact
    offsets, the largest one for every offset, so that every candidate offset of a row is
    compared on the same grid (beyond both curves' ends the errors are those of the held
    values, and a window growing with the offset would thin the mean)."""
    if spec.contact_mode == "profile" and m.speed_mm_s:
        return np.maximum(delay, spec.contact_offset_mm / m.speed_mm_s)
    return delay


def _window(force: Curve, m: Measurement, spec: LossSpec, ts: Array) -> tuple[Array, Array]:
    """The comparison grid ``(P, N)`` for switch times ``ts`` ``(P,)`` (the simulated switch,
    delayed as :func:`_window_delay` says) and the measured ``force`` on it."""
    tm, fm = force.time_s, force.values
    if spec.clip == "force_limit":
        t_lim = crossing_time(force, m.force_limit_kN)
        if t_lim is not None:
            tm, fm = np.append(tm[tm < t_lim], t_lim), np.append(fm[tm < t_lim], m.force_limit_kN)
    if spec.clip == "flow_stop":
        if m.flow_stop_s is None:
            raise DataError(f"configuration '{m.config_id}': no flow-stop time; use clip='none'")
        end = np.full(ts.shape, m.flow_stop_s)
    else:
        end = np.maximum(ts, tm[-1])
    grid = end[:, None] * np.linspace(0.0, 1.0, spec.grid_points)[None, :]
    return grid, np.interp(grid, tm, fm)


def _sim_on_grid(grid: Array, t: Array, f: Array, ts: Array, m: Measurement, spec: LossSpec) -> Array:
    """The simulated force on the grid, held at its switch value beyond the switch."""
    sim = interp_rows(np.minimum(grid, ts[:, None]), t, f)
    return np.minimum(sim, m.force_limit_kN) if spec.clip == "force_limit" else sim


def _compare(res: SimulationResult, m: Measurement, force: Curve, spec: LossSpec,
             offsets_mm: Array) -> tuple[Array, Array, Array, Array, Array, NDArray[np.bool_]]:
    """The comparison of every row at its contact offset ``(P,)``: grid, the delayed
    simulated times ``(P, T)``, simulated and measured force on the grid, delayed switch
    times and the usable rows."""
    t0, f, _, ok = _safe(res)
    delay = _delay_s(m, offsets_mm)
    ts0 = _switch(res, t0, ok)
    grid, meas = _window(force, m, spec, ts0 + _window_delay(m, spec, delay))
    t, ts = t0 + delay[:, None], ts0 + delay
    return grid, t, _sim_on_grid(grid, t, f, ts, m, spec), meas, ts, ok


def _mse_at(res: SimulationResult, m: Measurement, spec: LossSpec, offsets_mm: Array) -> Array:
    """Force MSE (kN^2) of every row at its contact offset ``(P,)``; inf where a run failed."""
    if m.force is None:
        raise DataError(f"configuration '{m.config_id}' has no measured force curve")
    _, _, sim, meas, _, ok = _compare(res, m, m.force, spec, offsets_mm)
    return np.where(ok, np.mean((sim - meas) ** 2, axis=1), np.inf)


def best_offsets_mm(res: SimulationResult, m: Measurement, spec: LossSpec) -> Array:
    """Each row's contact offset (mm) within +-``spec.contact_offset_mm`` of least force MSE,
    shape ``(P,)``: the profile of a per-trial nuisance parameter (Murphy & van der Vaart
    2000, "On profile likelihood", J. Am. Stat. Assoc. 95:449-465).

    :data:`OFFSET_STEPS` offsets on an even grid, then the vertex of the parabola through the
    best and its two neighbours where that fits better (the offset then moves with the
    parameters rather than in grid steps, though it can still jump by up to half a step
    where the parabola fits worse than the grid point); 0 for a failed row.  Every offset
    of a row is compared on one window (:func:`_window_delay`); with ``clip = "flow_stop"``
    the window keeps the nominal flow-stop time.
    """
    width = spec.contact_offset_mm
    cand = np.linspace(-width, width, OFFSET_STEPS)
    err = np.stack([_mse_at(res, m, spec, np.full(res.rows, c)) for c in cand], axis=1)  # (P, S)
    j = np.argmin(err, axis=1)
    rows = np.arange(res.rows)
    inner = (j > 0) & (j < OFFSET_STEPS - 1) & np.all(np.isfinite(err), axis=1)
    jl, jr = np.clip(j - 1, 0, OFFSET_STEPS - 1), np.clip(j + 1, 0, OFFSET_STEPS - 1)
    e0, el, er = err[rows, j], err[rows, jl], err[rows, jr]
    curv = np.where(inner, er - 2 * e0 + el, 1.0)
    h = cand[1] - cand[0] if OFFSET_STEPS > 1 else 0.0
    vertex = cand[j] - np.where(inner & (curv > 0), 0.5 * h * (er - el) / np.where(curv > 0, curv, 1.0), 0.0)
    vertex = np.clip(vertex, cand[jl], cand[jr])
    refined = _mse_at(res, m, spec, vertex)
    best = np.where(refined <= e0, vertex, cand[j])
    return np.where(np.isfinite(e0), best, 0.0)


def end_state_offsets_mm(res: SimulationResult, m: Measurement, bound_mm: float = 0.0) -> Array:
    """Each row's contact offset (mm) from the trial's measured end state, shape ``(P,)``.

    The measurement gives H_meas = h_end + v t_end (:func:`smcbayes.data.dataset.
    end_stack_height_mm`): the gap where the force reached the limit plus the set speed
    times the time it took.  The simulation gives the same sum at its own switch,
    h_sim + v t_sim: its stack height plus the frame's deflection there (the ram runs at
    the set speed, the gap closes slower by F / k), and less any stretch in which the ram
    could not keep the speed (a locked incompressible charge), which the measurement holds
    alike if the model is right.  The offset H_meas - (h_sim + v t_sim) is how much higher
    the charge stood than the simulated one: measured, not fitted, it cannot absorb a
    model that ends the closing at the wrong gap.  Delayed by offset / v, the simulated
    closing ends at t_end + (h_end - h_sim) / v: exactly at the measured end when it ends
    at the measured gap.  With ``bound_mm`` above 0 the offset is clipped to +- it (no
    charge stands further from its nominal height; ``[loss] contact_offset_mm``).  0 for a
    failed row (or one whose gap is not finite).
    """
    if m.end_stack_mm is None:
        why = next((s.removeprefix("no end state: ") for s in m.steps if s.startswith("no end state: ")),
                   "it has no measured part (part.thickness_mm, or part.mass_g with part.density_g_cm3)")
        raise DataError(f"configuration '{m.config_id}': [loss] contact = \"end_state\" cannot place its "
                        f"contact: {why}; give the trial its end state, leave it out of the loss or "
                        "choose another [loss] contact")
    if not m.speed_mm_s:
        raise DataError(f"configuration '{m.config_id}': a contact from the end state "
                        "needs the set closing speed")
    t, _, _, ok = _safe(res)
    ts = _switch(res, t, ok)
    gap = np.where(ok[:, None], res.gap_mm, 0.0)
    end = interp_rows(ts[:, None], t, gap)[:, 0] + m.speed_mm_s * ts
    offset = np.where(ok & np.isfinite(end), m.end_stack_mm - end, 0.0)
    return np.clip(offset, -bound_mm, bound_mm) if bound_mm > 0 else offset


def trial_offsets_mm(res: SimulationResult, m: Measurement, spec: LossSpec) -> Array:
    """Each row's contact offset (mm) as ``spec.contact_mode`` says, shape ``(P,)``: measured
    from the end state (within +- ``spec.contact_offset_mm`` when above 0), profiled, or 0
    at the nominal stack height."""
    if spec.contact_mode == "end_state":
        return end_state_offsets_mm(res, m, spec.contact_offset_mm)
    if spec.contact_mode == "profile":
        return best_offsets_mm(res, m, spec)
    return np.zeros(res.rows)


def contact_offsets_mm(results: Mapping[str, SimulationResult], dataset: Dataset, spec: LossSpec,
                       ids: Sequence[str], row: int = 0) -> dict[str, float]:
    """Each configuration's contact offset (mm) at row ``row`` (:func:`trial_offsets_mm`):
    those of ``ids`` with a measured force, a usable run and, for ``contact =
    "end_state"``, a measured end state; empty at the nominal contact."""
    if not spec.per_trial_contact:
        return {}
    out = {}
    for cid in ids:
        m = dataset.measurements.get(cid)
        if m is None or m.force is None or cid not in results or not bool(np.asarray(results[cid].ok)[row]):
            continue
        if spec.contact_mode == "end_state" and m.end_stack_mm is None:
            continue
        out[cid] = float(trial_offsets_mm(results[cid], m, spec)[row])
    return out


def contact_beyond_bound(results: Mapping[str, SimulationResult], dataset: Dataset, spec: LossSpec,
                         ids: Sequence[str], row: int = 0) -> dict[str, float]:
    """Of ``ids``, the trials whose end state puts their contact beyond +-
    ``spec.contact_offset_mm`` at row ``row``, with their unbounded offsets (mm); empty
    unless ``contact = "end_state"`` has a bound."""
    if spec.contact_mode != "end_state" or spec.contact_offset_mm <= 0:
        return {}
    raw = contact_offsets_mm(results, dataset, spec.model_copy(update={"contact_offset_mm": 0.0}), ids, row)
    return {c: v for c, v in raw.items() if abs(v) > spec.contact_offset_mm}


def displacement_mse(res: SimulationResult, m: Measurement, spec: LossSpec) -> Array:
    """e^D (mm^2) of the hold displacement, shape ``(P,)``; NaN without a measured hold."""
    if m.hold is None:
        return np.full(res.rows, np.nan)
    t, _, d, ok = _safe(res)
    ts = _switch(res, t, ok)
    d_switch = interp_rows(ts[:, None], t, d)
    hold_end = t[:, -1] - ts
    end = np.maximum(hold_end, m.hold.end_s)
    tau = end[:, None] * np.linspace(0.0, 1.0, spec.grid_points)[None, :]
    sim = -(interp_rows(ts[:, None] + np.minimum(tau, hold_end[:, None]), t, d) - d_switch)
    th, dh = m.hold.time_s, m.hold.values
    if th[0] > 0:  # by definition the hold displacement is 0 where the hold begins
        th, dh = np.concatenate(([0.0], th)), np.concatenate(([0.0], dh))
    meas = np.interp(tau, th, dh)
    out = np.mean((sim - meas) ** 2, axis=1)
    return np.where(ok, out, np.nan)


def evaluate_loss(results: Mapping[str, SimulationResult], dataset: Dataset,
                  spec: LossSpec = LossSpec(), ids: Sequence[str] | None = None,
                  offsets_mm: Mapping[str, float | Sequence[float]] | None = None) -> LossResult:
    """Loss of a batch of simulations against the measured data.

    Args:
        results: configuration id -> simulation of ``P`` parameter rows (all the same P).
        dataset: the measured data.
        spec: weights, grid size and clipping.
        ids: configurations to compare (default: the dataset's training configurations).
        offsets_mm: contact offsets (mm) of configurations compared at a given one, or
            averaged over given ones (a trial outside the loss over the training trials'
            own, :func:`mixed_force_pair`); the others take the one ``spec.contact_mode``
            gives them.

    Returns:
        Per-configuration MSEs ``(P, K)`` and the global loss ``(P,)``.

    Raises:
        DataError: a configuration lacks a measurement or a simulation result.
    """
    ids = dataset.ids("train") if ids is None else list(ids)
    if not ids:
        raise DataError("no configurations to compare: the dataset has no training measurements")
    missing = [cid for cid in ids if cid not in results]
    if missing:
        raise DataError(f"no simulation result for configuration(s) {', '.join(missing)}; "
                        "simulate every configuration of the loss")
    rows = {results[cid].rows for cid in ids}
    if len(rows) != 1:
        raise DataError(f"simulation results have different batch sizes {sorted(rows)}")
    P, K = rows.pop(), len(ids)
    ef, ed = np.empty((P, K)), np.empty((P, K))
    ok = np.ones(P, dtype=bool)
    for k, cid in enumerate(ids):
        m = dataset[cid]
        pair = given_force_pair(results[cid], m, spec, (offsets_mm or {}).get(cid))
        ef[:, k] = np.where(pair.ok, np.mean((pair.sim_kN - pair.meas_kN) ** 2, axis=1), np.nan)
        if spec.w_displacement > 0 and m.hold is None:
            raise DataError(f"configuration '{cid}': w_displacement > 0 but no measured hold "
                            "displacement; add data.hold or set w_displacement = 0")
        ed[:, k] = displacement_mse(results[cid], m, spec)
        ok &= pair.ok
    per = spec.w_force * ef + (spec.w_displacement * ed if spec.w_displacement > 0 else 0.0)
    total = np.where(ok, np.mean(per, axis=1), np.nan)
    return LossResult(ids, total, ef, ed, ok, spec.w_force, spec.w_displacement)
