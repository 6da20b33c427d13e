"""2-D solver on a compliant press frame (``press_compliance``): convergence, agreement with
the 1-D solver, cost and robustness.  Prints its figures and writes
benchmarks/results/forward_2d_frame.json.

Run:  python benchmarks/forward_2d_frame.py [--draws 4] [--seed 1]

1. Convergence: a Newtonian full-width bar on a soft frame (50 kN/mm, so the gap lags the
   ram by up to 3.4 mm) against the exact squeeze solution, an ODE solved at tight
   tolerance: F = 8 mu V W a^3 / H^3 with a H = vol / (2 W) (planar squeeze flow) and
   F = k (H - X), X = H0 - U t the ram's gap.  Fill time and RMS force error (over
   0.5 s to 90 % of the fill time) at 30-240 steps on 24 and 48 cells, with the orders.
2. Against the 1-D solver, full-width bars: the frame with the speed ramp (a stiff paste,
   100 kN/mm), and with compressibility up to the force limit (300 kN/mm): RMS force
   difference over the speed-controlled closing and the switch times.
3. Cost and robustness on the thesis project (configs/thesis.toml, centre charges, solid
   density 1.5 g/cm3): prior draws of compressibility + press_compliance, each run with
   and without the frame at the same values of the other parameters: failures and wall
   time per run.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from smcbayes.config import MaterialSpec, ProjectConfig, build_project, load_project
from smcbayes.forward.hele_shaw2d import charge_effects
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.parameters import to_si
from smcbayes.forward.references import newtonian_bar_on_frame
from smcbayes.forward.result import SimulationResult
from smcbayes.forward.squeeze1d import material_table

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "thesis-press"
MU, K_SOFT = 1.0e4, 50.0
NEWTONIAN = {"n": 0.5, "tau_star_Pa": 1e12, "B_Pa_s": MU, "tau_c_MPa": 1e12, "m": 1.0}
SHEAR = {"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 2e4, "tau_c_MPa": 1.0}
STIFF = {"n": 0.6, "tau_star_Pa": 1e4, "B_Pa_s": 1e5, "tau_c_MPa": 10.0}


def _bar(steps: int, cells: int, mass_g: float | None = None, speed_mm_s: float = 0.3) -> ProjectConfig:
    """A 60 % full-width bar (configuration ``c``) on ``cells`` cells and ``steps`` steps."""
    charge: dict[str, object] = {"shape": "bar", "coverage_pct": 60.0, "stack_height_mm": 8.0}
    if mass_g is not None:
        charge["mass_g"] = mass_g
    press = {"speed_mm_s": speed_mm_s, "hold_s": 20.0}
    raw = {"solver": {"cells_2d": cells, "closing_steps_2d": steps},
           "configuration": [{"id": "c", "charge": charge, "press": press}]}
    return build_project(raw, "bar.toml", Path("."))


def _run(model: ForwardModel, values: dict[str, float]) -> tuple[SimulationResult, float]:
    """Configuration ``c`` at the defaults overridden by ``values`` (user units), and its wall time (s)."""
    theta = {**model.space.defaults(), **values}
    batch = {k: np.array([v]) for k, v in theta.items() if k in model.space.names}
    t0 = time.perf_counter()
    res = model.simulate_params(batch)["c"]
    return res, time.perf_counter() - t0


def _orders(errors: list[float]) -> list[float]:
    """Observed orders between successive halvings of the step."""
    return [float(np.log2(a / b)) for a, b in zip(errors[:-1], errors[1:], strict=True)]


def convergence() -> dict:
    """Section 1: fill time and force errors against the exact squeeze, and their orders."""
    out = {}
    for cells in (24, 48):
        rows = []
        for steps in (30, 60, 120, 240):
            model = ForwardModel(_bar(steps, cells), effects=["press_compliance"], fidelity="2d")
            case = model.cases["c"]
            t_fill, exact = newtonian_bar_on_frame(case, K_SOFT * 1e6, MU)
            values = {**model.space.defaults(), **NEWTONIAN, "k_press_kN_mm": K_SOFT}
            si = to_si({k: np.array([v]) for k, v in values.items()}, model.space.parameters)
            table = material_table(si, MaterialSpec(), model.solver.tau)
            t0 = time.perf_counter()
            run = model.solver.run_row(case, table, MU, 0, None, charge_effects(case, si, model.effects, 0))
            wall = time.perf_counter() - t0
            k_fill = int(np.argmax(np.array(run.gap) <= case.gap_full * (1.0 + 1e-9)))
            fill = run.t[k_fill]
            t = np.linspace(0.5, 0.9 * t_fill, 200)
            f = np.interp(t, run.t, run.force) / 1e3
            rms = float(np.sqrt(np.mean((f - exact(t)) ** 2) / np.mean(exact(t) ** 2)))
            rows.append({"steps": steps, "fill_error_pct": 100 * (fill / t_fill - 1.0),
                         "force_rms_pct": 100 * rms, "seconds": wall})
            print(f"soft frame, {cells} cells, {steps:4d} steps: fill {rows[-1]['fill_error_pct']:+.3f} % "
                  f"(exact {t_fill:.3f} s), force {100 * rms:.3f} % RMS, {wall:.1f} s", flush=True)
        out[str(cells)] = {"rows": rows,
                           "fill_order": _orders([abs(r["fill_error_pct"]) for r in rows]),
                           "force_order": _orders([r["force_rms_pct"] for r in rows])}
        print(f"  orders: fill {np.round(out[str(cells)]['fill_order'], 2)}, "
              f"force {np.round(out[str(cells)]['force_order'], 2)}")
    return out


def _versus_1d(project: ProjectConfig, effects: list[str], values: dict[str, float],
               rigid: list[str]) -> dict:
    """RMS force difference of the 2-D bar against the 1-D one with ``effects``, and how far
    the frame moves the force (against the 2-D run with ``rigid``)."""
    r1, _ = _run(ForwardModel(project, effects=effects, fidelity="1d"), values)
    r2, wall = _run(ForwardModel(project, effects=effects, fidelity="2d"), values)
    r0, wall0 = _run(ForwardModel(project, effects=rigid, fidelity="2d"), values)
    t = np.linspace(0.0, 0.99 * min(r1.switch_time_s[0], r2.switch_time_s[0]), 300)
    f1, f2, f0 = (np.interp(t, r.time_s[0], r.force_kN[0]) for r in (r1, r2, r0))
    scale = float(np.sqrt(np.mean(f1**2)))
    return {"effects": effects, "rms_vs_1d_pct": 100 * float(np.sqrt(np.mean((f2 - f1) ** 2))) / scale,
            "frame_moves_force_pct": 100 * float(np.sqrt(np.mean((f2 - f0) ** 2))) / scale,
            "switch_1d_s": float(r1.switch_time_s[0]), "switch_2d_s": float(r2.switch_time_s[0]),
            "force_max_kN": float(f1.max()), "seconds": wall, "seconds_rigid": wall0}


def against_1d() -> list[dict]:
    """Section 2: the frame with the speed ramp and with compressibility, against 1-D."""
    cases = [
        _versus_1d(_bar(60, 48), ["press_compliance", "speed_ramp"],
                   {**STIFF, "ramp_time_s": 0.5, "load_slowdown": 0.6, "k_press_kN_mm": 100.0},
                   ["speed_ramp"]),
        _versus_1d(_bar(60, 24, mass_g=390.0, speed_mm_s=0.7), ["compressibility", "press_compliance"],
                   {**SHEAR, "k_press_kN_mm": 300.0}, ["compressibility"]),
    ]
    for c in cases:
        print(f"{' + '.join(c['effects'])}: {c['rms_vs_1d_pct']:.2f} % RMS against 1-D, switch "
              f"{c['switch_2d_s']:.3f} s (1-D {c['switch_1d_s']:.3f} s), the frame moves the force by "
              f"{c['frame_moves_force_pct']:.0f} %, {c['seconds']:.1f} s "
              f"(rigid frame {c['seconds_rigid']:.1f} s)")
    return cases


def thesis_draws(draws: int, seed: int) -> dict:
    """Section 3: prior draws on the thesis's centre charges with and without the frame."""
    if not DATA.is_dir():
        print(f"{DATA} not found: the thesis draws are skipped")
        return {}
    project = load_project(ROOT / "configs" / "thesis.toml", DATA)
    effects = ["compressibility", "press_compliance"]
    over = {"rho_solid_g_cm3": 1.5}
    full = ForwardModel(project, effects=effects, fidelity="2d", overrides=over)
    rigid = ForwardModel(project, effects=["compressibility"], fidelity="2d", overrides=over)
    theta = full.space.from_unit(np.random.default_rng(seed).random((draws, full.space.dim)))
    keep = [full.space.free_names.index(n) for n in rigid.space.free_names]
    out: dict = {}
    for cid in ("60-center-07", "80-center-07"):
        rows = []
        for i in range(draws):
            row = {}
            for name, model, th in (("frame", full, theta[i:i + 1]), ("rigid", rigid, theta[i:i + 1, keep])):
                t0 = time.perf_counter()
                res = model.simulate(th, [cid])[cid]
                row[name] = {"status": res.status[0], "seconds": time.perf_counter() - t0,
                             "switch_s": float(res.switch_time_s[0])}
            rows.append(row)
            print(f"{cid} draw {i}: frame {row['frame']['status'][:60]} {row['frame']['seconds']:.1f} s, "
                  f"rigid {row['rigid']['status'][:60]} {row['rigid']['seconds']:.1f} s", flush=True)
        out[cid] = rows
    return out


def main() -> None:
    """Run the three sections, print their figures and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=4, help="prior draws per thesis configuration")
    parser.add_argument("--seed", type=int, default=1, help="seed of the prior draws")
    args = parser.parse_args()
    result = {"convergence": convergence(), "against_1d": against_1d(),
              "thesis_draws": thesis_draws(args.draws, args.seed)}
    for cid, rows in result["thesis_draws"].items():
        for name in ("frame", "rigid"):
            fails = sum(r[name]["status"] != "ok" for r in rows)
            secs = [r[name]["seconds"] for r in rows]
            print(f"{cid} {name}: {fails}/{len(rows)} failed, {np.median(secs):.1f} s median "
                  f"({min(secs):.1f}-{max(secs):.1f} s) a run")
    path = ROOT / "benchmarks" / "results" / "forward_2d_frame.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
