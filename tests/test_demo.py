"""``smcbayes demo --quick`` end to end, and the HTML report it writes."""

from __future__ import annotations

import json
import shlex
import shutil
import sys
from pathlib import Path

import pytest

from smcbayes.cli import build_parser, main
from smcbayes.report import write_report

sys.path.insert(0, str(Path(__file__).resolve().parent / "report"))  # the shared HTML checker
from htmlcheck import PLACEHOLDER, external_references, parse_page  # noqa: E402

SECTIONS = ["data", "calibration", "posterior", "bands", "diagnosis", "reproducibility"]


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("demo") / "out"
    assert main(["demo", "--quick", "--out", str(out)]) == 0
    return out


def test_quick_demo_writes_every_stage(demo_out: Path) -> None:
    run = demo_out / "run"
    for rel in ("summary.json", "gp.pt", "posterior/posterior.nc", "posterior/summary.json",
                "diagnose/summary.json", "diagnose/ranking.csv", "report.html", "report.md", "demo.json"):
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
    # measured data, convergence, best curves, corner, correlations, bands, heat map, phases, before/after
    assert len(facts.img_src) + facts.inline_svg >= 9
    assert all(src.startswith("data:image/") for src in facts.img_src)
    assert external_references(facts) == []
    assert facts.stylesheets == [] and facts.scripts == 0
    assert "http://" not in page and "https://" not in page
    text = "".join(facts.text)
    assert not PLACEHOLDER.search(text), PLACEHOLDER.search(text)
    for words in ("force RMSE (kN)", "R-hat", "inside 90 % band", "press_compliance", "SHA-256"):
        assert words in text, words


def test_markdown_twin_references_existing_figures(demo_out: Path) -> None:
    run = demo_out / "run"
    md = (run / "report.md").read_text(encoding="utf-8")
    links = [line.split("](", 1)[1].rstrip(")") for line in md.splitlines() if line.startswith("![")]
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
    assert set(record["timings_s"]) >= {"synth", "calibrate", "posterior", "diagnose", "report", "total"}


def test_report_of_calibration_only_omits_later_stages(demo_out: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(demo_out / "run", run, ignore=shutil.ignore_patterns("posterior", "diagnose", "report*",
                                                                         "demo.json"))
    write_report(run)
    facts = parse_page((run / "report.html").read_text(encoding="utf-8"))
    assert facts.sections == ["data", "calibration", "reproducibility"]
    assert len(facts.img_src) >= 3 and all(s.startswith("data:image/") for s in facts.img_src)


def test_demo_refuses_a_used_folder(demo_out: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--quick", "--out", str(demo_out)]) == 2
    assert "not empty" in capsys.readouterr().err
