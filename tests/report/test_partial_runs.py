"""Reports of partial or damaged run directories: missing stages are omitted, never fatal."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from smcbayes.cli import main
from smcbayes.errors import ConfigError
from smcbayes.report import write_report

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HTML checker of these tests
from htmlcheck import PLACEHOLDER, external_references, parse_page

PROJECT = {
    "name": "tiny",
    "configuration": [
        {
            "id": "bar-03",
            "role": "train",
            "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 388.0},
            "press": {"speed_mm_s": 0.3},
        }
    ],
}


def fake_run(tmp_path: Path) -> Path:
    """A run directory with the calibration's config.json and summary.json only (no figures)."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(
        json.dumps({"project": PROJECT, "seed": 3, "budget": 5}), encoding="utf-8"
    )
    summary = {
        "best_loss_kN2": 12.5,
        "best_index": 2,
        "evaluations": 5,
        "failures": 0,
        "best_params": {
            "n": {"value": 0.31, "unit": "-", "fixed": False},
            "B_Pa_s": {"value": 2.0e4, "unit": "Pa s", "fixed": True},
        },
        "best_errors_kN2": {"bar-03": 12.5},
        "settings": {"seed": 3, "budget": 5},
        "loss": {"w_force": 1.0, "w_displacement": 0.0, "clip": "none"},
    }
    (run / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    return run


def sections_of(run: Path) -> list[str]:
    return parse_page((run / "report.html").read_text(encoding="utf-8")).sections


def test_calibration_only_run_has_no_posterior_or_diagnosis(tmp_path: Path) -> None:
    run = fake_run(tmp_path)
    paths = write_report(run)
    assert [p.name for p in paths] == ["report.html", "report.md"]
    assert sections_of(run) == ["data", "calibration", "reproducibility"]
    page = (run / "report.html").read_text(encoding="utf-8")
    assert "RMSE" in page and ">3.54<" in page  # sqrt(12.5) kN from the recorded error
    assert "Pa s" in page and "B_Pa_s" in page
    md = (run / "report.md").read_text(encoding="utf-8")
    assert "## Posterior" not in md and "## Sim-to-real" not in md
    assert not PLACEHOLDER.search(md)


def test_damaged_stage_summaries_are_skipped_or_tolerated(tmp_path: Path) -> None:
    run = fake_run(tmp_path)
    (run / "posterior").mkdir()
    (run / "posterior" / "summary.json").write_text(
        '{"parameters": [{"name": "n"}]}', encoding="utf-8"
    )
    (run / "diagnose").mkdir()
    (run / "diagnose" / "summary.json").write_text("{ not json", encoding="utf-8")
    write_report(run)
    # the unreadable diagnosis is named as incomplete, not silently dropped
    assert sections_of(run) == ["data", "calibration", "posterior", "incomplete", "reproducibility"]
    facts = parse_page((run / "report.html").read_text(encoding="utf-8"))
    assert external_references(facts) == [] and facts.img_src == []


def test_diagnosis_in_another_folder(tmp_path: Path) -> None:
    run = fake_run(tmp_path)
    other = tmp_path / "diag"
    other.mkdir()
    (other / "summary.json").write_text(
        json.dumps(
            {
                "where": {"verdict": "the misfit is late in the closing"},
                "seed": 4,
                "decision": {"best": None, "statement": "no effect explains the gap beyond noise"},
            }
        ),
        encoding="utf-8",
    )
    write_report(run, ("html",), other)
    assert sections_of(run) == ["data", "calibration", "diagnosis", "reproducibility"]
    assert not (run / "report.md").exists()
    text = (run / "report.html").read_text(encoding="utf-8")
    assert "The misfit is late in the closing" in text and "diagnosis 4" in text


def test_not_a_run_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError, match="not a calibration run directory"):
        write_report(tmp_path)
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "smcbayes calibrate" in err


