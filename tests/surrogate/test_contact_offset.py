"""A calibration whose loss gives each trial a contact offset records each training trial's
offset at the best point and draws the curves at it; with the offset from the end state
and a bound, it names the trials whose end state lies beyond the bound."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

import smcbayes

REPO = Path(__file__).resolve().parents[2]


def test_a_calibration_records_each_trials_contact_offset(tmp_path: Path) -> None:
    project = smcbayes.load_project(REPO / "configs" / "verify-slip-2d.toml")
    project = project.model_copy(update={"loss": project.loss.model_copy(update={"contact_offset_mm": 0.2})})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = smcbayes.calibrate(project, tmp_path / "run", fidelity="1d", budget=4, init=3, figures=True,
                                 polish=0, truth={"tau_c_MPa": 0.02, "m": 1.4})
    offsets = cal.summary["contact_offsets_mm"]
    train = [c.id for c in project.configuration if c.role == "train"]
    assert sorted(offsets) == sorted(train)
    saved = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert saved["contact_offsets_mm"] == offsets
    assert (tmp_path / "run" / "figures" / "best_curves.png").is_file()
    # the recorded offsets are the loss's at the best point, found again from its curves
    from smcbayes.data.loss import contact_offsets_mm

    problem = cal.run_dir.load_problem()
    theta = np.array([[cal.best_params[n] for n in problem.model.space.free_names]])
    again = contact_offsets_mm(problem.model.simulate(theta, train), problem.dataset,
                               problem.project.loss, train)
    assert again == offsets


def test_a_calibration_names_the_trials_whose_end_state_lies_beyond_the_bound(tmp_path: Path) -> None:
    """Trials pressed with a ram that lags (1 s speed ramp), calibrated without the ramp
    and a 0.05 mm bound: the model ends each closing earlier than the press did, so the
    end state puts the contacts beyond the bound; the summary and a warning say which."""
    from smcbayes.cli import main
    from smcbayes.errors import ContactOffsetWarning

    ids = ["60-bar-03", "80-bar-11"]
    assert main(["synth", str(REPO / "configs" / "thesis.toml"), "--effect", "compressibility",
                 "--effect", "speed_ramp", "--truth", "ramp_time_s=1.0", "--truth", "load_slowdown=0.3",
                 "--seed", "1", "--only", *ids, "--out", str(tmp_path / "data")]) == 0
    project = smcbayes.load_project(tmp_path / "data" / "project.toml")
    project = project.model_copy(update={
        "loss": project.loss.model_copy(update={"contact_offset_mm": 0.05}),
        "configuration": [c for c in project.configuration if c.id in ids]})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cal = smcbayes.calibrate(project, tmp_path / "run", effects=["compressibility"], budget=4, init=3,
                                 figures=False, polish=0)
    beyond = {c["config_id"]: c["offset_mm"] for c in cal.summary["contact_on_bound"]}
    assert beyond and set(beyond) <= set(ids) and all(abs(v) > 0.05 for v in beyond.values())
    assert all(abs(v) == 0.05 for c, v in cal.summary["contact_offsets_mm"].items() if c in beyond)
    named = [str(w.message) for w in caught if issubclass(w.category, ContactOffsetWarning)]
    assert len(named) == len(beyond) and all("contact_offset_mm" in t for t in named)
