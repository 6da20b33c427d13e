"""``smcbayes diagnose`` on the command line: bad input and a calibrate -> diagnose chain."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from smcbayes.cli import main
from smcbayes.config import load_project
from smcbayes.diagnose.synthetic import make_case

from .conftest import IDS, NOISE, REPO, coarse


def one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def test_missing_run_dir_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["diagnose", str(tmp_path / "nope"), "--out", str(tmp_path / "d")]) == 2
    assert "run directory not found" in one_line_error(capsys)


def test_not_a_run_dir_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["diagnose", str(tmp_path), "--out", str(tmp_path / "d")]) == 2
    assert "not a calibration run directory" in one_line_error(capsys)


def test_unknown_effect_suggests_the_closest(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["diagnose", str(tmp_path), "--effects", "heating,press_complience", "--out",
                 str(tmp_path / "d")])
    assert code == 2
    err = one_line_error(capsys)
    assert "unknown effect 'press_complience'" in err and "did you mean 'press_compliance'" in err


def test_calibrate_then_diagnose(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = coarse(load_project(REPO / "configs" / "thesis.toml"))
    make_case(source, IDS, "press_compliance", NOISE, 7, tmp_path / "data")
    run_dir, out = tmp_path / "run", tmp_path / "diag"
    assert main(["calibrate", str(tmp_path / "data" / "project.toml"), "--out", str(run_dir),
                 "--budget", "6", "--init", "5", "--seed", "0", "--no-figures"]) == 0
    assert main(["diagnose", str(run_dir), "--effects", "press_compliance,heating", "--population", "6",
                 "--generations", "1", "--holdout", "60-bar-07", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["decision"]["best"] == "press_compliance"
    assert "press_compliance explains the gap" in printed
    with (out / "ranking.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["effect"] for r in rows][0] == "press_compliance" and len(rows) == 2
    assert all(r["evidence"] for r in rows)
    assert "<- named" in next(line for line in printed.splitlines() if "press_compliance" in line
                              and line.lstrip().startswith("1"))
    models = summary["shrink"]["models"]
    assert models["press_compliance"]["holdout"]["shrink_pct"] > 50.0
    for name in ("heatmap", "phase_rmse", "before_after"):
        assert (out / "figures" / f"{name}.png").is_file() and (out / "figures" / f"{name}.svg").is_file()