def test_cli_markdown_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = fake_run(tmp_path)
    assert main(["report", str(run), "--format", "md"]) == 0
    assert (run / "report.md").is_file() and not (run / "report.html").exists()
    assert "report.md" in capsys.readouterr().out


def test_interval_share_of_the_search_range() -> None:
    from smcbayes.report.sections_stages import interval_share

    ranges = {"B_Pa_s": (1e3, 1e5, True), "n": (0.2, 0.6, False)}
    assert interval_share({"name": "B_Pa_s", "q05": 1e3, "q95": 1e4}, ranges) == pytest.approx(0.5)
    assert interval_share({"name": "n", "q05": 0.3, "q95": 0.4}, ranges) == pytest.approx(0.25)
    assert interval_share({"name": "m", "q05": 1.1, "q95": 1.2}, ranges) != interval_share(
        {"name": "m", "q05": 1.1, "q95": 1.2}, ranges
    )  # unknown range: NaN


def test_recorded_command_lines_are_shown_with_their_folder(tmp_path: Path) -> None:
    """The report shows the command lines each stage recorded, after a `cd` to the folder
    they ran in (their paths are relative to it), and they parse as smcbayes commands."""
    import shlex

    from smcbayes.cli import build_parser
    from smcbayes.run import RunDir

    run = fake_run(tmp_path)
    argv = ["smcbayes", "calibrate", "p.toml", "--out", "run", "--data-dir", "data", "--set", "n=0.3"]
    RunDir(run).record_command("calibrate", argv)
    RunDir(run).record_command("posterior", ["smcbayes", "posterior", "run", "--walkers", "8"])
    write_report(run, ("md",))
    md = (run / "report.md").read_text(encoding="utf-8")
    block = md.split("```\n")[-2].strip().splitlines()
    assert block[0] == f"cd {shlex.quote(str(Path.cwd()))}"
    parsed = [build_parser().parse_args(shlex.split(line)[1:]) for line in block[1:]]
    assert [a.command for a in parsed] == ["calibrate", "posterior"]
    assert parsed[0].data_dir == "data" and parsed[0].set == ["n=0.3"] and parsed[1].walkers == 8


def test_an_interrupted_stage_is_named_not_dropped(tmp_path: Path) -> None:
    """A posterior stage that started and never finished gets its own section with the
    command that completes it."""
    from smcbayes.run import RunDir

    run = fake_run(tmp_path)
    RunDir(run).begin_stage("posterior", {"seed": 0})
    assert RunDir(run).stage_state("posterior") == "interrupted"
    write_report(run, ("md",))
    md = (run / "report.md").read_text(encoding="utf-8")
    assert "## Incomplete stages" in md and f"smcbayes posterior {run}" in md
    assert "## Posterior" not in md


@pytest.mark.parametrize(("correction", "expected"), [
    ({"enabled": True, "evaluations": 671, "k_hat": 0.06, "ess": 512.0, "reliable": True,
      "settled": True}, "can be trusted"),
    ({"enabled": True, "evaluations": 6000, "k_hat": 0.9, "ess": 20.0, "reliable": False,
      "settled": False}, "unreliable (k-hat above 0.7)"),
])
def test_posterior_section_states_the_importance_correction(tmp_path: Path, correction: dict,
                                                            expected: str) -> None:
    text = posterior_report_text(tmp_path, {"correction": correction})
    assert f"{correction['evaluations']} forward runs" in text and expected in text


