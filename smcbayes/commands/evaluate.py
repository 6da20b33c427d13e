"""``smcbayes evaluate``: the loss of the model at one parameter point against measured data."""

from __future__ import annotations

import argparse

import numpy as np

from smcbayes.commands.common import add_model_options
from smcbayes.config import load_project, parse_assignments
from smcbayes.data.breakdown import force_breakdown
from smcbayes.data.dataset import Dataset, load_dataset
from smcbayes.data.loss import (
    LossResult,
    LossSpec,
    contact_beyond_bound,
    contact_offsets_mm,
    evaluate_loss,
)
from smcbayes.errors import DataError
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.result import SimulationResult


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "evaluate", help="loss of the model at given parameters against the measured data",
        description="Load the measured curves, simulate the training configurations at one "
                    "parameter point (config values, --set overrides) and print the RMSE per "
                    "configuration (kN, mm), where the force error lies (phase; timing shift / "
                    "amplitude / shape) and the global loss, full and clipped at the "
                    "incompressible flow-stop time as in the thesis.")
    p.add_argument("config", help="project TOML file (e.g. configs/thesis.toml)")
    p.add_argument("--role", choices=("train", "validation", "all"), default="train",
                   help="configurations to evaluate (default: train)")
    add_model_options(p)
    p.set_defaults(run=run)


def _offsets_without_end_state(results: dict[str, SimulationResult], dataset: Dataset, spec: LossSpec,
                               ids: list[str]) -> dict[str, tuple[float, ...]]:
    """With the contact from the end state, the offsets (mm) each of ``ids`` without an end
    state is averaged over: the training trials' own (a trial not yet pressed, as
    predicted; :func:`smcbayes.data.loss.mixed_force_pair`)."""
    if spec.contact_mode != "end_state":
        return {}
    missing = [c for c in ids if dataset[c].end_stack_mm is None]
    if not missing:
        return {}
    own = tuple(contact_offsets_mm(results, dataset, spec, dataset.ids("train")).values())
    return {c: own for c in missing}


def _offsets_line(results: dict[str, SimulationResult], dataset: Dataset, spec: LossSpec,
                  ids: list[str]) -> str | None:
    """The line that gives each configuration's contact offset (mm) and how it was found;
    a trial whose end state lies beyond the bound also shows the offset it implies."""
    offsets = contact_offsets_mm(results, dataset, spec, ids)
    if not offsets:
        return None
    bound = spec.contact_offset_mm
    if spec.contact_mode == "profile":
        how = f"its best contact offset within +-{bound:g} mm ([loss] contact_offset_mm)"
    else:
        how = "the contact offset its end state implies ([loss] contact)" + \
            (f", within +-{bound:g} mm ([loss] contact_offset_mm)" if bound > 0 else "")
    beyond = contact_beyond_bound(results, dataset, spec, list(offsets))
    cells = [f"{c} {v:+.2f} mm" + (f" (on the bound; its end state implies {beyond[c]:+.2f} mm)"
                                   if c in beyond else "") for c, v in offsets.items()]
    return f"each configuration at {how}: " + ", ".join(cells)


def _rmse(x: float) -> str:
    return f"{np.sqrt(x):.2f}" if np.isfinite(x) else "-"


def print_table(full: LossResult, clipped: LossResult, shift_s: np.ndarray,
                parts: np.ndarray, phase_share: np.ndarray) -> None:
    """Per-configuration RMSE table (row 0 of the results)."""
    print(f"{'configuration':<16}{'force RMSE (kN)':>16}{'clipped (kN)':>14}{'hold (mm)':>11}"
          f"{'lag (s)':>11}{'shift/amp/shape %':>20}{'  worst phase'}")
    names = ("contact", "flow", "full", "force_control")
    for k, cid in enumerate(full.ids):
        e = full.force_mse_kN2[0, k]
        split = "/".join(f"{100 * p / e:.0f}" if e > 0 else "0" for p in parts[:, k])
        worst = names[int(np.nanargmax(phase_share[k]))] if np.any(np.isfinite(phase_share[k])) else "-"
        print(f"{cid:<16}{_rmse(e):>16}{_rmse(clipped.force_mse_kN2[0, k]):>14}"
              f"{_rmse(full.displacement_mse_mm2[0, k]):>11}{shift_s[k]:>11.2f}{split:>20}  {worst}")


def run(args: argparse.Namespace) -> int:
    """Execute ``evaluate``."""
    project = load_project(args.config, args.data_dir)
    dataset = load_dataset(project)
    role = None if args.role == "all" else args.role
    ids = [cid for cid in dataset.ids(role) if dataset[cid].force is not None]
    if not ids:
        raise DataError(f"{args.config}: no {args.role} configuration has a measured force curve; "
                        "check data_dir / --data-dir and the data tables")
    model = ForwardModel(project, effects=args.effect, overrides=parse_assignments(args.set),
                         fidelity=args.fidelity)
    results = model.simulate(None, ids)
    spec = project.loss
    given = _offsets_without_end_state(results, dataset, spec, ids)
    full = evaluate_loss(results, dataset, spec, ids, given)
    clipped = evaluate_loss(results, dataset, spec.model_copy(update={"clip": "flow_stop"}), ids, given)
    bd = force_breakdown(results, dataset, spec, ids, given)
    values = ", ".join(f"{k}={v:.4g}" for k, v in model.space.defaults().items())
    print(f"parameters: {values}; effects: {', '.join(model.effects.names) or 'none'}")
    failed = [cid for cid in ids if not results[cid].ok[0]]
    for cid in failed:
        print(f"{cid}: simulation failed: {results[cid].status[0]}")
    parts = np.stack([bd.shift_kN2[0], bd.amplitude_kN2[0], bd.shape_kN2[0]])
    print_table(full, clipped, bd.shift_s[0], parts, bd.phase_share[0])
    line = _offsets_line(results, dataset, spec, ids)
    if line:
        print(line)
    if given:
        print("without an end state, averaged over the training trials' offsets (mean "
              + ", ".join(f"{c} {np.mean(v) if v else 0.0:+.2f} mm" for c, v in given.items()) + ")")
    print(f"global loss L (w_F={spec.w_force:g}, w_D={spec.w_displacement:g}, {spec.grid_points} "
          f"points): full {full.total[0]:.6g} kN^2 (RMSE {_rmse(full.total[0])} kN); clipped at "
          f"flow stop (thesis) {clipped.total[0]:.6g} kN^2 (RMSE {_rmse(clipped.total[0])} kN)")
    return 1 if failed else 0
