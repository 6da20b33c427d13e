"""The diagnosis section: what it states for a given diagnosis summary, read defensively."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from smcbayes.report.collect import RunFiles
from smcbayes.report.document import Figure, Heading, Paragraph, Section, Table
from smcbayes.report.sections_diagnosis import diagnosis_section


def run_files(tmp_path: Path, diagnosis: dict[str, Any] | None, truth: dict[str, Any] | None = None,
              base_effects: list[str] | None = None, figures: tuple[str, ...] = ()) -> RunFiles:
    diag_dir = tmp_path / "diagnose"
    for name in figures:
        (diag_dir / "figures").mkdir(parents=True, exist_ok=True)
        (diag_dir / "figures" / f"{name}.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    return RunFiles(tmp_path, {}, {"effects": base_effects or []}, None, diagnosis, diag_dir, truth, None)


def summary() -> dict[str, Any]:
    return {
        "where": {"verdict": "the misfit is concentrated in the last 30 % of the closing"},
        "ranking": [
            {"rank": 1, "effect": "press_compliance", "extra_parameters": 1, "absorbable_share": 0.42,
             "holdout_loss_base_kN2": 812.345678, "holdout_loss_kN2": 95.5, "holdout_shrink_pct": 88.24,
             "dm_z": 4.123, "score": 31.26, "evidence": 80.04, "significant": True},
            {"rank": 2, "effect": "heating", "extra_parameters": 3, "absorbable_share": None,
             "holdout_loss_base_kN2": 812.345678, "holdout_loss_kN2": float("nan"),
             "significant": False},
        ],
        "decision": {"best": "press_compliance", "statement": "press_compliance explains the gap."},
        "shrink": {
            "sets": {"fit": ["60-bar-03", "60-bar-11"], "holdout": ["60-bar-07"]},
            "models": {
                "base": {"effects": [], "fit": {"loss_kN2": 400.0}, "holdout": {"loss_kN2": 800.0}},
                "press_compliance": {"effects": ["press_compliance"],
                                     "fit": {"loss_kN2": 40.0, "shrink_pct": 90.0},
                                     "holdout": {"loss_kN2": 100.0, "shrink_pct": 87.5}},
            },
        },
    }


def blocks(sec: Section, kind: type) -> list[Any]:
    return [b for b in sec.blocks if isinstance(b, kind)]


def texts(sec: Section) -> list[str]:
    return [b.text for b in blocks(sec, Paragraph)]


def test_no_diagnosis_no_section(tmp_path: Path) -> None:
    assert diagnosis_section(run_files(tmp_path, None)) is None


def test_full_summary_gives_verdict_ranking_decision_next_step_and_shrink(tmp_path: Path) -> None:
    sec = diagnosis_section(run_files(tmp_path, summary()))
    assert sec is not None and sec.key == "diagnosis"
    assert [h.text for h in blocks(sec, Heading)] == [
        "Where the model misses", "Which effect explains it", "How far the gap shrinks"]
    paragraphs = texts(sec)
    assert paragraphs[0] == "The misfit is concentrated in the last 30 % of the closing"
    assert "press_compliance explains the gap." in paragraphs
    # a summary written before effect sets were selected: the named effect is the set
    assert any("--effect press_compliance" in p
               and p.startswith("Selected effect set: press_compliance. Next step")
               for p in paragraphs)
    ranking, shrink = blocks(sec, Table)
    assert ranking.rows[0] == ("1", "press_compliance", "1", "42 %", "812.3", "95.5", "88.2", "4.12",
                               "31.3", "80", "yes, named")
    # missing and NaN values are dashes, never an error
    assert ranking.rows[1] == ("2", "heating", "3", "-", "812.3", "-", "-", "-", "-", "-", "no")
    assert shrink.rows == (("base", "none", "400", "-", "800", "-"),
                           ("press_compliance", "press_compliance", "40", "90", "100", "87.5"))
    assert "fitting: 60-bar-03, 60-bar-11; held out: 60-bar-07" in shrink.caption
    assert blocks(sec, Figure) == []  # no figure files, no figures


def test_figures_appear_only_when_their_files_exist(tmp_path: Path) -> None:
    sec = diagnosis_section(run_files(tmp_path, summary(), figures=("heatmap", "before_after")))
    paths = [f.path.name for f in blocks(sec, Figure)]
    assert paths == ["heatmap.png", "before_after.png"]


def test_truth_check_names_a_correct_diagnosis(tmp_path: Path) -> None:
    """Effects the calibrated model already has are not 'withheld'."""
    truth = {"effects": ["heating", "press_compliance"]}
    sec = diagnosis_section(run_files(tmp_path, summary(), truth, base_effects=["heating"]))
    check = [b for b in blocks(sec, Paragraph) if b.text.startswith("Check against the known truth")]
    assert len(check) == 1
    assert "made with press_compliance on" in check[0].text and "heating" not in check[0].text
    assert check[0].text.endswith("(correct).") and check[0].tone == "normal"


def test_truth_check_warns_when_the_withheld_effect_is_missed(tmp_path: Path) -> None:
    diag = summary()
    diag["decision"] = {"best": None, "statement": "no effect explains the gap beyond noise"}
    sec = diagnosis_section(run_files(tmp_path, diag, {"effects": ["speed_ramp"]}))
    check = [b for b in blocks(sec, Paragraph) if b.text.startswith("Check against")][0]
    assert "names no effect (not the withheld effect)" in check.text and check.tone == "warning"
    assert not any("Next step" in p for p in texts(sec))


def test_truth_without_withheld_effect(tmp_path: Path) -> None:
    sec = diagnosis_section(run_files(tmp_path, summary(), {"effects": []}))
    check = [p for p in texts(sec) if p.startswith("Check against")]
    assert check == ["Check against the known truth: the synthetic data have no withheld effect; "
                     "the diagnosis names press_compliance."]


def test_an_empty_summary_gives_only_the_where_heading(tmp_path: Path) -> None:
    sec = diagnosis_section(run_files(tmp_path, {}))
    assert sec is not None and sec.blocks == [Heading("Where the model misses")]


def test_selection_steps_and_the_selected_set_are_named(tmp_path) -> None:
    from smcbayes.report.sections_diagnosis import _selection

    diag = {"decision": {"best": "compressibility"},
            "selected_effects": ["compressibility", "press_compliance"],
            "selection": {"steps": [
                {"added": "press_compliance", "best_candidate": "press_compliance", "score": 40.0,
                 "holdout_loss_before_kN2": 2e4, "holdout_loss_after_kN2": 9e3},
                {"added": None, "best_candidate": "heating", "score": 1.0,
                 "holdout_loss_before_kN2": 9e3, "holdout_loss_after_kN2": 8.9e3}]}}
    blocks = _selection(diag)
    bullets = [b for b in blocks if hasattr(b, "items")][0].items
    assert "with press_compliance" in bullets[0] and "added" in bullets[0]
    assert "heating" in bullets[1] and "not significant" in bullets[1]
    last = blocks[-1].text
    assert "compressibility + press_compliance" in last and "--effects-from" in last
    assert _selection({"decision": {"best": None}}) == []


def test_effects_left_out_of_the_selection_are_named(tmp_path) -> None:
    from smcbayes.report.sections_diagnosis import _selection

    diag = {"decision": {"best": "compressibility"}, "selected_effects": ["compressibility"],
            "selection": {"left_out": ["heating", "curing"], "steps": [
                {"added": None, "best_candidate": "press_compliance", "score": 1.0,
                 "holdout_loss_before_kN2": 9e3, "holdout_loss_after_kN2": 8.9e3}]}}
    bullets = [b for b in _selection(diag) if hasattr(b, "items")][0].items
    assert len(bullets) == 2 and "not tried: heating, curing" in bullets[1]
