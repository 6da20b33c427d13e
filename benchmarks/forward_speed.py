"""Speed of the forward model and its measured convergence orders.

Prints a table and writes ``benchmarks/results/forward_speed.json``.  Each row is a
function ``row(bench) -> list[Row]`` in :data:`ROWS`; add a solver or an effect by
appending a function.  Times are medians of several repeats after a warm-up run.

Targets on a 2-core machine: one (configuration, parameter set) run with >= 200 output
times <= 10 ms; a batch of 256 parameter sets on one configuration <= 0.5 s; with effects,
a compressible run <= 5x the incompressible run and a batch of 256 sets <= 2 s.  The
effect rows run on the compiled marching path (numba); the "NumPy march" rows time the
reference path on the same cases, as the baseline of the speed-up.  A missed target is
printed as MISSED.  Reference: one Moldflow run of the thesis took 20 minutes.

Usage: ``python benchmarks/forward_speed.py [--repeats 5] [--batch 256]``
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import MaterialSpec, load_project
from smcbayes.forward.case import Case
from smcbayes.forward.effects import EffectStack, get_effect
from smcbayes.forward.flux import FlowTable, MaterialTable, log_grid
from smcbayes.forward.march import march
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.nodes import interp_rows
from smcbayes.forward.parameters import to_si
from smcbayes.forward.squeeze1d import Squeeze1D, Squeeze1DOptions, material_table

Array = NDArray[np.float64]
ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
MOLDFLOW_S = 20 * 60.0
EFFECTS = ("compressibility", "heating", "curing", "press_compliance", "speed_ramp")


@dataclass
class Row:
    """One timed case; ``target_s`` None means no target."""

    name: str
    seconds: float
    sets: int
    outputs: int
    target_s: float | None = None
    target: str = ""
    note: str = ""

    @property
    def met(self) -> bool | None:
        return None if self.target_s is None else self.seconds <= self.target_s


@dataclass
class Bench:
    """Shared settings of all rows."""

    config: Path
    config_id: str
    repeats: int
    batch: int
    seed: int = 0
    cache: dict[str, float] = field(default_factory=dict)

    def model(self, effects: tuple[str, ...] = (), fidelity: str | None = None,
              compiled: bool = True) -> ForwardModel:
        model = ForwardModel(load_project(self.config), effects=list(effects), fidelity=fidelity)
        if not compiled:
            model.solver.options = dataclasses.replace(model.solver.options, compiled=False)
        return model

    def thetas(self, model: ForwardModel, rows: int) -> Array:
        """``rows`` parameter vectors drawn uniformly in the search bounds (seeded)."""
        u = np.random.default_rng(self.seed).random((rows, model.space.dim))
        return model.space.from_unit(u)

    def time(self, model: ForwardModel, theta: Array | None, repeats: int | None = None) -> tuple[float, int]:
        """Median wall time (s) of ``model.simulate`` and the number of output times."""
        res = model.simulate(theta, [self.config_id])[self.config_id]  # warm-up
        failed = [s for s in res.status if s != "ok"]
        if failed:
            print(f"  note: {len(failed)} of {res.rows} rows failed: {failed[0]}")
        times = []
        for _ in range(repeats or self.repeats):
            start = time.perf_counter()
            model.simulate(theta, [self.config_id])
            times.append(time.perf_counter() - start)
        return statistics.median(times), res.time_s.shape[1]


def base_single(bench: Bench) -> list[Row]:
    model = bench.model()
    seconds, outputs = bench.time(model, None)
    bench.cache["base_single"] = seconds
    return [Row("1d base: one run", seconds, 1, outputs, 0.010, "<= 10 ms")]


def base_batch(bench: Bench) -> list[Row]:
    model = bench.model()
    seconds, outputs = bench.time(model, bench.thetas(model, bench.batch), max(3, bench.repeats // 2))
    return [Row(f"1d base: batch of {bench.batch}", seconds, bench.batch, outputs, 0.5 * bench.batch / 256,
                f"<= {0.5 * bench.batch / 256:g} s")]


def _effect_rows(bench: Bench, effects: tuple[str, ...], label: str) -> list[Row]:
    model = bench.model(effects)
    single, outputs = bench.time(model, None)
    base = bench.cache.get("base_single")
    ratio = "" if base is None else f"{single / base:.2g}x the base run"
    rows = [Row(f"1d {label}: one run", single, 1, outputs, None, "", ratio)]
    if effects == ("compressibility",) and base is not None:
        rows[0].target_s, rows[0].target = 5 * base, "<= 5x base run"
    batch, outputs = bench.time(model, bench.thetas(model, bench.batch), 1)
    rows.append(Row(f"1d {label}: batch of {bench.batch}", batch, bench.batch, outputs,
                    2.0 * bench.batch / 256, f"<= {2.0 * bench.batch / 256:g} s"))
    return rows


def first_call(bench: Bench) -> list[Row]:
    """First compressible run of the process: numba compiles the kernel or loads it from cache."""
    model = bench.model(("compressibility",))
    start = time.perf_counter()
    model.simulate(None, [bench.config_id])
    return [Row("1d compressibility: first call (kernel compile or cache load)",
                time.perf_counter() - start, 1, 0, None, "", "once per process")]


def numpy_reference(bench: Bench) -> list[Row]:
    """The NumPy marching path on the compiled path's cases: the baseline of its speed-up."""
    rows = []
    for effects, label in ((("compressibility",), "compressibility"), (EFFECTS, "all effects")):
        model = bench.model(effects, compiled=False)
        single, outputs = bench.time(model, None, 3)
        base = bench.cache.get("base_single")
        note = "" if base is None else f"{single / base:.2g}x the base run"
        rows.append(Row(f"1d {label}, NumPy march: one run", single, 1, outputs, None, "", note))
        batch, outputs = bench.time(model, bench.thetas(model, bench.batch), 1)
        rows.append(Row(f"1d {label}, NumPy march: batch of {bench.batch}", batch, bench.batch, outputs))
    return rows


