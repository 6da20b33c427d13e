"""The press's own export (Wickert controller), as recorded in the thesis trials.

Format: UTF-16-LE text (a byte-order mark is optional), ``;`` separated, decimal commas.
Row 1 names the columns, row 2 gives their units, then one row per sample whose first
column is a time stamp ``dd.mm.yyyy HH:MM:SS.ffffff``.  The ram position is in column
``dbPr\\diIstPos`` and the total press force in ``dbPr\\diIstKraftGes`` by default.
The whole recording is returned (idle states included); cutting it into the closing curve
and the hold is done by :mod:`smcbayes.data.preprocess`.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from smcbayes.data.curve import Curve, check_samples, unit_factor
from smcbayes.errors import DataError

FORCE_COLUMN = "dbPr\\diIstKraftGes"
POSITION_COLUMN = "dbPr\\diIstPos"
STAMP_FORMAT = "%d.%m.%Y %H:%M:%S.%f"
_EPOCH = datetime(2000, 1, 1)  # naive stamps: differences only, no time zone involved


@dataclass(frozen=True)
class PressRecord:
    """A whole press recording.

    Attributes:
        force: total press force (kN) vs time from the first stamp (s), shape ``(N,)``.
        position: ram position (mm, the controller's sign) vs the same times.
    """

    force: Curve
    position: Curve


def _decode(path: Path) -> str:
    if not path.is_file():
        raise DataError(f"{path}: file not found; check the path, data_dir or --data-dir")
    raw = path.read_bytes()
    if not raw.strip(b"\x00 \r\n\t\xff\xfe"):
        raise DataError(f"{path}: file is empty; expected a press export with header, units "
                        "and data rows")
    if len(raw) % 2 or b"\x00" not in raw[:400]:
        raise DataError(f"{path}: not UTF-16-LE text; for a plain CSV set data.format = 'csv'")
    try:
        return raw.decode("utf-16" if raw[:2] == b"\xff\xfe" else "utf-16-le")
    except UnicodeDecodeError:
        raise DataError(f"{path}: not UTF-16-LE text; for a plain CSV set data.format = 'csv'") from None


def _number(cell: str, path: Path, line: int, column: str) -> float:
    try:
        return float(cell.strip().replace(".", "").replace(",", ".") if "," in cell else cell)
    except ValueError:
        raise DataError(f"{path}: row {line}, column '{column}': {cell!r} is not a number; "
                        "fix or remove the row") from None


def read_press(path: str | Path, force_column: str | None = None,
               position_column: str | None = None, force_unit: str | None = None,
               position_unit: str | None = None) -> PressRecord:
    """Read force and ram position from a press export.

    Args:
        path: the export file.
        force_column, position_column: column names (defaults: the controller's).
        force_unit, position_unit: override the units row (e.g. ``N``, ``mm``).

    Raises:
        DataError: one line naming the file, the row or column, and the fix.
    """
    path = Path(path)
    fcol, pcol = force_column or FORCE_COLUMN, position_column or POSITION_COLUMN
    lines = [(i + 1, ln) for i, ln in enumerate(_decode(path).splitlines()) if ln.strip()]
    if len(lines) < 2:
        raise DataError(f"{path}: needs a header row, a units row and data rows; "
                        f"found {len(lines)} row(s)")
    header = [h.strip() for h in lines[0][1].split(";")]
    units = [u.strip() for u in lines[1][1].split(";")]
    for col in (fcol, pcol):
        if col not in header:
            raise DataError(f"{path}: missing column '{col}'; columns found: {', '.join(header)}; "
                            "set data.force_column / data.displacement_column")
    fi, pi = header.index(fcol), header.index(pcol)
    rows = lines[2:]
    stamps, force, pos = np.empty(len(rows)), np.empty(len(rows)), np.empty(len(rows))
    for r, (line, text) in enumerate(rows):
        cells = text.split(";")
        if len(cells) < len(header):
            raise DataError(f"{path}: row {line} has {len(cells)} cells, the header {len(header)}; "
                            "the file is cut short or mis-separated")
        try:
            stamps[r] = (datetime.strptime(cells[0].strip(), STAMP_FORMAT) - _EPOCH).total_seconds()
        except ValueError:
            raise DataError(f"{path}: row {line}, column '{header[0]}': {cells[0]!r} is not a "
                            "time stamp dd.mm.yyyy HH:MM:SS.ffffff") from None
        force[r] = _number(cells[fi], path, line, fcol)
        pos[r] = _number(cells[pi], path, line, pcol)
    numbers = [n for n, _ in rows]
    check_samples(path, stamps, force, numbers, header[0], fcol)
    check_samples(path, stamps, pos, numbers, header[0], pcol)
    t = stamps - stamps[0]
    ff = unit_factor(force_unit or _unit(units, fi, path, fcol), "force", f"{path}: column '{fcol}'")
    pf = unit_factor(position_unit or _unit(units, pi, path, pcol), "position",
                     f"{path}: column '{pcol}'")
    return PressRecord(Curve(t, force * ff, "force", "kN", path),
                       Curve(t, pos * pf, "position", "mm", path))


def _unit(units: list[str], i: int, path: Path, column: str) -> str:
    unit = units[i].strip("[]() ") if i < len(units) else ""
    if not unit:
        raise DataError(f"{path}: units row gives no unit for column '{column}'; "
                        "set data.force_unit / data.displacement_unit")
    return unit


def write_press(path: str | Path, start: datetime, time_s: np.ndarray, force_kN: np.ndarray,
                position_mm: np.ndarray) -> None:
    """Write a press export (for tests and examples): stamp, position (mm), force (kN)."""
    rows = [f"Zeit;{POSITION_COLUMN};{FORCE_COLUMN}", ";mm;kN"]
    for t, x, f in zip(time_s, position_mm, force_kN, strict=False):
        stamp = (start + timedelta(seconds=float(t))).strftime(STAMP_FORMAT)
        rows.append(";".join((stamp, f"{x:.6f}".replace(".", ","), f"{f:.6f}".replace(".", ","))))
    Path(path).write_bytes(("\r\n".join(rows) + "\r\n").encode("utf-16-le"))
