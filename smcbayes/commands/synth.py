"""``smcbayes synth``: synthetic measurements at known parameters, with realistic noise."""

from __future__ import annotations

import argparse

from smcbayes.commands.common import output_folder
from smcbayes.config import load_project, parse_assignments
from smcbayes.data.synth import TRUTH_FILE, NoiseSpec, write_synthetic
from smcbayes.forward.model import ForwardModel


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "synth", help="make synthetic measured data at known parameters",
        description="Simulate the configurations at known parameter values (--truth) with the "
                    "chosen effects, add white and slowly varying correlated force noise "
                    "(and optionally the quantisation of digitised data), and write a dataset "
                    "folder that reads like real data: force/<id>.csv, hold/<id>.csv, "
                    "project.toml and truth.json.")
    p.add_argument("config", help="project TOML file whose configurations are simulated")
    p.add_argument("--truth", action="append", default=[], metavar="NAME=VALUE",
                   help="true parameter value in its named unit, e.g. --truth n=0.35 (repeatable; "
                        "others keep the config's values)")
    p.add_argument("--effect", action="append", default=None, metavar="NAME",
                   help="effect on in the truth model (repeatable); default: the config's effects")
    p.add_argument("--only", nargs="+", metavar="ID", default=None,
                   help="configurations to write (default: all)")
    p.add_argument("--noise-kN", type=float, default=0.0, help="white force noise sd (kN)")
    p.add_argument("--correlated-kN", type=float, default=0.0,
                   help="sd of the slowly varying (Ornstein-Uhlenbeck) force error (kN)")
    p.add_argument("--correlation-s", type=float, default=1.0,
                   help="correlation time of that error (s, default 1)")
    p.add_argument("--resolution-s", type=float, default=0.0,
                   help="round times to this step, like digitised data (s, 0: off)")
    p.add_argument("--resolution-kN", type=float, default=0.0,
                   help="round forces to this step (kN, 0: off)")
    p.add_argument("--noise-mm", type=float, default=0.0, help="white hold displacement noise sd (mm)")
    p.add_argument("--sample-s", type=float, default=0.02, help="closing force sampling interval (s)")
    p.add_argument("--hold-sample-s", type=float, default=1.0, help="hold sampling interval (s)")
    p.add_argument("--fidelity", choices=("1d", "2d"), default=None, help="forward solver")
    p.add_argument("--seed", type=int, required=True, help="random seed (same seed, same data)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``synth``."""
    project = load_project(args.config)
    truth = parse_assignments(args.truth, "--truth")
    model = ForwardModel(project, effects=args.effect, overrides=truth, fidelity=args.fidelity)
    ids = args.only or model.config_ids
    for cid in ids:
        project.get(cid)
    noise = NoiseSpec(white_kN=args.noise_kN, correlated_kN=args.correlated_kN,
                      correlation_s=args.correlation_s, resolution_s=args.resolution_s,
                      resolution_kN=args.resolution_kN, white_mm=args.noise_mm,
                      sample_s=args.sample_s, hold_sample_s=args.hold_sample_s)
    out = output_folder(args.out)
    path = write_synthetic(model, ids, noise, args.seed, out, truth, source=str(args.config))
    values = ", ".join(f"{k}={v:.4g}" for k, v in model.space.defaults().items())
    print(f"synthetic data for {len(ids)} configuration(s) at {values}")
    print(f"effects: {', '.join(model.effects.names) or 'none'}; noise: white {noise.white_kN:g} kN, "
          f"correlated {noise.correlated_kN:g} kN over {noise.correlation_s:g} s; seed {args.seed}")
    print(f"project: {path}; truth: {out / TRUTH_FILE}")
    return 0
