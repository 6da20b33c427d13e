"""``smcbayes demo --quick`` end to end, and the HTML report it writes."""

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
    run = demo_out / "run"
    for rel in (
        "summary.json",
        "gp.pt",
        "posterior/posterior.nc",
        "posterior/summary.json",
        "diagnose/summary.json",
        "diagnose/ranking.csv",
        "report.html",
        "report.md",
        "demo.json",
    ):
        assert (run / rel).is_file(), rel
    truth = json.loads((demo_out / "data" / "truth.json").read_text(encoding="utf-8"))
    assert truth["effects"] == ["press_compliance"]
    summary = json.loads((run / "summary.json").read_text(encoding="utf-8"))
    assert summary["effects"] == []  # the calibrated model lacks the withheld effect
    bands = json.loads((run / "posterior" / "summary.json").read_text(encoding="utf-8"))["bands"]
    assert bands and all(b["role"] == "validation" for b in bands.values())
    for png in run.rglob("*.png"):
        assert png.with_suffix(".svg").is_file(), png


def test_html_report_is_complete_and_self_contained(demo_out: Path) -> None:
    page = (demo_out / "run" / "report.html").read_text(encoding="utf-8")
    facts = parse_page(page)
    assert facts.sections == SECTIONS
    # measured data, convergence, best curves, corner, correlations, bands, heat map, phases,
    # before/after: every figure of the run is in the page
    pngs = list((demo_out / "run").rglob("*.png"))
    assert len(pngs) >= 9 and len(facts.img_src) + facts.inline_svg == len(pngs)
    assert all(src.startswith("data:image/") for src in facts.img_src)
    assert external_references(facts) == []
    assert facts.stylesheets == [] and facts.scripts == 0
    assert "http://" not in page and "https://" not in page
    text = "".join(facts.text)
    assert not PLACEHOLDER.search(page), PLACEHOLDER.search(page)  # markup, CSS and text
    for words in (
        "force RMSE (kN)",
        "validation (not fitted)",
        "R-hat",
        "inside 90 % band",
        "press_compliance",
        "Check against the known truth",
        "SHA-256",
    ):
        assert words in text, words
    # the report states the decision the diagnosis computed (not a fixed phrase)
    decision = json.loads((demo_out / "run" / "diagnose" / "summary.json").read_text())["decision"]
    assert decision["statement"].split(":")[0] in text


def test_markdown_twin_references_existing_figures(demo_out: Path) -> None:
    run = demo_out / "run"
    md = (run / "report.md").read_text(encoding="utf-8")
    links = [
        line.split("](", 1)[1].rstrip(")") for line in md.splitlines() if line.startswith("![")
    ]
    assert len(links) >= 9
    for rel in links:
        assert not rel.startswith("/") and (run / rel).is_file(), rel
    for key in SECTIONS:
        assert f'<a id="{key}"></a>' in md
    assert not PLACEHOLDER.search(md)


def test_recorded_commands_are_valid_command_lines(demo_out: Path) -> None:
    record = json.loads((demo_out / "run" / "demo.json").read_text(encoding="utf-8"))
    parser = build_parser()
    names = []
    for line in record["commands"]:
        argv = shlex.split(line)
        assert argv[0] == "smcbayes"
        names.append(parser.parse_args(argv[1:]).command)
    assert names == ["synth", "calibrate", "posterior", "diagnose", "report"]
    assert set(record["timings_s"]) >= {
        "synth",
        "calibrate",
        "posterior",
        "diagnose",
        "report",
        "total",
    }


def test_report_of_calibration_only_omits_later_stages(demo_out: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(
        demo_out / "run",
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

    for quick, count in ((True, 4), (False, 12)):
        plan = load_plan(quick)
        roles = [c["role"] for c in plan.project["configuration"]]
        assert len(roles) == count and "validation" in roles and roles.count("train") >= 3
        assert plan.effect not in plan.project.get("effects", [])  # withheld from the model


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
    assert {"measured.png", "best_curves.png", "bands.png", "before_after.png"} <= names
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
