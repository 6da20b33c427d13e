"""The predictive-bands section: coverage beside sharpness and the error model's table."""

from __future__ import annotations

import json
from pathlib import Path

from smcbayes.report import write_report

PROJECT = {
    "name": "tiny", "data_dir": "data", "base_dir": ".",
    "configuration": [
        {"id": "bar-03", "role": "train", "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 388.0},
         "press": {"speed_mm_s": 0.3}},
        {"id": "bar-07", "role": "validation",
         "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 384.0}, "press": {"speed_mm_s": 0.7}},
    ],
}


def write(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data), encoding="utf-8")


def make_run(root: Path, discrepancy: dict | None) -> Path:
    run = root / "run"
    write(run / "config.json", {"project": dict(PROJECT, base_dir=str(root))})
    write(run / "summary.json", {"best_loss_kN2": 100.0, "best_params": {}, "effects": [], "search_box": {},
                                 "best_errors_kN2": {"bar-03": 100.0}, "settings": {"seed": 0},
                                 "loss": {"w_force": 1.0, "w_displacement": 0.0, "clip": "none"}})
    band = {"coverage50": 0.55, "coverage90": 0.88, "noise_kN": 30.0, "width90_kN": 123.4, "crps_kN": 17.25,
            "interval_score90_kN": 211.0, "rmse_median_kN": 41.5, "rmse_mean_kN": 38.25, "draws": 10,
            "role": "validation",
            "error_model": "discrepancy" if discrepancy else "white noise"}
    write(run / "posterior" / "summary.json", {"parameters": [], "bands": {"bar-07": band},
                                              "discrepancy": discrepancy})
    return run


def test_bands_section_reports_sharpness_and_the_error_model(tmp_path: Path) -> None:
    disc = {"bins": [{"from_mm": None, "to_mm": 0.0, "points": 80, "configurations": 2, "q05_kN": -310.0,
                      "q50_kN": -20.0, "q95_kN": 40.0},
                     {"from_mm": 0.0, "to_mm": None, "points": 300, "configurations": 3, "q05_kN": -12.0,
                      "q50_kN": 1.0, "q95_kN": 15.0}]}
    disc["extrapolation"] = [{"bins": [{**disc["bins"][0], "q05_kN": -555.0}], "configurations": ["bar-07"],
                              "residuals": "the 0.3 mm/s trials predicted from the faster ones"}]
    run = make_run(tmp_path, disc)
    write_report(run, formats=("md",))
    md = (run / "report.md").read_text(encoding="utf-8")
    for words in ("CRPS (kN)", "17.2", "123", "211", "41.5", "predictive mean RMSE (kN)", "38.2",
                  "remaining ram travel to the simulated end of closing",
                  "below 0", "above 0", "-310", "clipped to 0 kN and the press's force limit",
                  "error model of bar-07, outside the training set", "-555",
                  "the 0.3 mm/s trials predicted from the faster ones"):
        assert words in md, words


def test_without_an_error_model_the_section_says_white_noise(tmp_path: Path) -> None:
    run = make_run(tmp_path, None)
    write_report(run, formats=("md",))
    md = (run / "report.md").read_text(encoding="utf-8")
    assert "white noise with each configuration's residual standard deviation" in md
    assert "error model: measured minus simulated" not in md