def effect_rows(bench: Bench) -> list[Row]:
    rows: list[Row] = []
    for name in EFFECTS:
        rows += _effect_rows(bench, (name,), name)
    return rows


def all_effects(bench: Bench) -> list[Row]:
    return _effect_rows(bench, EFFECTS, "all effects")


def two_d(bench: Bench) -> list[Row]:
    """The 2-D solver on a thesis centre charge at its default grid (see forward_2d.py)."""
    from forward_2d import speed

    model = ForwardModel(load_project(ROOT / "configs" / "thesis.toml"), fidelity="1d")
    si = to_si(model.space.batch(None), model.space.parameters)
    s = speed(model, si, "60-center-07")
    cells = f"{s['cells_whole_mould'][0]} x {s['cells_whole_mould'][1]} cells"
    note = (f"{cells} ({s['cells_solved'][0]} x {s['cells_solved'][1]} solved); force vs "
            f"twice-refined grid {s['rms_vs_refined_pct']:.2f} % RMS (target <= 2 %)")
    return [Row("2d 60-center-07: one run", s["seconds"], 1, s["nodes"], 10.0, "<= 10 s", note)]


def _interp_searchsorted(x_new: Array, xp: Array, fp: Array) -> Array:
    """Row-wise linear interpolation by one sorted search over all rows (each row mapped
    to its own interval): the NumPy baseline of the compiled walk."""
    P, T = xp.shape
    lo, hi = xp[:, :1], xp[:, -1:]
    span = np.where(hi > lo, hi - lo, 1.0)
    offset = 2.0 * np.arange(P)[:, None]
    q = np.clip((x_new - lo) / span, 0.0, 1.0) + offset
    j = np.searchsorted(((xp - lo) / span + offset).ravel(), q.ravel(), side="right").reshape(q.shape)
    j = np.clip(j - np.arange(P)[:, None] * T, 1, T - 1)
    rows = np.arange(P)[:, None]
    x0, x1 = xp[rows, j - 1], xp[rows, j]
    w = np.where(x1 > x0, (np.clip(x_new, lo, hi) - x0) / np.where(x1 > x0, x1 - x0, 1.0), 1.0)
    return fp[rows, j - 1] + w * (fp[rows, j] - fp[rows, j - 1])


