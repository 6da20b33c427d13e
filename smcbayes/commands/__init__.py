"""CLI subcommands, one module each with ``add_parser(subparsers)`` and ``run(args)``."""

from smcbayes.commands import demo, simulate

COMMANDS = (simulate, demo)
