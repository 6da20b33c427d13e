"""``smcbayes report``: one HTML page and a Markdown twin of a run directory."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the subcommand."""
    p = sub.add_parser(
        "report",
        help="write the report of a run (self-contained HTML and Markdown)",
        description="Write RUN_DIR/report.html (one self-contained file: figures embedded, no "
        "network needed, printable) and RUN_DIR/report.md (figures by relative path): "
        "data, calibration, posterior, predictive bands, gap diagnosis and a "
        "reproducibility block. Sections of stages that were not run are left out.",
    )
    p.add_argument("run_dir", metavar="RUN_DIR", help="run directory of `smcbayes calibrate`")
    p.add_argument(
        "--format",
        choices=("html", "md", "both"),
        default="both",
        help="what to write (default: both)",
    )
    p.add_argument(
        "--diagnosis",
        metavar="DIR",
        default=None,
        help="output folder of `smcbayes diagnose` (default: RUN_DIR/diagnose)",
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``report``."""
    from smcbayes.report import write_report

    formats = ("html", "md") if args.format == "both" else (args.format,)
    diag = Path(args.diagnosis) if args.diagnosis else None
    for path in write_report(Path(args.run_dir), formats, diag):
        print(f"report: {path}")
    return 0
