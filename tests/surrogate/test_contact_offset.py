"""A calibration whose loss profiles each trial's contact offset records each training
trial's offset at the best point and draws the curves at it."""

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
    again = contact_offsets_mm(problem.model.simulate(theta, train), problem.dataset, problem.project.loss, train)
    assert again == offsets
