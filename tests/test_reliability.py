"""What a user who tries to break the command line meets: one line and the right exit
code, never a traceback or a silent outcome."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest

from smcbayes.cli import main
from smcbayes.errors import FixedOutsideBoxWarning

REPO = Path(__file__).resolve().parents[1]
SLIP = REPO / "configs" / "verify-slip-2d.toml"
QUICK = ["--budget", "4", "--init", "3", "--polish", "0", "--fidelity", "1d", "--no-figures"]


def one_config(tmp: Path) -> Path:
    """The 2-D slip check reduced to its first configuration (a known-truth check: no data)."""
    head, _, rest = SLIP.read_text().partition("[[configuration]]")
    path = tmp / "one.toml"
    path.write_text(head + "[[configuration]]" + rest.split("[[configuration]]")[0])
    return path


def error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "Traceback" not in "\n".join(err)
    return err[-1]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small finished calibration started with explicit budget and init."""
    tmp = tmp_path_factory.mktemp("cal")
    out = tmp / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["calibrate", str(one_config(tmp)), "--out", str(out), *QUICK]) == 0
    return out


def test_out_naming_a_file_is_an_input_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "taken").write_text("x")
    assert main(["calibrate", str(one_config(tmp_path)), "--out", str(tmp_path / "taken"), *QUICK]) == 2
    assert "is a file" in error_line(capsys)


def test_resume_of_a_missing_or_foreign_folder_is_refused(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    config = one_config(tmp_path)
    assert main(["calibrate", str(config), "--out", str(tmp_path / "nope"), "--resume", *QUICK]) == 2
    assert "does not exist" in error_line(capsys)
    (tmp_path / "foreign").mkdir()
    assert main(["calibrate", str(config), "--out", str(tmp_path / "foreign"), "--resume", *QUICK]) == 2
    assert "holds no calibration run" in error_line(capsys)


def test_bare_resume_takes_the_runs_own_settings(run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Started with --budget 4 --init 3; a resume naming only a larger budget continues it,
    and one naming another init is refused."""
    config = run.parent / "one.toml"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["calibrate", str(config), "--out", str(run), "--resume", "--budget", "5",
                     "--fidelity", "1d", "--no-figures"]) == 0
    assert json.loads((run / "summary.json").read_text())["evaluations"] == 5
    assert main(["calibrate", str(config), "--out", str(run), "--resume", "--init", "4",
                 "--fidelity", "1d"]) == 2
    assert "--resume changes only --budget, --tolerance and --polish" in error_line(capsys)


def test_an_emptied_log_is_not_silently_recomputed(run: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    (copy / "evaluations.jsonl").write_text("")
    assert main(["calibrate", str(run.parent / "one.toml"), "--out", str(copy), "--resume",
                 "--fidelity", "1d"]) == 2
    assert "missing or empty" in error_line(capsys)


def test_a_calibration_whose_evaluations_all_failed_exits_1(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    config = one_config(tmp_path)
    code = main(["calibrate", str(config), "--out", str(tmp_path / "r"), "--budget", "2", "--init", "2",
                 "--no-figures", "--external", "false {params} {output}"])
    assert code == 1
    assert "every evaluation failed" in error_line(capsys)
    assert (tmp_path / "r" / "summary.json").is_file()


def test_a_directory_given_as_the_config_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    one_config(tmp_path)
    assert main(["calibrate", str(tmp_path), "--out", str(tmp_path / "r")]) == 2
    assert "is a directory" in (line := error_line(capsys)) and "one.toml" in line


def test_a_latin1_csv_is_not_called_a_press_export(tmp_path: Path) -> None:
    from smcbayes.data.readers.csv import read_csv
    from smcbayes.errors import DataError

    path = tmp_path / "f.csv"
    path.write_bytes("time_s,force_kN\n0,1\n1,2\n# Prüfung\n".encode("latin-1"))
    with pytest.raises(DataError, match="not UTF-8 text.*save it as UTF-8"):
        read_csv(path, "force_kN", "force")
    path.write_bytes("time_s,force_kN\n0,1\n".encode("utf-16"))
    with pytest.raises(DataError, match="UTF-16.*data.format = 'press'"):
        read_csv(path, "force_kN", "force")


def test_a_value_fixed_outside_its_search_bounds_is_said(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    from smcbayes.config import load_project
    from smcbayes.simulation.problem import build_problem

    with pytest.warns(FixedOutsideBoxWarning, match="m = 2.5 is fixed outside its search bounds 1-1.9"):
        build_problem(load_project(one_config(tmp_path)), tmp_path / "p", overrides={"m": 2.5}, fidelity="1d")
    assert main(["calibrate", str(one_config(tmp_path)), "--out", str(tmp_path / "r"), "--set", "m=2.5",
                 "--budget", "3", "--init", "2", "--fidelity", "1d", "--no-figures"]) == 0
    assert "warning: m = 2.5 is fixed outside its search bounds" in capsys.readouterr().err


def test_interrupted_calibration_names_the_resume_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    import smcbayes.surrogate.calibration as stage

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(stage, "calibrate", interrupted)
    config, out = one_config(tmp_path), tmp_path / "r"
    assert main(["calibrate", str(config), "--out", str(out), *QUICK]) == 130
    assert error_line(capsys).endswith(f"continue with: smcbayes calibrate {config} --out {out} "
                                       f"{' '.join(QUICK)} --resume")