def interpolation(bench: Bench) -> list[Row]:
    """The loss's resampling: a batch's simulated force (250 output times) read on a
    400-point comparison grid at each of the contact-offset profile's 9 offsets and its
    refinement, by the compiled walk and by the sorted-search baseline (the force only;
    the loss also reads the phase and, for the hold, the displacement).  The rows above
    include the compiled resampling of the forward model's output grid."""
    rng = np.random.default_rng(bench.seed)
    nodes = np.cumsum(rng.uniform(0.5, 1.5, (bench.batch, 250)), axis=1)
    force = np.cumsum(rng.random((bench.batch, 250)), axis=1)
    grid = np.linspace(0.0, 1.05, 400)[None, :] * nodes[:, -1:]
    shifts = np.linspace(-0.3, 0.3, 10) / 0.7 * nodes[:, -1:].mean() / 30.0
    queries = [np.minimum(grid - s, nodes[:, -1:]) for s in shifts]
    timed = {}
    for name, fn in (("compiled walk", interp_rows), ("sorted search", _interp_searchsorted)):
        fn(queries[0], nodes, force)  # warm-up (the kernel compiles or loads here)
        times = []
        for _ in range(bench.repeats):
            start = time.perf_counter()
            out = [fn(q, nodes, force) for q in queries]
            times.append(time.perf_counter() - start)
        timed[name] = (statistics.median(times), out)
    diff = max(float(np.max(np.abs(a - b))) for a, b in zip(timed["compiled walk"][1],
                                                             timed["sorted search"][1], strict=True))
    walk, search = timed["compiled walk"][0], timed["sorted search"][0]
    label = f"loss resampling: {bench.batch} rows x 10 offsets x 400 points"
    return [Row(f"{label}, compiled walk", walk, bench.batch, 400, None, "",
                f"{search / walk:.2g}x faster than the sorted search; max difference {diff:.1e}"),
            Row(f"{label}, sorted search", search, bench.batch, 400, None, "", "NumPy baseline")]


ROWS: list[Callable[[Bench], list[Row]]] = [base_single, base_batch, first_call, effect_rows,
                                             all_effects, numpy_reference, interpolation, two_d]


# -- convergence orders --------------------------------------------------------------------
THRESHOLD = {"n": 0.35, "tau_star": 3e4, "B": 2e4, "tau_c": 0.05e6, "m": 1.5}


def _si(rows: int = 1) -> dict[str, Array]:
    return {k: np.full(rows, v) for k, v in THRESHOLD.items()}


def stress_grid_order(case: Case, levels: tuple[int, ...] = (6, 12, 24, 48)) -> dict[str, object]:
    """RMS force error over 25 states of the closing vs stress points per decade (400 ref)."""
    gap = np.linspace(case.gap0, case.gap_full, 25)
    area = case.area0 * case.gap0 / gap
    p = _si(gap.size)
    opts = Squeeze1DOptions()

    def forces(per_decade: int) -> Array:
        tau = log_grid(opts.tau_min_Pa, opts.tau_max_Pa, per_decade)
        table = MaterialTable.build(tau, p["n"], p["tau_star"], np.full(gap.size, 1e-8), p["tau_c"], p["m"])
        flow = FlowTable.build(table.flux(gap, p["B"]), tau, case.planar, case.front(area), gap, case.width)
        return flow.solve(np.zeros(gap.size), np.ones(gap.size), np.full(gap.size, case.speed)).force

    ref = forces(400)
    errors = np.array([np.sqrt(np.mean((forces(k) / ref - 1) ** 2)) for k in levels])
    order = float(-np.polyfit(np.log(levels), np.log(errors), 1)[0])
    return {"levels": list(levels), "errors": errors.tolist(), "order": order, "expected": 2.0}


def _fill_time(time_s: Array, area: Array, count: int, area_mould: float) -> float:
    full = area[:count] >= area_mould * (1 - 1e-12)
    return float(time_s[np.argmax(full)])


def _orders(values: list[float]) -> list[float]:
    d = np.abs(np.diff(values))
    return np.log2(d[:-1] / d[1:]).tolist()


def hold_steps_order(case: Case, levels: tuple[int, ...] = (8, 16, 32, 64, 128)) -> dict[str, object]:
    """Kinematic path: time to fill under force control vs ``hold_steps`` (Richardson)."""
    fill = []
    for k in levels:
        solver = Squeeze1D(Squeeze1DOptions(hold_steps=k))
        nodes = solver._kinematic(case, _si(), material_table(_si(), MaterialSpec(), solver.tau))
        fill.append(_fill_time(nodes.time[0], nodes.area[0], nodes.count[0], case.area_mould))
    return {"levels": list(levels), "fill_time_s": fill, "orders": _orders(fill), "expected": 2.0}


