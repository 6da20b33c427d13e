"""Compressible charge against the measured 60 % bar at 0.3 mm/s (thesis configuration 60-bar-03).

The incompressible model stops at the fill gap (4.8 mm) and jumps to the force limit
there; the real press closed to about 2.6 mm.  With the ``compressibility`` effect and
hand-chosen parameters inside the thesis's bounds, this script checks that the simulated
run reaches 1400 kN below 4.0 mm with the measured shape (a long low-force phase, then a
steep rise), prints the gap at the limit, the time to the limit (measured 17.9 s) and the
RMSE against the measured force, and writes ``benchmarks/results/compressible_60bar.png``
(+ .svg, .json).

Choice of parameters (no fitting algorithm): a coarse grid of 20 412 sets over the thesis
bounds (n 0.3/0.45/0.6; tau* and B 1e3/1e4/1e5; tau_c 0.005/0.05/0.5 MPa; m 1/1.5/1.9;
rho_solid 1.6/1.7/1.8 g/cm3; compaction modulus 0.01-10 MPa, 7 log steps; exponent
2/5/8/12; no bulk viscosity) ranked by RMSE, then a small grid around the best sets.  The
sets that keep the force low for long need a stiff, slowly slipping charge (tau*, B at
1e5, m near 1) and a soft compaction law (k_c ~ 0.2-0.5 MPa, exponent 1.5-2) with a solid
density of 1.7-1.8 g/cm3 (s0 = 0.48-0.51); the chosen set below is one of the best and
keeps m off its bound.  The measured data are read by path and never copied.

Usage: ``python benchmarks/compressible_60bar.py [--data DIR]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import load_project
from smcbayes.data.readers.csv import read_columns
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.result import SimulationResult
from smcbayes.plotting import pyplot, save

Array = NDArray[np.float64]
ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
CONFIG_ID = "60-bar-03"
PARAMETERS = {
    "n": 0.45, "tau_star_Pa": 1e5, "B_Pa_s": 1e5, "tau_c_MPa": 0.5, "m": 1.2,
    "rho_solid_g_cm3": 1.8, "compaction_modulus_MPa": 0.2, "compaction_exponent": 2.0,
    "bulk_viscosity_MPa_s": 0.0,
}
GAP_TARGET_MM = 4.0


def simulate(project_path: Path, effects: list[str]) -> tuple[ForwardModel, SimulationResult]:
    """Run the configuration at :data:`PARAMETERS` (base parameters only without effects)."""
    model = ForwardModel(load_project(project_path), effects=effects)
    batch = {name: np.array([PARAMETERS[name]]) for name in model.space.names}
    return model, model.simulate_params(batch, [CONFIG_ID])[CONFIG_ID]


def shape(time_s: Array, force_kN: Array, t_limit: float, limit_kN: float) -> dict[str, float]:
    """Share of the time to the limit spent below 10 % of the limit, and the 10-90 % rise time."""
    closing = time_s <= t_limit
    t, f = time_s[closing], force_kN[closing]
    t10 = float(t[np.argmax(f >= 0.1 * limit_kN)])
    t90 = float(t[np.argmax(f >= 0.9 * limit_kN)])
    return {"low_phase_share": t10 / t_limit, "rise_10_90_s": t90 - t10}


def figure(measured: tuple[Array, Array], comp: SimulationResult, base: SimulationResult,
           path: Path, title: str) -> Path:
    plt = pyplot()
    fig, (ax, ax_gap) = plt.subplots(2, 1, figsize=(8, 7), sharex=True, height_ratios=(2, 1))
    t_end = max(comp.switch_time_s[0], measured[0][-1]) + 3.0
    ax.plot(measured[0], measured[1], color="black", lw=2, label="measured 60-bar-03")
    for res, colour, label in ((comp, "tab:red", "compressible charge"),
                               (base, "tab:blue", "incompressible (base model)")):
        keep = res.time_s[0] <= t_end
        ax.plot(res.time_s[0, keep], res.force_kN[0, keep], color=colour, label=label)
        ax_gap.plot(res.time_s[0, keep], res.gap_mm[0, keep], color=colour, label=label)
    ax_gap.plot(measured[0], 8.0 - 0.3 * measured[0], color="black", ls=":",
                label="8 mm - 0.3 mm/s x t (rigid press)")
    ax_gap.axhline(GAP_TARGET_MM, color="grey", lw=0.8, ls="--")
    ax.set_ylabel("press force (kN)")
    ax_gap.set_ylabel("gap (mm)")
    ax_gap.set_xlabel("time from first contact (s)")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left")
    ax_gap.legend(loc="lower left", fontsize=8)
    for a in (ax, ax_gap):
        a.grid(alpha=0.3)
    return save(fig, path)[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "thesis.toml")
    parser.add_argument("--data", type=Path, default=ROOT / ".." / "shared" / "data" / "thesis-press")
    args = parser.parse_args()
    data_file = args.data.resolve() / "force" / f"{CONFIG_ID}.csv"
    if not data_file.is_file():
        print(f"measured curve not found: {data_file}")
        return 1
    t_meas, f_meas = read_columns(data_file, ("time_s", "force_kN"))
    model, comp = simulate(args.config, ["compressibility"])
    _, base = simulate(args.config, [])
    if comp.status[0] != "ok":
        print(f"simulation failed: {comp.status[0]}")
        return 1
    case = model.cases[CONFIG_ID]
    limit_kN = case.force_limit / 1e3
    t_limit = float(comp.switch_time_s[0])
    gap_limit = float(np.interp(t_limit, comp.time_s[0], comp.gap_mm[0]))
    f_sim = np.interp(t_meas, comp.time_s[0], comp.force_kN[0])
    rmse = float(np.sqrt(np.mean((f_sim - f_meas) ** 2)))
    rmse_base = float(np.sqrt(np.mean((np.interp(t_meas, base.time_s[0], base.force_kN[0]) - f_meas) ** 2)))
    s0 = case.mass / (case.area0 * case.gap0) / (PARAMETERS["rho_solid_g_cm3"] * 1e3)
    sim_shape = shape(comp.time_s[0], comp.force_kN[0], t_limit, limit_kN)
    meas_limit_s = float(t_meas[np.argmax(f_meas >= limit_kN)] if np.any(f_meas >= limit_kN) else t_meas[-1])
    meas_shape = shape(t_meas, f_meas, float(t_meas[-1]), limit_kN)
    ok = gap_limit < GAP_TARGET_MM
    print(f"{CONFIG_ID}, compressibility on, parameters: "
          + ", ".join(f"{k}={v:g}" for k, v in PARAMETERS.items()))
    print(f"  initial solid fraction s0 = {s0:.3f}; fully consolidated gap {s0 * case.gap_full * 1e3:.2f} mm")
    print(f"  gap at the {limit_kN:g} kN limit: {gap_limit:.2f} mm (target < {GAP_TARGET_MM:g} mm: "
          f"{'met' if ok else 'MISSED'}; incompressible fill gap {case.gap_full * 1e3:.2f} mm)")
    print(f"  time to the limit: {t_limit:.2f} s (measured {meas_limit_s:.2f} s; "
          f"incompressible model {base.switch_time_s[0]:.2f} s)")
    print(f"  RMSE of the force over the measured closing: {rmse:.1f} kN "
          f"(incompressible model {rmse_base:.1f} kN)")
    print(f"  shape: share of the time to the limit below 10 % of the limit: simulated "
          f"{sim_shape['low_phase_share']:.2f}, measured {meas_shape['low_phase_share']:.2f}; 10-90 % "
          f"rise: simulated {sim_shape['rise_10_90_s']:.2f} s, measured {meas_shape['rise_10_90_s']:.2f} s")
    values = [f"{k}={v:g}" for k, v in PARAMETERS.items()]
    title = (f"{CONFIG_ID}: compressible charge (s0 = {s0:.2f}); gap at limit {gap_limit:.2f} mm, "
             f"RMSE {rmse:.0f} kN\n" + ", ".join(values[:5]) + "\n" + ", ".join(values[5:]))
    png = figure((t_meas, f_meas), comp, base, RESULTS / "compressible_60bar", title)
    summary = {"config_id": CONFIG_ID, "parameters": PARAMETERS, "solid_fraction0": s0,
               "gap_at_limit_mm": gap_limit, "gap_target_mm": GAP_TARGET_MM, "gap_target_met": ok,
               "time_to_limit_s": t_limit, "measured_time_to_limit_s": meas_limit_s,
               "rmse_kN": rmse, "rmse_incompressible_kN": rmse_base,
               "incompressible_time_to_limit_s": float(base.switch_time_s[0]),
               "shape_simulated": sim_shape, "shape_measured": meas_shape}
    (RESULTS / "compressible_60bar.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    print(f"  figure: {png}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
