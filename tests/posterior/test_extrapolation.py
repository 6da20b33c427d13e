"""Band configurations that lie outside what the training configurations span are named, and
matched with the training groups whose leave-out refits put them across the same gap."""

from __future__ import annotations

from pathlib import Path

from smcbayes.config import load_project
from smcbayes.posterior.extrapolation import extrapolation_notes, leave_out_groups

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


def test_leave_out_groups_match_the_gap() -> None:
    project = load_project(ROOT / "configs" / "thesis.toml")
    train = ["60-bar-03", "60-bar-07", "60-center-03", "60-center-07", "80-bar-07"]
    # a faster trial: the fastest training trials, predicted from the slower ones
    groups, words = leave_out_groups(project, train, "60-center-11")
    assert groups == [(1, 3, 4)] and "0.7 mm/s trials predicted from the slower" in words
    # a slower trial: the slowest ones, predicted from the faster ones
    groups, words = leave_out_groups(project, ["60-bar-07", "60-bar-11", "80-bar-11"], "60-bar-03")
    assert groups == [(0,)] and "0.7 mm/s trials predicted from the faster" in words
    # a new charge: each training charge in turn
    groups, words = leave_out_groups(project, train, "80-center-07")
    assert groups == [(0, 1), (2, 3), (4,)] and words == "each training charge predicted from the others"
    # both gaps: both kinds of groups
    groups, words = leave_out_groups(project, train, "80-center-11")
    assert groups == [(1, 3, 4), (0, 1), (2, 3), (4,)] and " and " in words
    # inside the training set: none
    assert leave_out_groups(project, train, "60-bar-07") == ([], "")
    assert leave_out_groups(project, ["60-bar-03", "60-bar-11"], "60-bar-07") == ([], "")
    # a single training speed or charge cannot be left out: nothing would remain to fit
    assert leave_out_groups(project, ["60-bar-07", "60-center-07"], "60-bar-11") == ([], "")
    assert leave_out_groups(project, ["60-bar-03", "60-bar-07"], "80-bar-07") == ([], "")
