"""Plain CSV curves: a header row, comma-separated numbers, named columns."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from smcbayes.errors import DataError

Array = NDArray[np.float64]


def read_columns(path: str | Path, columns: tuple[str, str]) -> tuple[Array, Array]:
    """Read two named numeric columns; the first must be strictly increasing (time).

    Raises:
        DataError: one line naming the file, the row or column, and the fix.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file not found (check data_dir or --data-dir)")
    with path.open(newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    if len(rows) < 3:
        raise DataError(f"{path}: needs a header row and at least 2 data rows")
    header = [h.strip() for h in rows[0]]
    idx = []
    for col in columns:
        if col not in header:
            raise DataError(f"{path}: missing column '{col}'; columns found: {', '.join(header)}")
        idx.append(header.index(col))
    out = np.empty((len(rows) - 1, 2))
    for r, row in enumerate(rows[1:], start=2):
        for c, i in enumerate(idx):
            try:
                out[r - 2, c] = float(row[i])
            except (ValueError, IndexError):
                cell = row[i] if i < len(row) else ""
                raise DataError(f"{path}: row {r}, column '{columns[c]}': {cell!r} is not a number") from None
            if not np.isfinite(out[r - 2, c]):
                raise DataError(f"{path}: row {r}, column '{columns[c]}': value is {cell_text(row, i)}")
    bad = np.nonzero(np.diff(out[:, 0]) <= 0)[0]
    if bad.size:
        raise DataError(f"{path}: row {bad[0] + 3}: '{columns[0]}' is not strictly increasing "
                        "(duplicate or decreasing time stamp); sort or de-duplicate the file")
    return out[:, 0], out[:, 1]


def cell_text(row: list[str], i: int) -> str:
    """The raw text of a cell, for messages."""
    return row[i] if i < len(row) else "(empty)"
