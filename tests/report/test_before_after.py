"""The before-and-after section: a run compared with the run it follows, read not simulated."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from smcbayes.report import write_report

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HTML checker of these tests
from htmlcheck import PLACEHOLDER, parse_page

PROJECT = {
    "name": "tiny",
    "data_dir": "data",
    "base_dir": ".",
    "configuration": [
        {"id": "bar-03", "role": "train",
         "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 388.0},
         "press": {"speed_mm_s": 0.3}},
        {"id": "bar-07", "role": "validation",
         "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 384.0},
         "press": {"speed_mm_s": 0.7}},
    ],
}
BOX = {"n": {"lower": 0.2, "upper": 0.6, "log": False, "unit": "-"},
       "B_Pa_s": {"lower": 1e3, "upper": 1e5, "log": True, "unit": "Pa s"}}
TRUTH = {"parameters": {"n": 0.35, "B_Pa_s": 2.0e4, "k_press_kN_mm": 300.0},
         "effects": ["press_compliance"], "noise": {"white_kN": 2.0, "correlated_kN": 3.0}}


def write(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data), encoding="utf-8")


def make_run(root: Path, name: str, effects: list[str], loss: float, params: list[dict],
             box: dict, widths: dict | None) -> Path:
    run = root / name
    project = dict(PROJECT, base_dir=str(root))
    write(run / "config.json", {"project": project})
    write(run / "summary.json", {
        "best_loss_kN2": loss, "best_params": {}, "effects": effects, "search_box": box,
        "best_errors_kN2": {"bar-03": loss}, "settings": {"seed": 0},
        "loss": {"w_force": 1.0, "w_displacement": 0.0, "clip": "flow_stop"},
        "validation_errors": {"bar-07": {"mse_kN2": 4 * loss, "rmse_kN": (4 * loss) ** 0.5}},
    })
    band = {"coverage50": 0.5, "coverage90": 0.9 if widths else 0.4, "noise_kN": 4.0, "draws": 10,
            "role": "validation", **((widths or {}).get("bar-07") or {})}
    write(run / "posterior" / "summary.json", {"parameters": params, "bands": {"bar-07": band}})
    return run


def two_runs(tmp_path: Path, b_interval: tuple[float, float]) -> Path:
    write(tmp_path / "data" / "truth.json", TRUTH)
    base = make_run(tmp_path, "run-base", [], 250.0,
                    [{"name": "n", "q05": 0.21, "q95": 0.59}, {"name": "B_Pa_s", "q05": 1.1e3,
                                                                "q95": 9.5e4}], BOX, None)
    write(base / "diagnose" / "summary.json",
          {"decision": {"best": "press_compliance", "statement": "press_compliance explains it"}})
    box = dict(BOX, k_press_kN_mm={"lower": 50.0, "upper": 5000.0, "log": True, "unit": "kN/mm"})
    after = make_run(tmp_path, "run-effect", ["press_compliance"], 25.0,
                     [{"name": "n", "q05": 0.3, "q95": 0.4},
                      {"name": "B_Pa_s", "q05": b_interval[0], "q95": b_interval[1]},
                      {"name": "k_press_kN_mm", "q05": 250.0, "q95": 350.0}],
                     box, {"bar-07": {"width90_kN": 20.0, "coverage90": 0.9}})
    write(after / "demo.json", {"compare_with": "../run-base", "commands": []})
    return after


def test_before_and_after_states_fit_width_truth_and_bands(tmp_path: Path) -> None:
    after = two_runs(tmp_path, (1.5e4, 3.0e4))
    write_report(after)
    facts = parse_page((after / "report.html").read_text(encoding="utf-8"))
    assert facts.sections[:3] == ["data", "before-after", "calibration"]
    text = " ".join(facts.text)
    for words in (
        "250 kN² before, 25 kN² after, 10 times lower",
        "press_compliance explains it",
        "the diagnosis names press_compliance (correct)",
        "Before, the posterior is essentially the prior",
        "the true value lies inside the 90 % interval after for 3 of 3 parameters",
        "not in the model",
        "the final rise to the force limit is not fitted",
        "coverage of the 90 % band 40 % before, 90 % after",
        "mean width of the 90 % band - kN before, 20 kN after",
    ):
        assert words in text, words
    md = (after / "report.md").read_text(encoding="utf-8")
    assert "## Before and after" in md and not PLACEHOLDER.search(md)


def test_a_truth_outside_the_interval_is_a_warning(tmp_path: Path) -> None:
    after = two_runs(tmp_path, (3.0e4, 5.0e4))
    write_report(after, formats=("md",))
    md = (after / "report.md").read_text(encoding="utf-8")
    assert ("> **Warning:** Check against the known truth: the true value lies inside the 90 % "
            "interval after for 2 of 3 parameters; outside it for B_Pa_s") in md


def test_a_missing_earlier_run_is_said_not_fatal(tmp_path: Path) -> None:
    after = two_runs(tmp_path, (1.5e4, 3.0e4))
    write(after / "demo.json", {"compare_with": "../gone"})
    write_report(after, formats=("md",))
    md = (after / "report.md").read_text(encoding="utf-8")
    assert "cannot be read, so there is no comparison" in md and "## Posterior" in md
