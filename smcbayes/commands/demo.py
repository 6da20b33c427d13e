"""``smcbayes demo``: run the package's most complete chain on an embedded case."""

from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

from smcbayes.commands.simulate import simulate_and_write
from smcbayes.config import build_project
from smcbayes.forward.model import ForwardModel


def embedded_project(name: str = "thesis.toml"):  # noqa: ANN201
    """The embedded project file shipped inside the package."""
    import tomllib

    text = resources.files("smcbayes.resources").joinpath(name).read_text(encoding="utf-8")
    return build_project(tomllib.loads(text), f"<embedded {name}>", Path.cwd())


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser("demo", help="run the whole chain on an embedded example",
                       description="Simulate the 12 thesis press configurations with default "
                                   "parameters and write curves and a figure.")
    p.add_argument("--out", default="smcbayes-demo", metavar="DIR",
                   help="output directory (default: ./smcbayes-demo)")
    p.add_argument("--quick", action="store_true", help="smaller budgets (for tests)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``demo``."""
    model = ForwardModel(embedded_project())
    return simulate_and_write(model, model.config_ids, Path(args.out))
