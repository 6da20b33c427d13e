"""2-D thin-cavity solver: convergence, the 1-D equal-area error, the square-charge
correction and run time.  Prints its figures and writes benchmarks/results/forward_2d.json.

Run:  python benchmarks/forward_2d.py [--quick] [--compressible-only]

1. Convergence: Newtonian square charge at first contact against F = 0.42173 mu V L^4/H^3
   (grid order); full-width bar against the exact 1-D planar solver over the closing (grid
   order); force impulse over 80 % of the closing of a centre charge (time-step order).
2. For the thesis's centre charges (60 % and 80 %, three speeds, parameters of
   configs/thesis.toml) the RMS force difference of the 1-D equal-area disc against the
   2-D solver over the closing (contact to cavity full or force limit), in kN and in % of
   the RMS 2-D force; the ratio F_2D / F_1D against the fill fraction, the correction
   table fitted to it (geometric mean over the six runs, and leave-one-out), and the error
   after :func:`smcbayes.forward.layout.square_charge_factor`.
3. Speed: one thesis configuration at the default grid, wall time, grid size and the RMS
   force difference to a twice-refined grid.
4. Compressible charge (local solid fraction per cell, compressibility effect at its
   default parameters): wall time of the same configuration; grid convergence at four times
   the default steps and time-step convergence on 24 cells (RMS force difference of
   successive runs over the closing, force impulse over the flow, final gap, with the
   measured orders); solid mass conservation over the whole run; the per-cell path at s0 = 1 against the
   incompressible run; the high-fluidity (uniform-pressure) limit of a bar against the
   lumped compaction of the 1-D march; the solid fraction at the centre and at the front,
   and its field at the fill snapshots (benchmarks/results/forward_2d_solid_fraction.png).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from smcbayes.config import MaterialSpec, ProjectConfig, load_project
from smcbayes.forward.case import Case
from smcbayes.forward.compaction2d import CellCompaction
from smcbayes.forward.hele_shaw2d import (
    FillHistory,
    HeleShaw2D,
    HeleShaw2DOptions,
    cell_compaction,
    make_grid,
)
from smcbayes.forward.layout import square_charge_factor
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.parameters import to_si
from smcbayes.forward.squeeze1d import material_table
from smcbayes.forward.stepper2d import Run
from smcbayes.plotting import pyplot, save

ROOT = Path(__file__).resolve().parents[1]
CENTRE = ["60-center-03", "60-center-07", "60-center-11", "80-center-03", "80-center-07", "80-center-11"]
COVERAGES = (0.6, 0.8)
PROGRESS = np.concatenate([np.linspace(0.0, 0.9, 46), 1.0 - np.logspace(-1.0, -3.0, 21)[1:]])
"""Filling progress u = (fill - fill0) / (1 - fill0) of the correction table."""
NEWTONIAN = {"n": 0.5, "tau_star": 1e30, "B": 1e4, "tau_c": 1e30, "m": 1.0}


def _run(case: Case, si: dict, cells: int, steps: int = 100, courant: float = 0.5,
         compaction: CellCompaction | None = None) -> Run:
    solver = HeleShaw2D(HeleShaw2DOptions(cells=cells, closing_steps=steps, courant=courant))
    table = material_table(si, MaterialSpec(), solver.tau)
    return solver.run_row(case, table, float(si["B"][0]), 0, compaction)


def _order(values: list[float]) -> list[float]:
    """Observed orders from successive differences of a halving sequence."""
    v = np.asarray(values)
    d = np.abs(np.diff(v))
    return [float(np.log2(d[i] / d[i + 1])) for i in range(d.size - 1)]


def convergence(model: ForwardModel, si: dict, quick: bool) -> dict:
    """Grid and time-step orders."""
    L, H, V = 0.1, 8e-3, 1e-3
    sq = Case(id="square", planar=False, width=0.2, mould_length=0.2, area0=L * L, area_mould=0.04,
              gap0=H, mass=None, T_mould=400.0, T_charge=400.0, speed=V, force_limit=1e12,
              hold=1.0, pieces=((0.0, 0.0, L, L),))
    newt = {k: np.array([v]) for k, v in NEWTONIAN.items()}
    exact = 0.42173 * NEWTONIAN["B"] * V * L**4 / H**3
    cells = [16, 32, 64, 128]
    first = [_run(sq, newt, c, steps=5).force[0] for c in cells]
    out = {"square_first_instant": {"cells": cells, "relative_error": [f / exact - 1 for f in first],
                                    "order": _order(first)}}
    bar = model.cases["60-bar-07"]
    r1 = model.simulate(None, ["60-bar-07"])["60-bar-07"]
    t_full = (bar.gap0 - bar.gap_full) / bar.speed
    t = np.linspace(0.0, 0.99 * t_full, 400)
    f1 = np.interp(t, r1.time_s[0], r1.force_kN[0])
    bar_cells = [12, 24, 48] if quick else [12, 24, 48, 96]
    errs = []
    for c in bar_cells:
        run = _run(bar, si, c)
        f2 = np.interp(t, run.t, np.array(run.force) / 1e3)
        errs.append(float(np.sqrt(np.mean((f2 - f1) ** 2)) / np.sqrt(np.mean(f1**2))))
    out["bar_vs_1d"] = {"cells": bar_cells, "rms_relative": errs,
                        "order": [float(np.log2(errs[i] / errs[i + 1])) for i in range(len(errs) - 1)]}
    centre = model.cases["60-center-07"]
    t_full = (centre.gap0 - centre.gap_full) / centre.speed
    steps = [20, 40, 80, 160] if quick else [20, 40, 80, 160, 320]
    impulse = []
    for n in steps:
        run = _run(centre, si, 16, steps=n, courant=100.0)
        tt, ff = np.array(run.t), np.array(run.force)
        k = int(np.argmin(np.abs(tt - 0.8 * t_full)))
        impulse.append(float(np.trapezoid(ff[: k + 1], tt[: k + 1])))
    out["time_step"] = {"cells": 16, "closing_steps": steps, "impulse_Ns": impulse, "order": _order(impulse)}
    return out


def _closing_curves(model: ForwardModel, cid: str, run: Run) -> tuple[np.ndarray, ...]:
    """Times, fill fraction, 1-D and 2-D force (kN) over the common closing window."""
    case = model.cases[cid]
    r1 = model.simulate(None, [cid])[cid]
    jump = 0.05  # both solvers take this long to reach the limit once the cavity is full
    t_end = min(r1.switch_time_s[0], run.switch, (case.gap0 - case.gap_full) / case.speed + jump) - jump
    # stop two output samples short of the switch: the resampled 1-D curve ramps to the
    # limit between the last closing sample and the switch
    t_end -= 2.0 * r1.switch_time_s[0] / (r1.time_s.shape[1] - model.project.solver.output_hold_points)
    t = np.linspace(0.0, t_end, 400)
    f1 = np.interp(t, r1.time_s[0], r1.force_kN[0])
    f2 = np.interp(t, run.t, np.array(run.force) / 1e3)
    fill = np.interp(t, r1.time_s[0], r1.fill_fraction[0])
    return t, fill, f1, f2


def _rms(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    kn = float(np.sqrt(np.mean((a - b) ** 2)))
    return kn, 100.0 * kn / float(np.sqrt(np.mean(b**2)))


def one_d_error(model: ForwardModel, si: dict, cells: int) -> dict:
    """1-D equal-area error and the square-charge correction on the thesis centre charges.

    The ratio F_2D / F_1D is taken against the filling progress u = (fill - fill0) /
    (1 - fill0); the correction table is its geometric mean over the three speeds of each
    coverage, and its leave-one-out check uses the two other speeds only.
    """
    rows, ratios, curves = {}, {}, {}
    for cid in CENTRE:
        case = model.cases[cid]
        run = _run(case, si, cells)
        t, fill, f1, f2 = curves[cid] = _closing_curves(model, cid, run)
        fill0 = case.area0 / case.area_mould
        kn, pct = _rms(f1, f2)
        kn_c, pct_c = _rms(f1 * square_charge_factor(fill, fill0), f2)
        rows[cid] = {"rms_kN": kn, "rms_pct": pct, "corrected_rms_kN": kn_c, "corrected_rms_pct": pct_c,
                     "window_s": float(t[-1])}
        u = (fill - fill0) / (1.0 - fill0)
        ratios[cid] = np.interp(-np.log10(1.0 - PROGRESS), -np.log10(np.maximum(1.0 - u, 1e-12)), f2 / f1)
    groups = {c: [k for k in CENTRE if k.startswith(f"{round(100 * c)}-")] for c in COVERAGES}
    table = np.array([_geomean([ratios[k] for k in groups[c]]) for c in COVERAGES])
    loo = {}
    for cid in CENTRE:
        c = next(c for c in COVERAGES if cid in groups[c])
        fit = _geomean([ratios[k] for k in groups[c] if k != cid])
        _, fill, f1, f2 = curves[cid]
        u = (fill - c) / (1.0 - c)
        factor = np.interp(-np.log10(np.maximum(1.0 - u, 1e-12)), -np.log10(1.0 - PROGRESS), fit)
        loo[cid] = _rms(f1 * factor, f2)[1]
    return {"configurations": rows, "progress": PROGRESS.tolist(), "coverages": list(COVERAGES),
            "fitted_ratio": table.tolist(), "leave_one_out_rms_pct": loo}


def _geomean(rows: list[np.ndarray]) -> np.ndarray:
    return np.exp(np.mean(np.log(np.array(rows)), axis=0))


def speed(model: ForwardModel, si: dict, cid: str) -> dict:
    """Wall time at the default grid and the force change on a twice-refined grid."""
    cells = model.project.solver.cells_2d
    case = model.cases[cid]
    grid, _ = make_grid(case, cells, True)
    start = time.perf_counter()
    coarse = _run(case, si, cells, steps=model.project.solver.closing_steps_2d)
    seconds = time.perf_counter() - start
    fine = _run(case, si, 2 * cells, steps=model.project.solver.closing_steps_2d)
    t_end = min(coarse.switch, fine.switch) - 0.05
    t = np.linspace(0.0, t_end, 400)
    fc = np.interp(t, coarse.t, np.array(coarse.force) / 1e3)
    ff = np.interp(t, fine.t, np.array(fine.force) / 1e3)
    kn, pct = _rms(fc, ff)
    return {"configuration": cid, "cells_whole_mould": [2 * grid.nx, 2 * grid.ny],
            "cells_solved": [grid.nx, grid.ny], "seconds": seconds, "rms_vs_refined_kN": kn,
            "rms_vs_refined_pct": pct, "nodes": len(coarse.t)}


def compressible(project: ProjectConfig, cid: str, quick: bool) -> dict:
    """Per-cell compaction: speed, grid convergence, conservation and the limits."""
    model = ForwardModel(project, effects=["compressibility"], fidelity="1d")
    si = to_si(model.space.batch(None), model.space.parameters)
    case = model.cases[cid]
    comp = cell_compaction(case, si, model.effects, 0)
    steps = project.solver.closing_steps_2d
    start = time.perf_counter()
    run = _run(case, si, project.solver.cells_2d, steps=steps, compaction=comp)
    seconds = time.perf_counter() - start
    solid = np.array(run.solid_volume)
    out: dict = {"configuration": cid, "solid0": comp.solid0, "seconds": seconds, "nodes": len(run.t),
                 "solid_mass_max_relative_error": float(np.max(np.abs(solid / solid[0] - 1.0))),
                 "final_solid_fraction": run.solid[-1]}
    # four times the default steps, so that the grid error stands above the time-step error
    out["grid"] = _grid_study(case, si, comp, 4 * steps, [12, 24, 48] if quick else [12, 24, 48, 96])
    out["time_step"] = _time_study(case, si, comp, 24, [50, 100, 200] if quick else [50, 100, 200, 400])
    base = _run(case, si, project.solver.cells_2d, steps=steps)
    one = _run(case, si, project.solver.cells_2d, steps=steps, compaction=CellCompaction(1.0, comp.law))
    out["s0_one_vs_incompressible_max_relative_force"] = (float(
        np.max(np.abs(np.array(one.force) / np.array(base.force) - 1.0)))
        if len(one.t) == len(base.t) else None)
    out["uniform_limit"] = _uniform_limit(project)
    out["direction"] = _direction(project, cid)
    return out


def _grid_study(case: Case, si: dict, comp: CellCompaction, steps: int, cells: list[int]) -> dict:
    """Compressible grid convergence at ``steps`` closing steps (see :func:`_study`)."""
    runs = [_run(case, si, c, steps=steps, compaction=comp) for c in cells]
    return {"cells": cells, "closing_steps": steps, **_study(case, runs)}


def _time_study(case: Case, si: dict, comp: CellCompaction, cells: int, steps: list[int]) -> dict:
    """Compressible time-step convergence on ``cells`` cells (see :func:`_study`); the
    Courant limit is lifted so that the step count alone sets the step."""
    runs = [_run(case, si, cells, steps=n, courant=100.0, compaction=comp) for n in steps]
    return {"cells": cells, "closing_steps": steps, **_study(case, runs)}


def _study(case: Case, runs: list[Run]) -> dict:
    """RMS force difference of successive runs over the closing (contact to the switch),
    force impulse over the flow (to 80 % of the incompressible filling time) and the
    final gap, with the observed orders."""
    t = np.linspace(0.0, 0.98 * min(r.switch for r in runs), 600)
    forces = [np.interp(t, r.t, np.array(r.force) / 1e3) for r in runs]
    rms = [float(np.sqrt(np.mean((forces[i] - forces[i + 1]) ** 2))) for i in range(len(runs) - 1)]
    t_flow = 0.8 * (case.gap0 - case.gap_full) / case.speed
    k = t <= t_flow
    impulse = [float(np.trapezoid(f[k], t[k])) for f in forces]
    return {"rms_successive_kN": rms,
            "rms_order": [float(np.log2(rms[i] / rms[i + 1])) for i in range(len(rms) - 1)],
            "rms_successive_pct": [100.0 * r / float(np.sqrt(np.mean(forces[-1] ** 2))) for r in rms],
            "flow_impulse_kNs": impulse, "flow_impulse_order": _order(impulse), "flow_window_s": t_flow,
            "final_gap_mm": [1e3 * r.gap[-1] for r in runs],
            "final_gap_order": _order([r.gap[-1] for r in runs]),
            "switch_s": [r.switch for r in runs]}


def _uniform_limit(project: ProjectConfig) -> dict:
    """Bar at high fluidity (B = 10 and 100 Pa s, also at four times the steps) and at the
    default: per-cell 2-D against the lumped compaction of the 1-D march over the closing."""
    out = {}
    fine = project.model_copy(update={"solver": project.solver.model_copy(
        update={"closing_steps_2d": 4 * project.solver.closing_steps_2d})})
    for label, over, proj in (("B_10_Pa_s", {"B_Pa_s": 10.0}, project),
                              ("B_10_Pa_s_4x_steps", {"B_Pa_s": 10.0}, fine),
                              ("B_100_Pa_s", {"B_Pa_s": 100.0}, project), ("default", {}, project)):
        r1 = ForwardModel(proj, effects=["compressibility"],
                          fidelity="1d", overrides=over).simulate(None, ["60-bar-07"])
        r2 = ForwardModel(proj, effects=["compressibility"],
                          fidelity="2d", overrides=over).simulate(None, ["60-bar-07"])
        a, b = r1["60-bar-07"], r2["60-bar-07"]
        t = np.linspace(0.0, a.switch_time_s[0], 400)
        f1, f2 = (np.interp(t, r.time_s[0], r.force_kN[0]) for r in (a, b))
        s1, s2 = (np.interp(t, r.time_s[0], r.solid_fraction[0]) for r in (a, b))
        out[label] = {"rms_force_pct": _rms(f2, f1)[1],
                      "max_solid_fraction_difference": float(np.max(np.abs(s2 - s1))),
                      "switch_relative": float(b.switch_time_s[0] / a.switch_time_s[0] - 1.0),
                      "final_solid_fraction_1d": float(a.solid_fraction[0, -1]),
                      "final_solid_fraction_2d": float(b.solid_fraction[0, -1])}
    return out


def _direction(project: ProjectConfig, cid: str) -> dict:
    """Solid fraction at the centre cell and over the front cells at mid-filling."""
    model = ForwardModel(project, effects=["compressibility"], fidelity="2d")
    res = model.simulate(None, [cid])[cid]
    h = model.solver.fields[cid][0]
    k = len(h.time_s) // 2
    solid, fill = h.solid[k], h.fill[k]
    front = solid[(fill > 0.0) & (fill < 1.0 - 1e-9)]
    nx, ny = solid.shape
    _solid_figure(h, ROOT / "benchmarks" / "results" / "forward_2d_solid_fraction")
    return {"time_s": float(h.time_s[k]), "solid0": float(res.solid_fraction[0, 0]),
            "centre": float(solid[nx // 2, ny // 2]), "max": float(np.nanmax(solid)),
            "front_min": float(front.min()), "front_max": float(front.max())}


def _solid_figure(h: FillHistory, path: Path) -> None:
    """Solid fraction per cell at the fill snapshots (empty cells blank), one panel each."""
    plt = pyplot()
    count = len(h.time_s)
    fig, axes = plt.subplots(1, count, figsize=(3.2 * count, 3.4), squeeze=False)
    lo, hi = float(np.nanmin(h.solid)), float(np.nanmax(h.solid))
    for k, ax in enumerate(axes[0]):
        mesh = ax.pcolormesh(h.x_faces_mm, h.y_faces_mm, h.solid[k].T, vmin=lo, vmax=hi, cmap="viridis")
        ax.set_aspect("equal")
        ax.set_title(f"t = {h.time_s[k]:.2f} s", fontsize=9)
        ax.set_xlabel("x (mm)")
        if k == 0:
            ax.set_ylabel("y (mm)")
    fig.subplots_adjust(wspace=0.45)
    fig.colorbar(mesh, ax=axes[0].tolist(), label="solid fraction s (-)", shrink=0.8)
    save(fig, path)


def _print_compressible(c: dict) -> None:
    print(f"2-D compressible, {c['configuration']} (s0 = {c['solid0']:.3f}): {c['seconds']:.2f} s, "
          f"{c['nodes']} steps, "
          f"solid mass max relative error {c['solid_mass_max_relative_error']:.1e}, "
          f"final s {c['final_solid_fraction']:.4f}")
    for name, g in (("grid", c["grid"]), ("time step", c["time_step"])):
        print(f"  {name}: cells {g['cells']}, closing steps {g['closing_steps']}; "
              "RMS force between successive "
              "runs over the closing",
              [f"{v:.3f} kN ({p:.2f} %)"
               for v, p in zip(g["rms_successive_kN"], g["rms_successive_pct"], strict=True)],
              "order", [f"{o:.2f}" for o in g["rms_order"]])
        print(f"    flow impulse to {g['flow_window_s']:.2f} s (kN s)",
              [f"{v:.4f}" for v in g["flow_impulse_kNs"]],
              "order", [f"{o:.2f}" for o in g["flow_impulse_order"]])
        print("    final gap (mm)", [f"{v:.4f}" for v in g["final_gap_mm"]], "order",
              [f"{o:.2f}" for o in g["final_gap_order"]], "; switch (s)", [f"{v:.4f}" for v in g["switch_s"]])
    print(f"  s0 = 1 on the per-cell path vs incompressible: max relative force difference "
          f"{c['s0_one_vs_incompressible_max_relative_force']:.1e}")
    for label, u in c["uniform_limit"].items():
        print(f"  bar 60-bar-07 per-cell vs lumped 1-D ({label}): "
              f"RMS force {u['rms_force_pct']:.2f} %, switch "
              f"{u['switch_relative']:+.1e}, max |ds| {u['max_solid_fraction_difference']:.1e}, final s "
              f"{u['final_solid_fraction_2d']:.4f} vs {u['final_solid_fraction_1d']:.4f}")
    d = c["direction"]
    print(f"  solid fraction at t = {d['time_s']:.2f} s: "
          f"centre {d['centre']:.4f} (max {d['max']:.4f}), front "
          f"{d['front_min']:.4f}-{d['front_max']:.4f}, s0 {d['solid0']:.4f}")


def incompressible(project: ProjectConfig, quick: bool) -> dict:
    """Sections 1-3 (base model), printed as they come."""
    model = ForwardModel(project, fidelity="1d")
    si = to_si(model.space.batch(None), model.space.parameters)
    results = {"speed": speed(model, si, "60-center-07")}
    s = results["speed"]
    print(f"2-D speed, {s['configuration']}: {s['seconds']:.2f} s at {s['cells_whole_mould'][0]} x "
          f"{s['cells_whole_mould'][1]} cells ({s['cells_solved'][0]} x {s['cells_solved'][1]} solved, "
          f"{s['nodes']} steps); RMS force vs twice-refined grid {s['rms_vs_refined_kN']:.3f} kN "
          f"({s['rms_vs_refined_pct']:.2f} %)")
    results["convergence"] = conv = convergence(model, si, quick)
    print("Newtonian square, first instant: cells", conv["square_first_instant"]["cells"],
          "error", [f"{e:+.2e}" for e in conv["square_first_instant"]["relative_error"]],
          "order", [f"{o:.2f}" for o in conv["square_first_instant"]["order"]])
    print("Bar vs exact 1-D over the closing: cells", conv["bar_vs_1d"]["cells"], "RMS",
          [f"{100 * e:.3f} %" for e in conv["bar_vs_1d"]["rms_relative"]],
          "order", [f"{o:.2f}" for o in conv["bar_vs_1d"]["order"]])
    print("Time step (impulse over 80 % of the closing, 16 cells): steps", conv["time_step"]["closing_steps"],
          "order", [f"{o:.2f}" for o in conv["time_step"]["order"]])
    # the plain equal-area disc: the correction is what this section measures
    plain = project.model_copy(update={"solver": project.solver.model_copy(
        update={"shape_correction": False})})
    results["one_d_error"] = err = one_d_error(ForwardModel(plain, fidelity="1d"),
                                               si, project.solver.cells_2d)
    print(f"{'configuration':<16}{'1-D RMS (kN)':>14}{'(%)':>9}{'corrected (kN)':>16}{'(%)':>9}"
          f"{'leave-one-out (%)':>19}")
    for cid, row in err["configurations"].items():
        print(f"{cid:<16}{row['rms_kN']:>14.2f}{row['rms_pct']:>9.1f}{row['corrected_rms_kN']:>16.2f}"
              f"{row['corrected_rms_pct']:>9.1f}{err['leave_one_out_rms_pct'][cid]:>19.1f}")
    print("fitted F_2D/F_1D table: progress u =", np.array2string(np.array(err["progress"]), precision=5,
                                                                separator=", ", max_line_width=100))
    for c, row in zip(err["coverages"], err["fitted_ratio"], strict=False):
        print(f"  coverage {c:.2f}:", np.array2string(np.array(row), precision=4, separator=", ",
                                                     max_line_width=100))
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer grids in the convergence study")
    parser.add_argument("--compressible-only", action="store_true",
                        help="run section 4 only (the other sections' results in the JSON are kept)")
    args = parser.parse_args()
    project = load_project(ROOT / "configs" / "thesis.toml")
    solver = project.solver.model_copy(update={"output_closing_points": 4000})
    project = project.model_copy(update={"solver": solver})
    out = ROOT / "benchmarks" / "results" / "forward_2d.json"
    results = {}
    if args.compressible_only and out.exists():
        results = json.loads(out.read_text(encoding="utf-8"))
    if not args.compressible_only:
        results.update(incompressible(project, args.quick))
    results["compressible"] = comp = compressible(project, "60-center-07", args.quick)
    _print_compressible(comp)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2), encoding="utf-8")
    print(f"written {out}")


if __name__ == "__main__":
    main()
