"""One exception tree for the whole package.

Every error raised on purpose by smcbayes derives from :class:`SmcBayesError`.
Errors caused by what the user gave us (a config, a data file, a command-line value)
derive from :class:`InputError`; the CLI turns those into exit code 2 and a single line.
"""

from __future__ import annotations


class SmcBayesError(Exception):
    """Root of all smcbayes errors."""


class InputError(SmcBayesError, ValueError):
    """Bad user input: the message names the offending key, file or value and the fix."""


class ConfigError(InputError):
    """A configuration (TOML file, ``--set`` override, CLI option) is invalid."""


class DataError(InputError):
    """A measured-data file is missing, unreadable or inconsistent."""


class SolverError(SmcBayesError, RuntimeError):
    """A forward solver could not produce a result."""


class SurrogateError(SmcBayesError, RuntimeError):
    """Fitting or optimising the surrogate model failed."""
