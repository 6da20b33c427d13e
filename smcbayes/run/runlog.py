"""The run directory's append-only evaluation log and atomic JSON files.

``evaluations.jsonl`` holds two kinds of JSON lines, each written, flushed and fsynced
before the next step:

- ``{"type": "round", "round": r, "kind": "init"|"bo"|"polish", "indices": [...], "unit":
  [[...]], "params": [[...]]}``: the candidates of a round (the initial design, a round of
  the Bayesian optimisation, one evaluation of the local search), logged before they are
  evaluated, so that a resumed run evaluates exactly the same points;
- ``{"type": "evaluation", "index": i, "round": r, "params": {name: value}, "errors":
  {config: kN^2}, "force_mse_kN2": {...}, "displacement_mse_mm2": {...}, "loss": L,
  "status": "ok"|"failed", "reason": str|null, "seconds": s}``: one finished evaluation.

A line cut short by a kill is dropped on reading and truncated on resume.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from smcbayes.errors import RunDirError

LOG_NAME = "evaluations.jsonl"


def clean(value: Any) -> Any:
    """JSON-safe copy: NaN and infinities become ``None`` (strict JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean(v) for v in value]
    if hasattr(value, "tolist"):
        return clean(value.tolist())
    return value


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as indented JSON atomically (temp file + rename)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    with tmp.open("w", encoding="utf-8") as fh:
        json.dump(clean(data), fh, indent=2)
        fh.write("\n")
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


@dataclass
class LogState:
    """What a log holds: round records by round, evaluation records by index."""

    rounds: dict[int, dict[str, Any]] = field(default_factory=dict)
    evaluations: dict[int, dict[str, Any]] = field(default_factory=dict)


class RunLog:
    """Append-only JSON-lines log of a run.

    Args:
        path: the log file (created if missing).
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def read(self, repair: bool = False) -> LogState:
        """Parse the log; a truncated last line is ignored (and cut off if ``repair``).

        Raises:
            RunDirError: a damaged line other than the last one (not JSON, not UTF-8, or a
                record with a field of the wrong type), named with its line number.
        """
        state = LogState()
        if not self.path.exists():
            return state
        raw = self.path.read_bytes()
        good_end = 0
        lines = raw.split(b"\n")
        for number, line in enumerate(lines, start=1):
            complete = number < len(lines)
            if not line.strip():
                good_end += len(line) + (1 if complete else 0)
                continue
            try:
                record = json.loads(line)
            except (json.JSONDecodeError, UnicodeDecodeError) as err:
                if complete:
                    kind = "not UTF-8" if isinstance(err, UnicodeDecodeError) else "not valid JSON"
                    raise RunDirError(f"{self.path}: line {number} is {kind}; the log is damaged: "
                                      "restore the file from a copy, or remove the line and rerun "
                                      "with --resume to evaluate it again") from None
                break
            if not complete:
                break  # parsed but without its newline: written partly, rewrite on resume
            good_end += len(line) + 1
            self._add(state, _checked(record, self.path, number))
        if repair and good_end < len(raw):
            with self.path.open("r+b") as fh:
                fh.truncate(good_end)
                fh.flush()
                os.fsync(fh.fileno())
        return state

    @staticmethod
    def _add(state: LogState, record: dict[str, Any]) -> None:
        kind = record.get("type")
        if kind == "round":
            state.rounds.setdefault(int(record["round"]), record)
        elif kind == "evaluation":
            state.evaluations.setdefault(int(record["index"]), record)

    def append(self, record: Mapping[str, Any]) -> None:
        """Append one record as a JSON line, flushed and fsynced."""
        line = json.dumps(clean(record), separators=(",", ":"))
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write(line + "\n")
            fh.flush()
            os.fsync(fh.fileno())


def _checked(record: Any, path: Path, number: int) -> dict[str, Any]:
    """``record`` if its fields have the types the log writes, else :class:`RunDirError`
    naming the line (a hand-edited or foreign file would otherwise fail far from here)."""
    def bad(what: str) -> RunDirError:
        return RunDirError(f"{path}: line {number}: {what}; the log is damaged: restore the file "
                           "from a copy, or remove the line and rerun with --resume")

    if not isinstance(record, dict) or record.get("type") not in ("round", "evaluation"):
        raise bad("not a round or evaluation record")
    key = "round" if record["type"] == "round" else "index"
    if not isinstance(record.get(key), int) or isinstance(record.get(key), bool):
        raise bad(f"'{key}' is not an integer")
    if record["type"] == "evaluation":
        loss = record.get("loss")
        if loss is not None and (isinstance(loss, bool) or not isinstance(loss, int | float)):
            raise bad(f"'loss' = {loss!r} is not a number")
    return record