def closing_steps_order(case: Case, levels: tuple[int, ...] = (100, 200, 400, 800)) -> dict[str, object]:
    """Marching path (a rigid press frame forces it): time to fill vs ``closing_steps``."""
    fill = []
    effects = EffectStack([get_effect("press_compliance")])
    for k in levels:
        solver = Squeeze1D(Squeeze1DOptions(closing_steps=k))
        p = {**_si(), "k_press": np.array([1e20])}
        nodes = march(case, p, effects, material_table(p, MaterialSpec(), solver.tau), solver.options)
        fill.append(_fill_time(nodes.time[0], nodes.area[0], nodes.count[0], case.area_mould))
    return {"levels": list(levels), "fill_time_s": fill, "orders": _orders(fill), "expected": 1.0}


def convergence(bench: Bench) -> dict[str, object]:
    case = bench.model().cases[bench.config_id]
    # a force limit low enough that the charge fills under force control
    low = dataclasses.replace(case, force_limit=40e3)
    return {"stress_grid_per_decade": stress_grid_order(case),
            "kinematic_hold_steps": hold_steps_order(low),
            "marching_closing_steps": closing_steps_order(low)}


# -- output ----------------------------------------------------------------------------------
def print_table(rows: list[Row]) -> None:
    width = max(len("case"), *(len(r.name) for r in rows)) + 2
    print(f"{'case':<{width}}{'median':>11}{'per set':>11}{'outputs':>9}  {'target':<18}{'status':<8}"
          f"{'vs Moldflow':>14}  note")
    for r in rows:
        per_set = r.seconds / r.sets
        status = "" if r.met is None else ("met" if r.met else "MISSED")
        print(f"{r.name:<{width}}{r.seconds * 1e3:>9.1f}ms{per_set * 1e3:>9.2f}ms{r.outputs:>9d}  "
              f"{r.target:<18}{status:<8}{MOLDFLOW_S / per_set:>13.3g}x  {r.note}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "thesis.toml")
    parser.add_argument("--id", default="60-bar-03", help="configuration to time")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--batch", type=int, default=256)
    args = parser.parse_args()
    bench = Bench(args.config, args.id, args.repeats, args.batch)
    print(f"forward model speed on '{args.id}' ({os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}); "
          f"Moldflow reference {MOLDFLOW_S / 60:g} min per run")
    rows: list[Row] = []
    for fn in ROWS:
        print(f"  timing {fn.__name__} ...", flush=True)
        rows += fn(bench)
    print()
    print_table(rows)
    conv = convergence(bench)
    print("\nconvergence orders (60 % bar, Cross + slip with threshold: n 0.35, tau* 3e4 Pa, B 2e4 Pa s, "
          "tau_c 0.05 MPa, m 1.5)")
    sg = conv["stress_grid_per_decade"]
    print(f"  force vs stress points per decade {sg['levels']}: RMS errors "
          f"{' '.join(f'{e:.2e}' for e in sg['errors'])}; observed order {sg['order']:.2f} (expected 2)")
    for key, label in (("kinematic_hold_steps", "time to fill vs hold_steps (kinematic path)"),
                       ("marching_closing_steps", "time to fill vs closing_steps (marching path)")):
        c = conv[key]
        print(f"  {label} {c['levels']}: {' '.join(f'{t:.4f}' for t in c['fill_time_s'])} s; "
              f"orders {' '.join(f'{o:.2f}' for o in c['orders'])} (expected {c['expected']:g})")
    missed = [r.name for r in rows if r.met is False]
    print("\nall targets met" if not missed else f"\nMISSED targets: {'; '.join(missed)}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / "forward_speed.json"
    payload = {
        "config": str(args.config.relative_to(ROOT) if args.config.is_relative_to(ROOT) else args.config),
        "config_id": args.id, "repeats": args.repeats, "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0], "python": platform.python_version(),
        "moldflow_s": MOLDFLOW_S,
        "rows": [{**dataclasses.asdict(r), "per_set_s": r.seconds / r.sets, "met": r.met,
                  "speedup_vs_moldflow": MOLDFLOW_S * r.sets / r.seconds} for r in rows],
        "convergence": conv, "missed": missed,
    }
    out.write_text(json.dumps(payload, indent=2), encoding="utf-8")
    print(f"written {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
