"""The append-only log: partial last lines, corrupt lines, duplicates, NaN."""

from __future__ import annotations

from pathlib import Path

import pytest

from smcbayes.errors import RunDirError
from smcbayes.run.runlog import RunLog


def test_partial_last_line_dropped_and_repaired(tmp_path: Path) -> None:
    log = RunLog(tmp_path / "log.jsonl")
    log.append({"type": "round", "round": 0, "indices": [0, 1]})
    log.append({"type": "evaluation", "index": 0, "round": 0, "loss": float("nan")})
    with log.path.open("a") as fh:
        fh.write('{"type": "evaluation", "index": 1, "ro')
    state = log.read()
    assert list(state.evaluations) == [0] and state.evaluations[0]["loss"] is None
    log.read(repair=True)
    log.append({"type": "evaluation", "index": 1, "round": 0, "loss": 2.0})
    state = log.read()
    assert sorted(state.evaluations) == [0, 1] and state.evaluations[1]["loss"] == 2.0


def test_complete_line_without_newline_is_rewritten(tmp_path: Path) -> None:
    log = RunLog(tmp_path / "log.jsonl")
    log.path.write_text('{"type": "evaluation", "index": 0, "round": 0, "loss": 1.0}')
    assert log.read(repair=True).evaluations == {}
    assert log.path.read_text() == ""


def test_corrupt_middle_line_is_an_error(tmp_path: Path) -> None:
    log = RunLog(tmp_path / "log.jsonl")
    log.path.write_text('{"type": "round", "round": 0}\nnot json\n{"type": "round", "round": 1}\n')
    with pytest.raises(RunDirError, match="line 2 is not valid JSON.*remove the line"):
        log.read()


def test_non_utf8_bytes_in_a_line_name_the_line(tmp_path: Path) -> None:
    log = RunLog(tmp_path / "log.jsonl")
    log.path.write_bytes(b'{"type": "round", "round": 0}\n{"type": "round", "round": 1, "x": "\xff"}\n'
                         b'{"type": "round", "round": 2}\n')
    with pytest.raises(RunDirError, match="line 2 is not UTF-8"):
        log.read()


@pytest.mark.parametrize("line", ['{"type": "evaluation", "index": 0, "round": 0, "loss": "abc"}',
                                  '{"type": "evaluation", "index": "0", "round": 0, "loss": 1.0}',
                                  '{"type": "note"}', '[1, 2]'])
def test_a_record_of_the_wrong_shape_names_the_line(tmp_path: Path, line: str) -> None:
    log = RunLog(tmp_path / "log.jsonl")
    log.path.write_text('{"type": "round", "round": 0}\n' + line + "\n")
    with pytest.raises(RunDirError, match="line 2"):
        log.read()


def test_first_record_of_an_index_wins(tmp_path: Path) -> None:
    log = RunLog(tmp_path / "log.jsonl")
    log.append({"type": "evaluation", "index": 3, "round": 1, "loss": 1.0})
    log.append({"type": "evaluation", "index": 3, "round": 1, "loss": 5.0})
    assert log.read().evaluations[3]["loss"] == 1.0
