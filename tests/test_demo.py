"""``smcbayes demo --quick`` end to end: the loop from a withheld effect to its diagnosis and a
second calibration with the named effect on, and the HTML reports it writes."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import sys
from pathlib import Path

import pytest
from matplotlib.colors import to_rgba

from smcbayes.cli import build_parser, main
from smcbayes.report import write_report

sys.path.insert(0, str(Path(__file__).resolve().parent / "report"))  # the shared HTML checker
from htmlcheck import PLACEHOLDER, external_references, parse_page

pytestmark = pytest.mark.slow

SECTIONS = ["data", "calibration", "posterior", "bands", "diagnosis", "reproducibility"]
"""Sections of the base run's report."""
AFTER_SECTIONS = ["data", "before-after", "calibration", "posterior", "bands", "reproducibility"]
"""Sections of the effect run's report (no diagnosis of its own)."""
LOSS_FACTOR = 5.0
"""Training loss of the base run over that of the effect run, at least (quick demo)."""


FIGURES: list[dict] = []
"""Axis labels and labelled lines of every PNG figure the quick demo saved."""

UNIT = re.compile(r"\(.+\)|^(log10 )?[A-Za-z0-9]+_[A-Za-z0-9_]+$|^[a-z][0-9]?$|^evaluation$")
"""An axis label with a unit in parentheses, a parameter name (unit suffix) or a count."""


def _spy(original):
    def savefig(fig, fname, *args, **kwargs):
        if str(fname).endswith(".png"):
            FIGURES.append(
                {
                    "file": str(fname),
                    "axes": [
                        {
                            "labels": [ax.get_xlabel(), ax.get_ylabel()],
                            "lines": [
                                (ln.get_label(), to_rgba(ln.get_color())) for ln in ax.get_lines()
                            ],
                        }
                        for ax in fig.axes
                        if ax.get_visible()
                    ],
                }
            )
        return original(fig, fname, *args, **kwargs)

    return savefig


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from matplotlib.figure import Figure

    out = tmp_path_factory.mktemp("demo") / "out"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Figure, "savefig", _spy(Figure.savefig))
        assert main(["demo", "--quick", "--out", str(out)]) == 0
    return out


def test_quick_demo_writes_every_stage(demo_out: Path) -> None:
    base, after = demo_out / "run-base", demo_out / "run-effect"
    for run, files in (
        (base, ("posterior/summary.json", "diagnose/summary.json", "diagnose/ranking.csv")),
        (after, ("posterior/posterior.nc", "posterior/summary.json")),
    ):
        for rel in ("summary.json", "gp.pt", "report.html", "report.md", "demo.json", *files):
            assert (run / rel).is_file(), run / rel
    assert not (demo_out / "run").exists()
    truth = json.loads((demo_out / "data" / "truth.json").read_text(encoding="utf-8"))
    assert truth["effects"] == ["press_compliance"]
    summary = json.loads((base / "summary.json").read_text(encoding="utf-8"))
    assert summary["effects"] == []  # the base model lacks the withheld effect
    bands = json.loads((after / "posterior" / "summary.json").read_text(encoding="utf-8"))["bands"]
    assert bands and all(b["role"] == "validation" for b in bands.values())
    assert all(b["width90_kN"] > 0 for b in bands.values())  # sharpness beside coverage
    for png in demo_out.rglob("*.png"):
        assert png.with_suffix(".svg").is_file(), png


def test_the_loop_closes_on_the_effect_the_diagnosis_names(demo_out: Path) -> None:
    base, after = demo_out / "run-base", demo_out / "run-effect"
    truth = json.loads((demo_out / "data" / "truth.json").read_text(encoding="utf-8"))
    named = json.loads((base / "diagnose" / "summary.json").read_text())["decision"]["best"]
    assert named == "press_compliance" and [named] == truth["effects"]
    before = json.loads((base / "summary.json").read_text(encoding="utf-8"))
    cal = json.loads((after / "summary.json").read_text(encoding="utf-8"))
    assert cal["effects"] == [named] and "k_press_kN_mm" in cal["free_parameters"]
    assert before["best_loss_kN2"] / cal["best_loss_kN2"] >= LOSS_FACTOR
    record = json.loads((after / "demo.json").read_text(encoding="utf-8"))
    assert record["effect_named"] == named and record["compare_with"] == "../run-base"


def test_html_report_is_complete_and_self_contained(demo_out: Path) -> None:
    run = demo_out / "run-effect"
    page = (run / "report.html").read_text(encoding="utf-8")
    facts = parse_page(page)
    assert facts.sections == AFTER_SECTIONS
    # measured data, before/after fit, convergence, best curves, corner, correlations, bands:
    # every figure of the run is in the page
    pngs = list(run.rglob("*.png"))
    assert len(pngs) >= 7 and len(facts.img_src) + facts.inline_svg == len(pngs)
    assert all(src.startswith("data:image/") for src in facts.img_src)
    assert external_references(facts) == []
    assert facts.stylesheets == [] and facts.scripts == 0
    assert "http://" not in page and "https://" not in page
    text = "".join(facts.text)
    assert not PLACEHOLDER.search(page), PLACEHOLDER.search(page)  # markup, CSS and text
    for words in (
        "force RMSE (kN)",
        "force RMSE before (kN)",
        "validation (not fitted)",
        "R-hat",
        "inside 90 % band",
        "mean 90 % width before (kN)",
        "truth inside 90 % interval after",
        "press_compliance",
        "Check against the known truth: the synthetic data were made with press_compliance",
        "Check against the known truth: the true value lies inside the 90 % interval",
        "SHA-256",
    ):
        assert words in text, words
    # the report states the decision the base run's diagnosis computed (not a fixed phrase)
    diag = json.loads((demo_out / "run-base" / "diagnose" / "summary.json").read_text())
    assert diag["decision"]["statement"].split(":")[0] in text


