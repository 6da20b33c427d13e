"""CLI subcommands, one module each with ``add_parser(subparsers)`` and ``run(args)``."""

from smcbayes.commands import calibrate, demo, diagnose, evaluate, posterior, report, simulate, synth

COMMANDS = (simulate, synth, evaluate, calibrate, posterior, diagnose, report, demo)
