"""The common measured-curve type and the unit conversions of its readers.

Every reader returns :class:`Curve` objects in the package's edge units: time in s,
force in kN, displacement in mm.  The unit a file is written in is converted once, here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from smcbayes.errors import DataError

Array = NDArray[np.float64]

FORCE_UNITS: dict[str, float] = {
    "kN": 1.0, "N": 1e-3, "MN": 1e3, "daN": 1e-2,
    "tonne-force": 9.80665, "tf": 9.80665, "tonne": 9.80665, "t": 9.80665,
    "lbf": 4.4482216152605e-3,
}
"""kN per unit of force (tonne-force is the metric tonne; Moldflow writes 'tonne')."""

LENGTH_UNITS: dict[str, float] = {"mm": 1.0, "m": 1e3, "cm": 10.0, "um": 1e-3, "µm": 1e-3, "in": 25.4}
"""mm per unit of length."""

TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "min": 60.0}
"""s per unit of time."""

QUANTITY_UNITS: dict[str, tuple[str, dict[str, float]]] = {
    "force": ("kN", FORCE_UNITS),
    "displacement": ("mm", LENGTH_UNITS),
    "position": ("mm", LENGTH_UNITS),
}
"""quantity -> (edge unit, conversion table)."""


def unit_factor(unit: str, quantity: str, where: str) -> float:
    """Factor converting ``unit`` of ``quantity`` to the edge unit (kN, mm or s).

    Raises:
        DataError: unknown unit, naming ``where`` and the accepted units.
    """
    table = TIME_UNITS if quantity == "time" else QUANTITY_UNITS[quantity][1]
    key = unit.strip()
    for name, factor in table.items():
        if key == name or key.lower() == name.lower():
            return factor
    raise DataError(f"{where}: unit '{unit}' of {quantity} is not known; accepted: {', '.join(table)}")


def unit_from_column(column: str) -> str | None:
    """The unit a column name ends with (``force_kN`` -> ``kN``), or None."""
    head, sep, tail = column.rpartition("_")
    return tail if sep and head else None


@dataclass(frozen=True)
class Curve:
    """One measured (or synthetic) curve.

    Attributes:
        time_s: sample times (s), strictly increasing, shape ``(N,)``.
        values: samples in the edge unit of ``quantity`` (kN or mm), shape ``(N,)``.
        quantity: ``force``, ``displacement`` or ``position``.
        unit: the unit of ``values`` (``kN`` or ``mm``).
        source: the file the curve was read from.
    """

    time_s: Array
    values: Array
    quantity: str
    unit: str
    source: Path

    @property
    def name(self) -> str:
        """Quantity with unit, e.g. ``force_kN``."""
        return f"{self.quantity}_{self.unit}"

    @property
    def size(self) -> int:
        """Number of samples ``N``."""
        return int(self.time_s.size)

    @property
    def end_s(self) -> float:
        """Time of the last sample (s)."""
        return float(self.time_s[-1])

    def with_data(self, time_s: Array, values: Array) -> Curve:
        """Copy with new samples (same quantity, unit and source)."""
        return replace(self, time_s=np.asarray(time_s, float), values=np.asarray(values, float))

    def at(self, t: Array) -> Array:
        """Linear interpolation at ``t`` (s), holding the end values outside the range."""
        return np.interp(t, self.time_s, self.values)


def check_samples(path: Path, time_s: Array, values: Array, lines: Sequence[int],
                  time_column: str, value_column: str) -> None:
    """Reject curves a loss cannot use: too short, NaN/inf, non-increasing time.

    Args:
        path: the file (for the message).
        time_s, values: samples, shape ``(N,)``.
        lines: file line number (1-based) of each sample, to name rows in messages.
        time_column, value_column: column names for messages.

    Raises:
        DataError: one line naming the file, the row and column, and the fix.
    """
    if time_s.size < 2:
        raise DataError(f"{path}: {time_s.size} data row(s); a curve needs at least 2 "
                        "(is the file empty or cut short?)")
    for name, arr in ((time_column, time_s), (value_column, values)):
        bad = np.nonzero(~np.isfinite(arr))[0]
        if bad.size:
            raise DataError(f"{path}: row {lines[bad[0]]}, column '{name}': value is "
                            f"{arr[bad[0]]} (NaN or infinite); remove the row or fill the gap")
    step = np.nonzero(np.diff(time_s) <= 0)[0]
    if step.size:
        i = step[0] + 1
        kind = "duplicate" if time_s[i] == time_s[i - 1] else "decreasing"
        raise DataError(f"{path}: row {lines[i]}, column '{time_column}': {kind} time stamp "
                        f"({time_s[i]:g} after {time_s[i - 1]:g}); time must be strictly "
                        "increasing: sort or de-duplicate the file")
