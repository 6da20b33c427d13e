"""Command-line interface: a thin shell over the library.

Each subcommand lives in :mod:`smcbayes.commands` as a module with ``add_parser`` and
``run``.  Bad input (:class:`~smcbayes.errors.InputError`) exits with code 2 and one line.
"""

from __future__ import annotations

import argparse
import logging
import os
import shlex
import sys
import textwrap
import warnings
from collections.abc import Sequence
from typing import TextIO

from smcbayes import __version__, progress
from smcbayes.commands import COMMANDS
from smcbayes.errors import InputError, SmcBayesError, SmcBayesWarning


class DefaultsFormatter(argparse.HelpFormatter):
    """Every option's help ends with its default, unless the help already names it or
    there is none (``None``: the project file's table or nothing applies)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("default" in text or default is None or default is False or default == []
                or default == argparse.SUPPRESS or not action.option_strings):
            return text
        return f"{text} (default: %(default)s)"

    # a hyphenated word (log-loss, flow-stop, 2-D) stays whole: "log- loss" across two lines
    # reads as two words, and the help's text would no longer be found in it
    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return textwrap.fill(" ".join(text.split()), width, initial_indent=indent, subsequent_indent=indent,
                             break_on_hyphens=False)


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
    parser.add_argument("--verbose", "-v", action="store_true", help="more detail in the log lines")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS:
        module.add_parser(sub)
    for command in sub.choices.values():
        command.formatter_class = DefaultsFormatter
    return parser


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: TextIO | None = None, line: str | None = None) -> None:
    """Warnings as one plain line each (smcbayes's own without the source location)."""
    if issubclass(category, SmcBayesWarning):
        print(f"warning: {message}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line).rstrip(), file=sys.stderr)


class _Stderr(logging.Handler):
    """Log records as plain lines on the current ``sys.stderr`` (looked up at each record,
    so a redirected or captured stderr is honoured)."""

    def emit(self, record: logging.LogRecord) -> None:
        print(self.format(record), file=sys.stderr)


def setup_output(verbose: bool = False) -> None:
    """What an application does and a library must not: a non-interactive matplotlib
    backend, log records and warnings on stderr, progress switched on."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    root = logging.getLogger("smcbayes")
    if not any(isinstance(h, _Stderr) for h in root.handlers):
        handler = _Stderr()
        handler.setFormatter(logging.Formatter("%(message)s"))
        root.addHandler(handler)
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
    root.propagate = False
    warnings.showwarning = _show_warning
    progress.enable(True)


def _continue_hint(args: argparse.Namespace) -> str:
    """How to go on after an interruption: nothing finished is lost in any stage."""
    if args.command == "calibrate":
        again = list(args.argv) + ([] if "--resume" in args.argv else ["--resume"])
        return f"continue with: {shlex.join(again)}"
    if args.command in ("posterior", "diagnose"):
        return "rerun the same command to continue (its finished forward runs are reused)"
    return "rerun the command"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``smcbayes`` console script; returns the exit code."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.argv = ["smcbayes", *argv]
    setup_output(getattr(args, "verbose", False))
    try:
        return int(args.run(args) or 0)
    except InputError as err:
        print(f"smcbayes {args.command}: error: {err}", file=sys.stderr)
        return 2
    except (FileExistsError, NotADirectoryError, IsADirectoryError, PermissionError) as err:
        # a path given on the command line that cannot be used as asked
        print(f"smcbayes {args.command}: error: {err.filename}: {err.strerror}; choose another path",
              file=sys.stderr)
        return 2
    except SmcBayesError as err:
        print(f"smcbayes {args.command}: failed: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"smcbayes {args.command}: interrupted; {_continue_hint(args)}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
