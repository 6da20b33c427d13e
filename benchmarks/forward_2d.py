"""2-D thin-cavity solver: convergence, the 1-D equal-area error, the square-charge
correction and run time.  Prints its figures and writes benchmarks/results/forward_2d.json.

Run:  python benchmarks/forward_2d.py [--quick]

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
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from smcbayes.config import MaterialSpec, load_project
from smcbayes.forward.case import Case
from smcbayes.forward.hele_shaw2d import HeleShaw2D, HeleShaw2DOptions, make_grid
from smcbayes.forward.layout import square_charge_factor
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.parameters import to_si
from smcbayes.forward.squeeze1d import material_table

ROOT = Path(__file__).resolve().parents[1]
CENTRE = ["60-center-03", "60-center-07", "60-center-11", "80-center-03", "80-center-07", "80-center-11"]
COVERAGES = (0.6, 0.8)
PROGRESS = np.concatenate([np.linspace(0.0, 0.9, 46), 1.0 - np.logspace(-1.0, -3.0, 21)[1:]])
"""Filling progress u = (fill - fill0) / (1 - fill0) of the correction table."""
NEWTONIAN = {"n": 0.5, "tau_star": 1e30, "B": 1e4, "tau_c": 1e30, "m": 1.0}


def _run(case: Case, si: dict, cells: int, steps: int = 100, courant: float = 0.5):
    solver = HeleShaw2D(HeleShaw2DOptions(cells=cells, closing_steps=steps, courant=courant))
    table = material_table(si, MaterialSpec(), solver.tau)
    return solver.run_row(case, table, float(si["B"][0]), 0)


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


def _closing_curves(model: ForwardModel, cid: str, run) -> tuple[np.ndarray, ...]:
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer grids in the convergence study")
    args = parser.parse_args()
    project = load_project(ROOT / "configs" / "thesis.toml")
    solver = project.solver.model_copy(update={"output_closing_points": 4000})
    project = project.model_copy(update={"solver": solver})
    model = ForwardModel(project, fidelity="1d")
    si = to_si(model.space.batch(None), model.space.parameters)
    results = {"speed": speed(model, si, "60-center-07")}
    s = results["speed"]
    print(f"2-D speed, {s['configuration']}: {s['seconds']:.2f} s at {s['cells_whole_mould'][0]} x "
          f"{s['cells_whole_mould'][1]} cells ({s['cells_solved'][0]} x {s['cells_solved'][1]} solved, "
          f"{s['nodes']} steps); RMS force vs twice-refined grid {s['rms_vs_refined_kN']:.3f} kN "
          f"({s['rms_vs_refined_pct']:.2f} %)")
    results["convergence"] = conv = convergence(model, si, args.quick)
    print("Newtonian square, first instant: cells", conv["square_first_instant"]["cells"],
          "error", [f"{e:+.2e}" for e in conv["square_first_instant"]["relative_error"]],
          "order", [f"{o:.2f}" for o in conv["square_first_instant"]["order"]])
    print("Bar vs exact 1-D over the closing: cells", conv["bar_vs_1d"]["cells"], "RMS",
          [f"{100 * e:.3f} %" for e in conv["bar_vs_1d"]["rms_relative"]],
          "order", [f"{o:.2f}" for o in conv["bar_vs_1d"]["order"]])
    print("Time step (impulse over 80 % of the closing, 16 cells): steps", conv["time_step"]["closing_steps"],
          "order", [f"{o:.2f}" for o in conv["time_step"]["order"]])
    results["one_d_error"] = err = one_d_error(model, si, project.solver.cells_2d)
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
    out = ROOT / "benchmarks" / "results" / "forward_2d.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2), encoding="utf-8")
    print(f"written {out}")


if __name__ == "__main__":
    main()
