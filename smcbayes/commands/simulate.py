"""``smcbayes simulate``: run the forward model on configurations, write curves and a figure."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from smcbayes.commands.common import add_model_options, output_folder
from smcbayes.config import load_project, parse_assignments
from smcbayes.data.dataset import measured_force
from smcbayes.data.readers.csv import write_curves
from smcbayes.forward.model import ForwardModel
from smcbayes.plotting import plot_flow_front, plot_simulation


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "simulate", help="simulate press configurations at given parameters",
        description="Simulate press configurations with the native squeeze-flow model. Writes "
                    "one CSV per configuration (time_s, gap_mm, displacement_mm, force_kN, "
                    "fill_fraction, solid_fraction, phase) and a figure of force and ram "
                    "displacement vs time with the measured force where the config has it.")
    p.add_argument("config", help="project TOML file (e.g. configs/thesis.toml)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--only", nargs="+", metavar="ID", default=None,
                   help="simulate only these configuration ids")
    add_model_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``simulate``."""
    project = load_project(args.config, args.data_dir)
    model = ForwardModel(project, effects=args.effect, overrides=parse_assignments(args.set),
                         fidelity=args.fidelity)
    ids = args.only or model.config_ids
    return simulate_and_write(model, ids, output_folder(args.out))


def simulate_and_write(model: ForwardModel, ids: list[str], out: Path) -> int:
    """Simulate ``ids`` at the model's parameter values and write CSVs and the figure."""
    start = time.perf_counter()
    results = model.simulate(None, ids)
    seconds = time.perf_counter() - start
    out.mkdir(parents=True, exist_ok=True)
    for cid, res in results.items():
        write_curves(res, 0, out / f"{cid}.csv")
    values = model.space.defaults()
    label = ", ".join(f"{k}={v:.4g}" for k, v in values.items())
    effects = ", ".join(model.effects.names) or "none"
    figure = plot_simulation(results, measured_force(model.project, ids), out / "simulation",
                             f"{label}\neffects: {effects}")
    print(f"simulated {len(ids)} configuration(s) in {seconds * 1000:.0f} ms "
          f"({model.solver.name} solver, effects: {effects})")
    print(f"{'configuration':<16}{'status':<10}{'limit reached (s)':>18}{'final gap (mm)':>16}")
    for cid, res in results.items():
        print(f"{cid:<16}{res.status[0]:<10}{res.switch_time_s[0]:>18.2f}{res.gap_mm[0, -1]:>16.3f}")
    print(f"curves: {out}/<id>.csv; figure: {figure[0]}")
    fields = getattr(model.solver, "fields", None)
    if fields:
        drawn = 0
        for cid, res in results.items():
            h = fields[cid][0]
            if h is None:  # the run of this configuration failed
                continue
            plot_flow_front(res, h.time_s, h.fill, h.x_faces_mm, h.y_faces_mm,
                            out / f"flow_front_{cid}", f"{cid}: {label}", solid=h.solid)
            drawn += 1
        if drawn:
            print(f"flow-front figures: {out}/flow_front_<id>.png")
    return 0
