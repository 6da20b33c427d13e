"""Progress of long work: one mechanism for every stage.

Library code reports progress through :class:`Progress` and never prints.  Progress is
shown only once an application switches it on with :func:`enable` (the command line
does; a notebook user may): on a terminal as a tqdm bar whose remaining-time estimate
comes from the measured rate (see :class:`Progress`), otherwise (a log file, CI) as one
plain log line on the ``smcbayes.progress`` logger at most every ``interval_s`` seconds
(and the last), so that files are not garbled by carriage returns.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any

logger = logging.getLogger("smcbayes.progress")

_STATE = {"enabled": False, "interval_s": 10.0}


def enable(on: bool = True, interval_s: float = 10.0) -> None:
    """Show progress (``on``) of every later :class:`Progress`; ``interval_s`` spaces the
    plain log lines written when stderr is not a terminal."""
    _STATE["enabled"] = on
    _STATE["interval_s"] = float(interval_s)


def enabled() -> bool:
    """Whether progress is shown."""
    return bool(_STATE["enabled"])


def _format_s(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "?"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


class Progress:
    """Progress of ``total`` units of work (forward runs, evaluations, steps).

    Use as a context manager; :meth:`update` after each finished unit or batch.  The
    remaining time is the measured time per unit since the end of the first batch times
    the units left.  The first batch is left out because it often includes a compilation
    or a pool start-up.  Units of one batch often finish together (the calibration's
    initial design: ``init`` evaluations in one batched call, reported one by one within
    microseconds): an update that follows the previous one within ``burst_s`` belongs to
    the same batch, so the reference point moves on to it instead of a rate being taken
    from an instant.  Whatever runs between batches (the calibration's GP fit of each
    round) lies between two updates and so is in the rate.  Until a unit has finished
    after the first batch the remaining time is unknown (``?``), not guessed.

    Args:
        total: units expected (``None``: unknown, no remaining-time estimate).
        desc: what is being done, e.g. ``"calibration"``.
        unit: name of one unit, e.g. ``"eval"``.
        clock: seconds of a monotonic clock (a fake one in tests).
        burst_s: updates closer than this (s) count as one batch.
    """

    def __init__(self, total: int | None, desc: str, unit: str = "run",
                 clock: Callable[[], float] = time.perf_counter, burst_s: float = 0.05) -> None:
        self.total = total
        self.desc = desc
        self.unit = unit
        self.done = 0
        self.postfix = ""
        self._clock = clock
        self._burst_s = burst_s
        self._start = clock()
        self._ref: tuple[float, int] | None = None  # end of the first batch: (time, done)
        self._frozen = False
        self._last_update = -math.inf
        self._last_line = -math.inf
        self._bar: Any = None
        if enabled() and sys.stderr.isatty():
            from tqdm import tqdm

            # tqdm's own estimate would take a rate from a burst of units; ours is shown instead
            self._bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=True,
                             dynamic_ncols=True,
                             bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} {unit} [{elapsed}]{postfix}")

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def remaining_s(self) -> float:
        """Remaining time (s) from the measured rate after the first batch; NaN while unknown."""
        if self.total is None or self._ref is None:
            return float("nan")
        t0, n0 = self._ref
        done = self.done - n0
        if done <= 0:
            return float("nan")
        rate = (self._last_update - t0) / done
        return max(self.total - self.done, 0) * rate

    def set_total(self, total: int | None) -> None:
        """Change the units expected (work found or dropped on the way)."""
        self.total = total
        if self._bar is not None:
            self._bar.total = total
            self._bar.refresh()

    def elapsed_s(self) -> float:
        """Seconds since the start."""
        return self._clock() - self._start

    def update(self, n: int = 1, note: str = "") -> None:
        """``n`` more units done; ``note`` is a short status such as ``"best 12.3 kN^2"``."""
        now = self._clock()
        if not self._frozen and self._ref is not None and now - self._last_update > self._burst_s:
            self._frozen = True  # the first batch is over: rates are measured from its end
        self.done += n
        if not self._frozen:
            self._ref = (now, self.done)
        self._last_update = now
        self.postfix = note
        if self._bar is not None:
            self._bar.update(n)
            self._bar.set_postfix_str(f"{note}  remaining ~{_format_s(self.remaining_s())}".strip(),
                                      refresh=False)
            return
        if not enabled():
            return
        finished = self.total is not None and self.done >= self.total
        if finished or now - self._last_line >= _STATE["interval_s"]:
            self._last_line = now
            logger.info("%s", self.line())

    def line(self) -> str:
        """One plain line: done/total, the note, elapsed and remaining time."""
        total = "?" if self.total is None else str(self.total)
        note = f"  {self.postfix}" if self.postfix else ""
        return (f"{self.desc}: {self.done}/{total} {self.unit}{note}  elapsed {_format_s(self.elapsed_s())}"
                f"  remaining ~{_format_s(self.remaining_s())}")

    def close(self) -> None:
        """End the bar (a plain final line is written by the last update)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
