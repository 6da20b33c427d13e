"""Band configurations that lie outside what the training configurations span are named."""

from __future__ import annotations

from pathlib import Path

from smcbayes.config import load_project
from smcbayes.posterior.report import extrapolation_notes

ROOT = Path(__file__).resolve().parents[2]


def test_speed_and_charge_outside_the_training_set_are_named() -> None:
    project = load_project(ROOT / "configs" / "thesis.toml")
    train = ["60-bar-03", "60-bar-07", "60-center-03", "60-center-07"]
    notes = extrapolation_notes(project, train, ["60-bar-07", "60-bar-11", "80-bar-07", "80-bar-11"])
    assert notes["60-bar-07"] == []  # a training trial: same speed, same charge
    assert len(notes["60-bar-11"]) == 1 and "1.1 mm/s outside the fitted 0.3-0.7" in notes["60-bar-11"][0]
    assert notes["80-bar-07"] == ["a charge none of the fitted trials has"]
    assert len(notes["80-bar-11"]) == 2
    # a speed between the fitted ones is inside
    assert extrapolation_notes(project, ["60-bar-03", "60-bar-11"], ["60-bar-07"]) == {"60-bar-07": []}
