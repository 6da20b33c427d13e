"""A resumed calibration takes the run's own settings (command line without CONFIG, and the
API); the budget and the tolerance may change, any other setting given must agree."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest

from smcbayes.api import calibrate
from smcbayes.cli import main
from smcbayes.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
SLIP = REPO / "configs" / "verify-slip-2d.toml"


def one_config(tmp: Path) -> Path:
    """The 2-D slip check reduced to its first configuration (a known-truth check: no data)."""
    head, _, rest = SLIP.read_text().partition("[[configuration]]")
    path = tmp / "one.toml"
    path.write_text(head + "[[configuration]]" + rest.split("[[configuration]]")[0])
    return path


def evaluations(run: Path) -> int:
    return json.loads((run / "summary.json").read_text())["evaluations"]


def last_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "Traceback" not in "\n".join(err)
    return err[-1]


@pytest.fixture
def started(tmp_path: Path) -> Path:
    """A finished 3-evaluation run started with explicit budget and init (not the table's)."""
    out = tmp_path / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["calibrate", str(one_config(tmp_path)), "--out", str(out), "--budget", "3",
                     "--init", "2", "--polish", "0", "--fidelity", "1d", "--no-figures"]) == 0
    return out


def test_resume_without_config_continues_with_the_runs_own_project_and_settings(
        started: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["calibrate", "--out", str(started), "--resume", "--budget", "4", "--no-figures"]) == 0
    out = capsys.readouterr().out
    assert "budget 4 (2 initial)" in out
    assert evaluations(started) == 4
    # the fidelity recorded in the run is kept; another one is refused
    assert main(["calibrate", "--out", str(started), "--resume", "--fidelity", "2d", "--no-figures"]) == 2
    assert "'fidelity'" in last_error(capsys)
    assert main(["calibrate", "--out", str(started), "--resume", "--init", "3"]) == 2
    line = last_error(capsys)
    assert line.startswith("smcbayes calibrate: error: --init 3") and "init = 2" in line


def test_config_may_be_left_out_only_on_resume_of_an_existing_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", "--out", str(tmp_path / "r")]) == 2
    assert "CONFIG" in (line := last_error(capsys)) and "only --resume" in line
    assert main(["calibrate", "--out", str(tmp_path / "nope"), "--resume"]) == 2
    assert "does not exist" in last_error(capsys)
    (tmp_path / "foreign").mkdir()
    assert main(["calibrate", "--out", str(tmp_path / "foreign"), "--resume"]) == 2
    assert "holds no calibration run" in last_error(capsys)


def test_api_resume_takes_the_runs_own_settings(tmp_path: Path) -> None:
    config, out = one_config(tmp_path), tmp_path / "api"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        calibrate(config, out, fidelity="1d", figures=False, budget=3, init=2, polish=0)
        result = calibrate(config, out, fidelity="1d", figures=False, resume=True, budget=4)
    assert result.summary["evaluations"] == 4
    assert result.summary["settings"]["init"] == 2
    with pytest.raises(ConfigError, match="init 3: the run in .* was started with init = 2; "
                                          "resume=True changes only budget"):
        calibrate(config, out, fidelity="1d", figures=False, resume=True, init=3)
