"""The curve emulator's active learning so far, and when it may stop.

:class:`LearningProgress` holds the learning's data and each round's measures: the emulator's
error at the round's fresh posterior draws, how far the emulated posterior's quantiles
moved, the spread of its sample functions, and the drift over the last
:data:`VALIDATED_ROUNDS` rounds.  :func:`rounds_validated` says when those rounds validate
the emulator, and :func:`confirmed` whether the reported posterior drawn then confirms it.
:func:`~smcbayes.posterior.curve_stage.learn` runs the rounds."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.posterior.correct import ImportanceSample
from smcbayes.posterior.curve_sample import ROUND_ESS, START_ROWS, FinalPosterior, quantile_shift
from smcbayes.posterior.spread import SPREAD_MAX

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

VALIDATED_ROUNDS = 3
"""Rounds in a row whose out-of-sample error is within the tolerance and whose posterior
quantiles moved by at most :data:`QUANTILE_SHIFT`, to stop.  Pooled over the rounds, the
error let the accuracy benchmark's first case stop after 240 active-learning runs at 0.99
nats, its last round 1.3, with a quantile 0.12 of the prior width off."""

QUANTILE_SHIFT = 0.05
"""Largest move of a 5/50/95 % quantile of the emulated posterior between rounds (share of
the unit cube) that a validated round allows, and over the :data:`VALIDATED_ROUNDS` rounds
that validate (their drift, :meth:`LearningProgress.drift`)."""

CONFIRMATIONS = 3
"""Most confirmations that may fail: then the learning asks for no more until the end of its
budget.  Each draws the reported posterior, 70-220 s on the measured thesis trials beside
other work (three to five rounds' fit and sampling); a learning whose validations the
reported posterior keeps failing would spend that every three rounds until its budget ends."""


@dataclass
class LearningProgress:
    """The active learning so far: the data, each round's measures (one entry per round),
    where the next round's importance sampling starts and where its exploration's walkers go
    on.

    Attributes:
        since: the first round that counts towards a validation (the one after the last
            failed confirmation), but at the budget's end.
        late: the last validation counted rounds from before the last failed confirmation,
            which only the budget's end allows.
        explorers: where the last round's exploration's walkers stopped ``(W, d)``, W the
            ensemble's walkers.
        earlier: the log posteriors of the emulators that drew the last rounds, the last
            round's at the end (at most :data:`VALIDATED_ROUNDS` + 1 of them).
        sample: the last round's importance sample of the emulated posterior.
        drifts: the drift over the rounds ending at each round that measured it
            (:meth:`drift`), by the rounds taken.
    """

    x: Array
    y: Array
    start: Array
    spent: int = 0
    rounds: int = 0
    since: int = 0
    errors: list[float] = field(default_factory=list)
    shifts: list[float | None] = field(default_factory=list)
    spreads: list[float] = field(default_factory=list)
    recent: list[Array] = field(default_factory=list)
    confirmations: list[dict[str, Any]] = field(default_factory=list)
    late: bool = False
    explorers: Array | None = None
    earlier: list[Callable[[Array], Array]] = field(default_factory=list)
    sample: ImportanceSample | None = None
    drifts: dict[int, float | None] = field(default_factory=dict)

    def validated(self, tolerance_nats: float, ended: bool = False) -> bool:
        """The rounds since the last failed confirmation validate the emulator
        (:func:`rounds_validated`); once the budget has ``ended``, the last
        :data:`VALIDATED_ROUNDS` rounds count whether they ran before or after it."""
        k = 0 if ended else self.since
        return rounds_validated(self.errors[k:], self.shifts[k:], tolerance_nats, self.spreads[k:],
                                self.drift)

    def drift(self) -> float | None:
        """How far the emulated posterior moved over the last :data:`VALIDATED_ROUNDS`
        rounds: the quantile shift (:func:`~smcbayes.posterior.curve_sample.quantile_shift`)
        between the last round's sample and the posterior of the emulator that drew the
        round that many rounds before; ``None`` with fewer rounds or a sample too thin to
        tell.  Each round's move may be small while the posterior creeps one way round after
        round, into a tail the emulator learns point by point: on the measured thesis trials
        two learnings whose last three rounds moved the quantiles by at most 0.048 each had
        drifted 0.066 and 0.121 over them, and n's 5 % quantile lay 0.23-0.25 of its range
        above where longer learnings put it.  Measured once a round, when a validation asks
        for it."""
        if self.rounds not in self.drifts:
            thin = (self.sample is None or len(self.earlier) <= VALIDATED_ROUNDS
                    or self.sample.ess < ROUND_ESS)
            self.drifts[self.rounds] = None if thin else quantile_shift(self.sample,
                                                                         self.earlier[-1 - VALIDATED_ROUNDS])
        return self.drifts[self.rounds]

    @property
    def before(self) -> Callable[[Array], Array] | None:
        """The log posterior of the emulator the last round sampled (``None`` before the
        first round)."""
        return self.earlier[-1] if self.earlier else None

    @property
    def draws(self) -> Array | None:
        """Draws ``(S, d)`` of the last round's emulated posterior (or of the last failed
        confirmation's; resampled, so heavy points repeat); ``None`` before the first round."""
        return self.start if self.rounds else None

    def failed(self) -> int:
        """How many confirmations failed."""
        return sum(1 for c in self.confirmations if not c["passed"])

    def may_confirm(self) -> bool:
        """Fewer than :data:`CONFIRMATIONS` confirmations failed, so a validation may still
        ask for one before the budget's end."""
        return self.failed() < CONFIRMATIONS

    def record(self, converged: bool) -> dict[str, Any]:
        """The active learning's record (see :func:`~smcbayes.posterior.curve_stage.learn`)."""
        last = [finite(e) for e in self.errors[-VALIDATED_ROUNDS:]]
        return {"evaluations": self.spent, "converged": converged, "rounds": self.rounds,
                "error_nats": None if not last or None in last else max(last),
                "quantile_shift": self.shifts[-1] if self.shifts else None,
                "last_errors_nats": last, "last_quantile_shifts": self.shifts[-VALIDATED_ROUNDS:],
                "last_spreads": [finite(v) for v in self.spreads[-VALIDATED_ROUNDS:]],
                "drift": self.drifts.get(self.rounds),
                "drifts": [{"rounds": k, "drift": v} for k, v in sorted(self.drifts.items())
                           if v is not None],
                "validated_rounds": VALIDATED_ROUNDS,
                "bounds": {"quantile_shift": QUANTILE_SHIFT, "drift": QUANTILE_SHIFT, "spread": SPREAD_MAX},
                "confirmations": self.confirmations, "validated_at_budget_end": self.late}


def round_status(progress: LearningProgress, tolerance_nats: float, budget: int) -> str:
    """One log line: the last round's measures beside the bounds the stop asks of
    :data:`VALIDATED_ROUNDS` rounds in a row (:meth:`LearningProgress.validated`; the spreads'
    mean over the rounds it counts), and the active-learning runs spent of ``budget``, so
    that a user watching a long learning sees what it still waits for."""
    shift = progress.shifts[-1]
    moved = ("posterior move not measured" if shift is None else
             f"posterior moved {shift:.3f} of a parameter's range (at most {QUANTILE_SHIFT:g})")
    # at the budget's end the stop counts the last rounds whenever they ran
    since = 0 if progress.spent >= budget else progress.since
    counted = progress.spreads[since:][-VALIDATED_ROUNDS:]
    mean = (f", mean of the last {VALIDATED_ROUNDS} {np.mean(counted):.3f}"
            if len(counted) == VALIDATED_ROUNDS else "")
    return (f"{progress.spent:,} of {budget:,} active-learning runs; error {progress.errors[-1]:.2f} nats "
            f"at fresh posterior draws (at most {tolerance_nats:g} to stop), {moved}, spread "
            f"{progress.spreads[-1]:.3f}{mean} (at most {SPREAD_MAX:g} on average)")


def log_drift(progress: LearningProgress) -> None:
    """One log line with the posterior's drift over the last rounds, when a validation
    measured it (their other measures passed): whether it passes or holds the learning."""
    drift = progress.drifts.get(progress.rounds)
    if drift is not None:
        logger.info("curve emulator round %d: the posterior moved %.3f of a parameter's range over the "
                    "last %d rounds (at most %g to stop)", progress.rounds, drift, VALIDATED_ROUNDS,
                    QUANTILE_SHIFT)


def confirmed(progress: LearningProgress, final: FinalPosterior, rng: np.random.Generator,
              going_on: bool) -> bool:
    """Whether the reported posterior ``final`` of a validated emulator has a spread of at
    most :data:`~smcbayes.posterior.spread.SPREAD_MAX`; records it (with its time) and,
    when it has not and the learning is ``going_on``, restarts the validation and starts
    the next round's sampling from the mean's importance sample of that posterior."""
    passed = bool(final.max_shift <= SPREAD_MAX)
    se = (final.spread or {}).get("max_quantile_shift_se")
    progress.confirmations.append({"rounds": progress.rounds, "forward_runs": progress.spent,
                                   "spread": finite(final.max_shift), "spread_se": se, "passed": passed,
                                   "seconds": float(sum(final.seconds.values()))})
    logger.info("curve emulator validated after %d rounds; the reported posterior's spread %.4f%s %s",
                progress.rounds, final.max_shift, "" if se is None else f" (standard error {se:.4f})",
                "confirms it" if passed else f"does not (> {SPREAD_MAX})")
    if not passed and going_on:
        progress.since = progress.rounds
        progress.start = final.sample.resample(3 * START_ROWS // 4, rng)
        if progress.failed() >= CONFIRMATIONS:
            logger.info("curve emulator: %d confirmations failed; no more, the learning runs to its budget",
                        CONFIRMATIONS)
    return passed


def finite(value: float) -> float | None:
    """``value`` as a float, ``None`` where it is not finite (JSON has no infinity)."""
    return float(value) if np.isfinite(value) else None


def rounds_validated(errors: list[float], shifts: list[float | None], tolerance_nats: float,
                     spreads: list[float], drift: Callable[[], float | None]) -> bool:
    """The last :data:`VALIDATED_ROUNDS` rounds validate the emulator, their mean spread is
    small and the posterior's ``drift`` over them (called only when the rest holds, as it
    costs a pass over the last round's sample) is within :data:`QUANTILE_SHIFT` (see
    :func:`~smcbayes.posterior.curve_stage.learn`)."""
    recent = shifts[-VALIDATED_ROUNDS:]
    if not (len(recent) == VALIDATED_ROUNDS and all(s is not None and s <= QUANTILE_SHIFT for s in recent)
            and all(e <= tolerance_nats for e in errors[-VALIDATED_ROUNDS:])
            and bool(np.mean(spreads[-VALIDATED_ROUNDS:]) <= SPREAD_MAX)):
        return False
    moved = drift()
    return moved is not None and moved <= QUANTILE_SHIFT
