"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from smcbayes.config import ProjectConfig
from smcbayes.data.dataset import load_dataset
from smcbayes.forward.result import PHASE_NAMES, SimulationResult


def add_model_options(p: argparse.ArgumentParser) -> None:
    """``--set``, ``--effect``, ``--data-dir`` and ``--fidelity``."""
    p.add_argument("--set", action="append", metavar="NAME=VALUE", default=[],
                   help="fix a parameter in its named unit, e.g. --set n=0.4 --set tau_c_MPa=0.05 "
                        "(repeatable)")
    p.add_argument("--effect", action="append", metavar="NAME", default=None,
                   help="switch an effect on (repeatable): compressibility, heating, curing, "
                        "press_compliance, speed_ramp; default: the config's 'effects'")
    p.add_argument("--data-dir", metavar="DIR", default=None,
                   help="directory of the measured curves (overrides the config's data_dir)")
    p.add_argument("--fidelity", choices=("1d", "2d"), default=None,
                   help="forward solver: fast 1-D (default) or 2-D thin-cavity reference")


def measured_force(project: ProjectConfig, ids: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Measured force curves ``(time_s, force_kN)`` of configurations that have them.

    Read through :func:`smcbayes.data.dataset.load_dataset` (formats, units, the project's
    pre-processing); empty when the project's data folder does not exist.
    """
    root = project.data_path()
    if root is None or not root.is_dir():
        return {}
    dataset = load_dataset(project, ids)
    return {cid: (m.force.time_s, m.force.values) for cid, m in dataset.measurements.items()
            if m.force is not None}


def write_curves(result: SimulationResult, row: int, path: Path) -> None:
    """One CSV of a simulated configuration: time, gap, displacement, force, fill, phase."""
    cols = result.row(row)
    names = ("time_s", "gap_mm", "displacement_mm", "force_kN", "fill_fraction", "solid_fraction")
    with path.open("w", encoding="utf-8") as fh:
        fh.write(",".join(names) + ",phase\n")
        for i in range(cols["time_s"].size):
            values = ",".join(f"{cols[n][i]:.9g}" for n in names)
            fh.write(f"{values},{PHASE_NAMES[int(cols['phase'][i])]}\n")
