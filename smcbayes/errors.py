"""One exception tree and one warning tree for the whole package.

Every error raised on purpose by smcbayes derives from :class:`SmcBayesError`.
Errors caused by what the user gave us (a config, a data file, a command-line value)
derive from :class:`InputError`; the CLI turns those into exit code 2 and a single line.
Failures of the computation itself (a solver, the surrogate, an external command) are
:class:`SolverError` or :class:`SurrogateError`: exit code 1 and a short message.

Every warning derives from :class:`SmcBayesWarning`, so a user can filter them all or one
kind, e.g. ``warnings.simplefilter("ignore", smcbayes.errors.SlowPathWarning)``.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence


class SmcBayesError(Exception):
    """Root of all smcbayes errors."""


class InputError(SmcBayesError, ValueError):
    """Bad user input: the message names the offending key, file or value and the fix."""


class ConfigError(InputError):
    """A configuration (TOML file, ``--set`` override, CLI option) is invalid."""


class DataError(InputError):
    """A measured-data file is missing, unreadable or inconsistent."""


class RunDirError(InputError):
    """A file of a run directory is missing, foreign or damaged (a line of the evaluation
    log that cannot be read, a summary without its log): the message names the file, the
    line and what to do."""


class SolverError(SmcBayesError, RuntimeError):
    """A forward solver (native or external) could not produce a result."""


class SurrogateError(SmcBayesError, RuntimeError):
    """Fitting, sampling or optimising the surrogate or the posterior failed."""


class SmcBayesWarning(UserWarning):
    """Root of all smcbayes warnings."""


class ConvergenceWarning(SmcBayesWarning):
    """An iterative method (optimiser, sampler, importance correction) did not settle."""


class UnreliablePosteriorWarning(SmcBayesWarning):
    """A posterior's own diagnostics say its numbers should not be trusted."""


class ParameterOnBoundWarning(SmcBayesWarning):
    """A calibrated parameter lies at a search bound: the data want it beyond the box."""

    @staticmethod
    def advice(name: str, side: str, limit: float, value: float,
               physical: float | None = None) -> str:
        """What to do about a parameter ``name`` calibrated to ``value`` on its ``side``
        (``lower``/``upper``) search bound ``limit`` (user units), in one sentence.

        ``physical``: the parameter's physical limit on that side, if known: a bound at
        it cannot be widened, only physics added; one inside it can be widened up to it.
        """
        where = "above" if side == "upper" else "below"
        return (f"{name} = {value:.4g} lies on its {side} search bound: the data want {name} "
                f"{where} {limit:.4g}; " + ParameterOnBoundWarning.remedy(name, side, limit, physical))

    @staticmethod
    def remedy(name: str, side: str, limit: float, physical: float | None = None) -> str:
        """The second half of :meth:`advice`: widen the bound ``limit`` of ``name`` on its
        ``side``, or, where it is the physical limit ``physical``, add physics."""
        missing = "add the missing physics (smcbayes diagnose lists candidate effects)"
        if physical is None:
            return f"widen the bound in [parameters.{name}] if that is physical, or {missing}"
        beyond = limit >= physical if side == "upper" else limit <= physical
        if beyond:
            return (f"that is the end of its physical range ({physical:.4g}), so do not "
                    f"widen the bound: {missing}")
        return (f"widen the bound in [parameters.{name}] (its physical range ends at "
                f"{physical:.4g}), or {missing}")


class ContactOffsetWarning(SmcBayesWarning):
    """A trial's end state puts its contact beyond the range a charge can stand from its
    nominal height (``[loss] contact_offset_mm``): the model ends the closing elsewhere
    than the press did."""

    @staticmethod
    def advice(config_id: str, offset_mm: float, bound_mm: float) -> str:
        """What a contact offset ``offset_mm`` beyond +- ``bound_mm`` means, in one sentence."""
        return (f"{config_id}: its end state puts its contact {offset_mm:+.2f} mm from the nominal "
                f"stack height, beyond the +-{bound_mm:g} mm of [loss] contact_offset_mm, so it is "
                "compared at the bound: the model ends the closing elsewhere than the press did "
                "(a ram speed ramp or frame compliance far from the press's, or a compaction law "
                "that locks too early or too late); check the trial's part and stack height, or "
                "the effects")


class FixedOutsideBoxWarning(SmcBayesWarning):
    """A parameter was fixed (``--set``, ``[parameters]``) outside its search bounds."""


class SlowPathWarning(SmcBayesWarning):
    """A forward run takes a slower solver path than it could (e.g. not the compiled one)."""


class DataWarning(SmcBayesWarning):
    """Measured data were accepted but look suspicious."""


class StaleRunsWarning(SmcBayesWarning):
    """Forward runs an earlier stage kept were made by another model (the package, its model
    code, the run's model or the external solver's files changed since) and are not reused."""


def closest(name: str, choices: Sequence[str]) -> str:
    """Return a ``" (did you mean 'x'?)"`` hint for a misspelt ``name``, or ``""``."""
    match = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.5)
    return f" (did you mean '{match[0]}'?)" if match else ""
