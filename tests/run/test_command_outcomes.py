"""Outcomes the command line states plainly: an output path that is a file, and the most
frequent reason when every evaluation of a calibration failed."""

from __future__ import annotations

from pathlib import Path

import pytest

from smcbayes.cli import main

REPO = Path(__file__).resolve().parents[2]
SLIP = REPO / "configs" / "verify-slip-2d.toml"


@pytest.mark.parametrize("command", [["simulate"], ["synth", "--seed", "1"]])
def test_out_naming_a_file_exits_2_naming_it(command: list[str], tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    taken = tmp_path / "taken"
    taken.write_text("keep me")
    code = main([command[0], str(SLIP), "--out", str(taken), *command[1:]])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].endswith(f"{taken}: is a file; --out names the output folder: choose another path "
                             "or move the file")
    assert taken.read_text() == "keep me"


def test_most_frequent_failure_counts_reasons_per_configuration() -> None:
    from smcbayes.commands.calibrate import most_frequent_failure

    info = {"config_ids": ["bar", "bar-2"], "failure_reasons": [
        {"index": 0, "reason": "bar: exited with 1: no licence; retry; "
                               "bar-2: exited with 1: no licence; retry"},
        {"index": 1, "reason": "bar: timed out after 60 s; bar-2: exited with 1: no licence; retry"},
    ]}
    assert most_frequent_failure(info) == (" (most often, 3 of 4 configuration runs: "
                                           "exited with 1: no licence; retry)")
    assert most_frequent_failure({"failure_reasons": []}) == ""


def test_all_failed_names_the_reason_once_and_the_log(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    code = main(["calibrate", str(SLIP), "--out", str(out), "--budget", "2", "--init", "2",
                 "--no-figures", "--external", "false {params} {output}"])
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 1
    assert "every evaluation failed (most often, 10 of 10 configuration runs: failed: external command " \
           "exited with 1" in line, line
    assert line.count("external command") == 1 and str(out / "evaluations.jsonl") in line
    assert (out / "summary.json").is_file()
