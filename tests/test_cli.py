"""Command line: bad input exits with code 2 and one line naming the key and what is
accepted; every subcommand has --help; ``simulate`` writes curves and a figure."""

from __future__ import annotations

from pathlib import Path

import pytest

from smcbayes.cli import build_parser, main

PROJECT = """\
name = "cli-test"

[parameters.n]
value = 0.4

[[configuration]]
id = "bar"
charge = { shape = "bar", coverage_pct = 60.0, mass_g = 388.0 }
press = { speed_mm_s = 0.3, force_limit_kN = 1400.0 }

[[configuration]]
id = "centre"
charge = { shape = "center", coverage_pct = 60.0, mass_g = 396.0 }
press = { speed_mm_s = 1.1 }
"""


def write(tmp_path: Path, old: str = "", new: str = "") -> Path:
    """The test project with ``old`` replaced by ``new`` (which must occur)."""
    assert old in PROJECT
    path = tmp_path / "project.toml"
    path.write_text(PROJECT.replace(old, new, 1) if old else PROJECT, encoding="utf-8")
    return path


def run_error(capsys: pytest.CaptureFixture[str], args: list[str]) -> str:
    """Run the CLI expecting exit code 2 and exactly one line on stderr; returns it."""
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize(("old", "new", "expected"), [
    ('shape = "bar"', 'shape = "ring"', ["shape", "'ring'", "'center'", "'bar'"]),
    ("coverage_pct = 60.0, mass_g = 388", "coverage_pct = 0.0, mass_g = 388",
     ["coverage_pct", "greater than 0"]),
    ("coverage_pct = 60.0, mass_g = 388", "coverage_pct = 120.0, mass_g = 388",
     ["coverage_pct", "less than or equal to 100"]),
    ("speed_mm_s = 0.3", "speed_mm_s = -0.3", ["speed_mm_s", "greater than 0"]),
    ("force_limit_kN = 1400.0", "force_limit_kN = 0.0", ["force_limit_kN", "greater than 0"]),
    ("force_limit_kN = 1400.0", "force_limit_kN = -5.0", ["force_limit_kN", "greater than 0"]),
    ("value = 0.4", "value = -1.0", ["parameters.n", "n=-1", "physical range"]),
    ("value = 0.4", "value = 0.0", ["parameters.n", "n=0", "physical range"]),
    ("press = { speed_mm_s = 0.3, force_limit_kN = 1400.0 }", "press = { force_limit_kN = 1400.0 }",
     ["speed_mm_s", "missing"]),
    ("speed_mm_s = 0.3", "sped_mm_s = 0.3", ["sped_mm_s", "did you mean 'speed_mm_s'", "accepted here"]),
    ("coverage_pct = 60.0, mass_g = 388", "coverage = 60.0, mass_g = 388",
     ["coverage", "did you mean 'coverage_pct'"]),
    ('[parameters.n]', '[parameters.tau_c_Mpa]', ["tau_c_Mpa", "did you mean 'tau_c_MPa'"]),
], ids=["shape", "coverage-0", "coverage-120", "negative-speed", "force-0", "force-negative",
        "n-negative", "n-zero", "missing-speed", "misspelt-speed", "misspelt-coverage", "misspelt-parameter"])
def test_bad_config_exits_2_with_one_line(old: str, new: str, expected: list[str], tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    line = run_error(capsys, ["simulate", str(write(tmp_path, old, new)), "--out", str(tmp_path / "o")])
    for text in expected:
        assert text in line, line
    if "parameters" not in line:  # schema errors also name the file
        assert str(tmp_path / "project.toml") in line


@pytest.mark.parametrize(("extra", "expected"), [
    (["--set", "n=-1"], ["--set", "n=-1", "physical range"]),
    (["--set", "n=0"], ["n=0", "physical range"]),
    (["--set", "tau_c_Mpa=0.1"], ["tau_c_Mpa", "did you mean 'tau_c_MPa'"]),
    (["--set", "n"], ["--set", "name=value"]),
    (["--set", "n=abc"], ["'abc'", "not a number"]),
    (["--effect", "compresibility"], ["compresibility", "did you mean 'compressibility'", "available"]),
    (["--only", "baar"], ["baar", "did you mean 'bar'"]),
])
def test_bad_options_exit_2_with_one_line(extra: list[str], expected: list[str], tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    line = run_error(capsys, ["simulate", str(write(tmp_path)), "--out", str(tmp_path / "o"), *extra])
    for text in expected:
        assert text in line, line


def test_missing_config_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = run_error(capsys, ["simulate", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")])
    assert "nope.toml" in line and "not found" in line


def _subcommands() -> list[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return sorted(sub.choices)


@pytest.mark.parametrize("command", _subcommands())
def test_help_works_for_every_subcommand(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main([command, "--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: smcbayes " + command)


def test_top_level_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    for command in ("simulate", "demo"):
        assert command in out


def test_simulate_writes_curves_and_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    code = main(["simulate", str(write(tmp_path)), "--out", str(out), "--only", "bar",
                 "--set", "tau_c_MPa=0.1", "--effect", "press_compliance"])
    assert code == 0, capsys.readouterr().err
    text = (out / "bar.csv").read_text(encoding="utf-8").splitlines()
    assert text[0] == "time_s,gap_mm,displacement_mm,force_kN,fill_fraction,solid_fraction,phase"
    assert len(text) - 1 >= 200
    assert text[1].endswith(",contact") and text[-1].endswith(",force_control")
    assert (out / "simulation.png").stat().st_size > 0
    assert not (out / "centre.csv").exists()
    assert "press_compliance" in capsys.readouterr().out


def test_simulate_2d_draws_the_flow_front_and_the_solid_fraction(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    project = write(tmp_path, 'name = "cli-test"\n', 'name = "cli-test"\n\n[solver]\ncells_2d = 16\n')
    out = tmp_path / "out"
    code = main(["simulate", str(project), "--out", str(out), "--only", "centre", "--fidelity", "2d",
                 "--effect", "compressibility"])
    assert code == 0, capsys.readouterr().err
    figure = out / "flow_front_centre.svg"
    assert figure.stat().st_size > 0
    svg = figure.read_text(encoding="utf-8")
    assert "solid fraction" in svg and "filled area" in svg


def test_every_option_with_a_default_shows_it_in_help() -> None:
    """`--help` names the default of every option that has one (settings that come from a
    project table name the table's default)."""
    import argparse

    from smcbayes.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = []
    for name, command in sub.choices.items():
        text = " ".join(command.format_help().split())
        for action in command._actions:
            if not action.option_strings or action.help == argparse.SUPPRESS or action.dest == "help":
                continue
            helptext = " ".join(command._get_formatter()._expand_help(action).split())
            trivial = action.default is None or action.default is False or action.default == []
            if not trivial and "default" not in helptext:
                missing.append(f"{name} {action.option_strings[0]}")
            assert helptext in text
    assert not missing, missing


@pytest.mark.parametrize("command", ["posterior", "diagnose"])
def test_interrupted_later_stage_says_rerun_the_same_command(command: str, tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    import importlib

    def interrupted(args: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib.import_module(f"smcbayes.commands.{command}"), "run", interrupted)
    extra = ["--out", str(tmp_path / "d")] if command == "diagnose" else []
    assert main([command, str(tmp_path), *extra]) == 130
    line = capsys.readouterr().err.strip()
    assert line == (f"smcbayes {command}: interrupted; rerun the same command to continue "
                    "(its finished forward runs are reused)")