def posterior_report_text(tmp_path: Path, extra: dict) -> str:
    """Markdown report of a fake run whose posterior summary holds ``extra``."""
    run = fake_run(tmp_path)
    (run / "posterior").mkdir()
    summary = {"parameters": [{"name": "n", "r_hat": 1.01, "ess": 512.0}], **extra}
    (run / "posterior" / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    write_report(run, formats=("md",))
    return next(run.glob("report*.md")).read_text(encoding="utf-8")


@pytest.mark.parametrize(("budget", "expected", "absent"), [
    ({"n_eff_total": 91.0, "n_eff_sandwich": 91.0, "n_eff_residual": 107.5},
     "the smaller of two estimates", "unavailable"),
    ({"n_eff_total": 107.5, "n_eff_sandwich": None, "n_eff_residual": 107.5},
     "the sandwich estimate was unavailable", "the smaller of two"),
    ({"n_eff_total": 107.5, "n_eff_residual": 107.5}, "from the residuals' autocorrelation)", "unavailable"),
])
def test_posterior_section_states_how_n_eff_was_estimated(tmp_path: Path, budget: dict, expected: str,
                                                          absent: str) -> None:
    text = posterior_report_text(tmp_path, {"effective_points": budget})
    assert absent not in text
    assert "Effective number of independent points in the likelihood" in text and expected in text


@pytest.mark.parametrize(("extra", "sampled", "pooled"), [
    ({"emulator_spread": {"functions": 4, "max_quantile_shift": 0.31, "pooled": True},
      "settings": {"functions": 0}}, "the GP mean and 4 GP sample functions, pooled", True),
    ({"emulator_spread": {"functions": 32, "max_quantile_shift": 0.08, "pooled": True, "pooled_shift": 0.065},
      "settings": {"functions": 0}, "active_learning": {"kind": "curves"}},
     "sampled by importance on the emulator (no forward run, pooled with 32 GP sample functions' posteriors",
     True),
    ({"emulator_spread": {"functions": 4, "max_quantile_shift": 0.04, "pooled": False},
      "settings": {"functions": 0}}, "the GP mean,", False),
    ({"settings": {"functions": 8}}, "8 GP sample functions,", False),
])
def test_posterior_section_states_what_was_sampled_and_the_spread(tmp_path: Path, extra: dict, sampled: str,
                                                                  pooled: bool) -> None:
    text = " ".join(posterior_report_text(tmp_path, extra).split())
    assert sampled in text
    spread = extra.get("emulator_spread")
    assert ("Emulator spread" in text) == (spread is not None)
    if spread is not None:
        assert f"up to {spread['max_quantile_shift']:.2f} of its range" in text
    assert ("widens it" in text) == pooled
    moved = (spread or {}).get("pooled_shift")
    assert ("moving a 5/50/95 % quantile by up to 0.065 of its range" in text) == (moved is not None)


def test_the_emulators_start_and_active_learning_are_stated() -> None:
    from smcbayes.report.sections_stages import _active_words

    start = {"calibration_gp": 61, "local_search": 178}
    words = _active_words({"active_learning": {"enabled": True, "evaluations": 400, "rounds": 14,
                                               "converged": False, "start_points": start}})
    assert words.startswith(", starting from its 61 points and 178 evaluations "
                            "of the calibration's local search")
    assert "400 forward runs in 14 rounds (stopped by its budget" in words
    alone = {"enabled": False, "evaluations": 0, "start_points": {"calibration_gp": 30, "local_search": 0}}
    assert _active_words({"active_learning": alone}) == ""
    searched = {**alone, "start_points": start}
    assert _active_words({"active_learning": searched}) == (
        ", starting from its 61 points and 178 evaluations of the calibration's local search")


def test_the_active_learnings_figure_is_shown_where_the_stage_drew_it(tmp_path: Path) -> None:
    from smcbayes.posterior.plots import learning_plot

    (tmp_path / "without").mkdir()
    assert "Active learning round by round" not in posterior_report_text(tmp_path / "without", {})
    run = fake_run(tmp_path)
    rounds = [{"round": 1, "forward_runs": 40, "error_nats": 2.0, "quantile_shift": None, "spread": 0.2}]
    learning_plot(rounds, {"start_runs": 60, "tolerance_nats": 1.0},
                  run / "posterior" / "figures" / "learning")
    (run / "posterior" / "summary.json").write_text(json.dumps({"parameters": []}), encoding="utf-8")
    write_report(run, formats=("md",))
    text = next(run.glob("report*.md")).read_text(encoding="utf-8")
    assert "Active learning round by round" in text and "posterior/figures/learning.png" in text
