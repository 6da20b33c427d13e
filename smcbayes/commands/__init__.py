"""CLI subcommands, one module each with ``add_parser(subparsers)`` and ``run(args)``."""

from smcbayes.commands import calibrate, demo, evaluate, posterior, simulate, synth

COMMANDS = (simulate, synth, evaluate, calibrate, posterior, demo)