def test_base_report_keeps_its_diagnosis(demo_out: Path) -> None:
    facts = parse_page((demo_out / "run-base" / "report.html").read_text(encoding="utf-8"))
    assert facts.sections == SECTIONS
    assert "Check against the known truth" in "".join(facts.text)


def test_markdown_twin_references_existing_figures(demo_out: Path) -> None:
    run = demo_out / "run-effect"
    md = (run / "report.md").read_text(encoding="utf-8")
    links = [
        line.split("](", 1)[1].rstrip(")") for line in md.splitlines() if line.startswith("![")
    ]
    assert len(links) >= 7
    for rel in links:
        assert not rel.startswith("/") and (run / rel).is_file(), rel
    for key in AFTER_SECTIONS:
        assert f'<a id="{key}"></a>' in md
    assert not PLACEHOLDER.search(md)


def test_recorded_commands_are_valid_command_lines(demo_out: Path) -> None:
    record = json.loads((demo_out / "run-effect" / "demo.json").read_text(encoding="utf-8"))
    parser = build_parser()
    names = []
    for line in record["commands"]:
        argv = shlex.split(line)
        assert argv[0] == "smcbayes"
        names.append(parser.parse_args(argv[1:]).command)
    assert names == ["synth", "calibrate", "posterior", "diagnose", "calibrate", "posterior",
                     "report", "report"]
    assert f"--effect {record['effect_named']}" in record["commands"][4]
    assert set(record["timings_s"]) >= {
        "synth",
        "calibrate",
        "posterior",
        "diagnose",
        "calibrate-effect",
        "posterior-effect",
        "report",
        "total",
    }


def test_report_of_calibration_only_omits_later_stages(demo_out: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(
        demo_out / "run-base",
        run,
        ignore=shutil.ignore_patterns("posterior", "diagnose", "report*", "demo.json"),
    )
    write_report(run)
    facts = parse_page((run / "report.html").read_text(encoding="utf-8"))
    assert facts.sections == ["data", "calibration", "reproducibility"]
    assert len(facts.img_src) >= 3 and all(s.startswith("data:image/") for s in facts.img_src)


def test_demo_refuses_a_used_folder(demo_out: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--quick", "--out", str(demo_out)]) == 2
    assert "not empty" in capsys.readouterr().err


def test_embedded_plans_hold_out_validation_trials() -> None:
    from smcbayes.commands.demo import load_plan

    for quick, count in ((True, 7), (False, 12)):
        plan = load_plan(quick)
        roles = [c["role"] for c in plan.project["configuration"]]
        assert len(roles) == count and "validation" in roles and roles.count("train") >= 3
        assert plan.effect not in plan.project.get("effects", [])  # withheld from the model
        assert plan.stage["effect_budget"] >= plan.stage["effect_init"] >= 2


def test_failing_stage_names_itself_and_its_log(tmp_path: Path) -> None:
    from smcbayes.commands.demo import load_plan, run_stage
    from smcbayes.errors import ConfigError

    (tmp_path / "logs").mkdir()
    with pytest.raises(
        ConfigError, match=r"demo stage 'report': .*not a calibration run.*report\.log"
    ):
        run_stage(load_plan(True), "report", tmp_path)
    assert (tmp_path / "logs" / "report.log").is_file()


def test_figures_follow_the_package_conventions(demo_out: Path) -> None:
    names = {Path(f["file"]).name for f in FIGURES}
    assert {"measured.png", "best_curves.png", "bands.png", "before_after.png",
            "before_after_fit.png"} <= names
    black = to_rgba("black")
    for fig in FIGURES:
        for ax in fig["axes"]:
            for label in ax["labels"]:
                assert not label or UNIT.search(label), (fig["file"], label)
            for label, colour in ax["lines"]:
                if "measured" in label:
                    assert colour == black, (fig["file"], label)
                elif not label.startswith("_") and "simulated" in label:
                    assert colour != black, (fig["file"], label)


def test_second_calibration_switches_on_the_effect_read_from_the_diagnosis(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from smcbayes.commands import demo
    from smcbayes.errors import ConfigError

    calls: list[dict] = []
    monkeypatch.setattr(demo.api, "calibrate", lambda *a, **kw: calls.append(kw))
    (tmp_path / "logs").mkdir()
    plan = demo.load_plan(True)
    with pytest.raises(ConfigError, match="names no effect"):
        demo.run_stage(plan, "calibrate-effect", tmp_path)
    diag = tmp_path / demo.BASE_RUN / "diagnose"
    diag.mkdir(parents=True)
    # an effect other than the demo's withheld one: the summary decides, not the plan
    (diag / "summary.json").write_text(json.dumps({"decision": {"best": "speed_ramp"}}))
    demo.run_stage(plan, "calibrate-effect", tmp_path)
    assert calls[-1]["effects"] == ["speed_ramp"] != [plan.effect]
    lines = demo.command_lines(plan, tmp_path, demo.named_effect(tmp_path))
    assert "--effect speed_ramp" in " ".join(lines["calibrate-effect"])
    assert "calibrate-effect" not in demo.command_lines(plan, tmp_path, None)
