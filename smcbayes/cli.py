"""Command-line interface: a thin shell over the library.

Each subcommand lives in :mod:`smcbayes.commands` as a module with ``add_parser`` and
``run``.  Bad input (:class:`~smcbayes.errors.InputError`) exits with code 2 and one line.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from smcbayes import __version__
from smcbayes.commands import COMMANDS
from smcbayes.errors import InputError, SmcBayesError


def build_parser() -> argparse.ArgumentParser:
    """The ``smcbayes`` argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="smcbayes",
        description="Identify SMC rheology (viscosity, wall slip) from press force-time "
                    "curves: native squeeze-flow simulation, Bayesian calibration, posterior "
                    "with predictive bands, and a sim-to-real gap diagnosis.",
        epilog="Units at the edges: mm, mm/s, kN, MPa, C, g; every key names its unit.",
    )
    parser.add_argument("--version", action="version", version=f"smcbayes {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS:
        module.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``smcbayes`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except InputError as err:
        print(f"smcbayes {args.command}: error: {err}", file=sys.stderr)
        return 2
    except SmcBayesError as err:
        print(f"smcbayes {args.command}: failed: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"smcbayes {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
