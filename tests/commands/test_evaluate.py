"""``smcbayes evaluate``: per-configuration RMSE table and global loss."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from smcbayes.cli import main

REPO = Path(__file__).resolve().parents[2]
REAL_DATA = REPO / ".." / "shared" / "data" / "thesis-press"
THESIS_TOML = REPO / "configs" / "thesis.toml"


def _rows(out: str) -> dict[str, list[str]]:
    return {line.split()[0]: line.split()[1:] for line in out.splitlines()
            if re.match(r"^\d\d-(bar|center)-\d\d ", line)}


def test_evaluate_real_data_at_the_default_point(capsys: pytest.CaptureFixture[str]) -> None:
    if not REAL_DATA.is_dir():
        pytest.skip("thesis-press data folder not present")
    assert main(["evaluate", str(THESIS_TOML)]) == 0
    out = capsys.readouterr().out
    rows = _rows(out)
    assert len(rows) == 9 and "80-center-03" not in rows
    for cells in rows.values():
        assert float(cells[0]) > 0 and float(cells[1]) > 0  # full and clipped force RMSE (kN)
    assert "global loss L" in out and "clipped at flow stop" in out


def test_evaluate_synthetic_data_at_the_truth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["synth", str(THESIS_TOML), "--truth", "n=0.3", "--noise-kN", "10", "--seed", "2",
                 "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "project.toml"), "--set", "n=0.3"]) == 0
    rows = _rows(capsys.readouterr().out)
    assert len(rows) == 9
    for cells in rows.values():
        assert 5.0 < float(cells[0]) < 15.0  # about the 10 kN noise (interpolated, plus a floor)


def test_evaluate_without_data_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", str(THESIS_TOML), "--data-dir", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "not found" in err
