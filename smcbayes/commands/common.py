"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import argparse
from pathlib import Path

from smcbayes.errors import ConfigError


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


def add_executor_options(p: argparse.ArgumentParser) -> None:
    """``--workers`` and ``--scheduler``: where a stage's forward runs execute."""
    p.add_argument("--workers", type=int, default=1,
                   help="local worker processes for the forward runs (default 1: in process)")
    p.add_argument("--scheduler", metavar="ADDR", default=None,
                   help="Dask scheduler address (tcp://host:8786): run the forward batches on a cluster")


def output_folder(path: str | Path, option: str = "--out") -> Path:
    """The output folder named by ``option``; it may exist, but not as a file.

    Raises:
        ConfigError: ``path`` is an existing file (one line naming it and the fix).
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: is a file; {option} names the output folder: choose another path "
                          "or move the file")
    return out
