"""Plain CSV curves: one header row, then numbers, columns chosen by name.

Comma, semicolon and tab separators are recognised from the header; lines starting with
``#`` are comments.  Units come from the column name (``force_kN``, ``displacement_m``)
unless given explicitly, and are converted to kN / mm.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from smcbayes.data.curve import Curve, check_samples, unit_factor, unit_from_column
from smcbayes.errors import DataError
from smcbayes.forward.result import PHASE_NAMES, SimulationResult

Array = NDArray[np.float64]


def _not_utf8(path: Path, raw: bytes) -> str:
    """Why a file is not UTF-8 text, and the fix: a UTF-16 press export (byte-order mark or
    NUL bytes between ASCII characters) wants ``data.format = 'press'``; other text (an
    8-bit code page such as Latin-1 or Windows-1252) wants saving as UTF-8."""
    head = raw[:4096]
    if head.startswith((b"\xff\xfe", b"\xfe\xff")) or head.count(b"\x00") > len(head) // 4:
        return f"{path}: UTF-16 text, as the press exports it; set data.format = 'press'"
    return (f"{path}: not UTF-8 text (an 8-bit code page such as Latin-1 or Windows-1252?); "
            "save it as UTF-8")


def _open_rows(path: Path) -> list[tuple[int, list[str]]]:
    """Non-empty, non-comment rows with their 1-based line numbers."""
    if not path.is_file():
        raise DataError(f"{path}: file not found; check the path, data_dir or --data-dir")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DataError(_not_utf8(path, raw)) from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines())
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise DataError(f"{path}: file is empty; expected a header row and data rows")
    header = lines[0][1]
    delimiter = max((",", ";", "\t"), key=header.count)
    reader = csv.reader([line for _, line in lines], delimiter=delimiter)
    return [(n, [cell.strip() for cell in row]) for (n, _), row in zip(lines, reader, strict=False)]


def read_csv(path: str | Path, value_column: str, quantity: str, time_column: str = "time_s",
             unit: str | None = None, time_unit: str | None = None) -> Curve:
    """Read one curve from a CSV file.

    Args:
        path: the file.
        value_column: column of the values, e.g. ``force_kN``.
        quantity: ``force`` or ``displacement`` (decides the edge unit, kN or mm).
        time_column: column of the time stamps.
        unit: unit of ``value_column``; default: the suffix of its name.
        time_unit: unit of the time column; default: its suffix, else s.

    Returns:
        The curve in s and kN (force) or mm (displacement), shape ``(N,)`` each.

    Raises:
        DataError: one line naming the file, the row or column, and the fix.
    """
    path = Path(path)
    rows = _open_rows(path)
    header = rows[0][1]
    idx = []
    for col in (time_column, value_column):
        if col not in header:
            raise DataError(f"{path}: missing column '{col}'; columns found: {', '.join(header)}; "
                            "name the column in the config (data.time_column, data.force_column, "
                            "data.displacement_column)")
        idx.append(header.index(col))
    if len(rows) == 1:
        raise DataError(f"{path}: header only, no data rows")
    out = np.empty((len(rows) - 1, 2))
    for r, (line, row) in enumerate(rows[1:]):
        for c, i in enumerate(idx):
            cell = row[i] if i < len(row) else ""
            try:
                out[r, c] = float(cell)
            except ValueError:
                name = (time_column, value_column)[c]
                raise DataError(f"{path}: row {line}, column '{name}': {cell!r} is not a number; "
                                "fix or remove the row (decimal point, not comma)") from None
    check_samples(path, out[:, 0], out[:, 1], [n for n, _ in rows[1:]], time_column, value_column)
    vunit = unit or unit_from_column(value_column)
    if vunit is None:
        raise DataError(f"{path}: column '{value_column}' names no unit; set data.force_unit "
                        "or data.displacement_unit (e.g. 'kN', 'mm')")
    tunit = time_unit or unit_from_column(time_column) or "s"
    where = f"{path}: column '{value_column}'"
    factor = unit_factor(vunit, quantity, where)
    tfactor = unit_factor(tunit, "time", f"{path}: column '{time_column}'")
    edge = "kN" if quantity == "force" else "mm"
    return Curve(out[:, 0] * tfactor, out[:, 1] * factor, quantity, edge, path)


def read_columns(path: str | Path, columns: tuple[str, str]) -> tuple[Array, Array]:
    """Two named numeric columns ``(time, value)`` as read, without unit conversion."""
    path = Path(path)
    curve = read_csv(path, columns[1], "force", time_column=columns[0], unit="kN", time_unit="s")
    return curve.time_s, curve.values


def write_csv(path: str | Path, time_s: Array, values: Array, value_column: str,
              digits: int = 6) -> None:
    """Write ``time_s,<value_column>`` rows (used for synthetic data and fixtures)."""
    path = Path(path)
    with path.open("w", encoding="utf-8", newline="") as fh:
        fh.write(f"time_s,{value_column}\n")
        for t, v in zip(time_s, values, strict=False):
            fh.write(f"{t:.{digits}g},{v:.{digits}g}\n")


def write_curves(result: SimulationResult, row: int, path: Path) -> None:
    """One CSV of a simulated configuration: time, gap, displacement, force, fill, phase."""
    cols = result.row(row)
    names = ("time_s", "gap_mm", "displacement_mm", "force_kN", "fill_fraction", "solid_fraction")
    with path.open("w", encoding="utf-8") as fh:
        fh.write(",".join(names) + ",phase\n")
        for i in range(cols["time_s"].size):
            values = ",".join(f"{cols[n][i]:.9g}" for n in names)
            fh.write(f"{values},{PHASE_NAMES[int(cols['phase'][i])]}\n")
