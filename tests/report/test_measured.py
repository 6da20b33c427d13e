"""Measured-data figure, and the validation errors of the best point that the calibration
records for the report, on synthetic data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import build_project, load_project
from smcbayes.data.synth import NoiseSpec, write_synthetic
from smcbayes.forward.model import ForwardModel
from smcbayes.report.measured import load_measured, plot_measured, project_of
from smcbayes.simulation.problem import build_problem
from smcbayes.surrogate.calibration import validation_errors

TRUTH = {"n": 0.35, "tau_star_Pa": 2.0e4, "B_Pa_s": 2.0e4, "tau_c_MPa": 0.05, "m": 1.4}
RAW = {
    "name": "pair",
    "configuration": [
        {
            "id": "bar-07",
            "role": "train",
            "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 384.0},
            "press": {"speed_mm_s": 0.7, "hold_s": 50.0},
        },
        {
            "id": "centre-07",
            "role": "validation",
            "charge": {"shape": "center", "coverage_pct": 80.0, "mass_g": 527.0},
            "press": {"speed_mm_s": 0.7, "hold_s": 50.0},
        },
    ],
}


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("pair")
    model = ForwardModel(build_project(RAW, "<test>", folder), overrides=TRUTH)
    return write_synthetic(
        model, ["bar-07", "centre-07"], NoiseSpec(white_kN=2.0), 5, folder, TRUTH
    )


def errors_at(synthetic: Path, tmp: Path, values: dict[str, float]) -> dict[str, dict[str, float]]:
    project = load_project(synthetic)
    problem = build_problem(project, tmp)
    theta = np.array([[values[n] for n in problem.space.free_names]])
    with problem.runner() as runner:
        results = runner.simulate(theta, problem.model.config_ids)
    return validation_errors(problem, results)


def test_validation_errors_are_small_at_the_truth_and_large_elsewhere(synthetic: Path,
                                                                      tmp_path: Path) -> None:
    project = load_project(synthetic)
    assert project_of({"project": project.model_dump(mode="json")}) is not None
    at_truth = errors_at(synthetic, tmp_path, TRUTH)
    assert list(at_truth) == ["centre-07"]  # only the validation configuration
    # 2 kN of white noise plus a floor of about 5 kN: the loss resamples the steep rise to
    # the force limit, where a few samples of misplaced time weigh hundreds of kN
    assert 1.0 < at_truth["centre-07"]["rmse_kN"] < 7.0
    wrong = errors_at(synthetic, tmp_path, {**TRUTH, "B_Pa_s": 8.0e4})
    assert wrong["centre-07"]["rmse_kN"] > 3 * at_truth["centre-07"]["rmse_kN"]


def test_measured_figure_is_written_as_png_and_svg(synthetic: Path, tmp_path: Path) -> None:
    dataset = load_measured(load_project(synthetic))
    paths = plot_measured(dataset, tmp_path / "measured")
    assert paths is not None and [p.suffix for p in paths] == [".png", ".svg"]
    assert all(p.stat().st_size > 1000 for p in paths)


def test_no_data_folder_gives_no_dataset(tmp_path: Path) -> None:
    project = build_project({**RAW, "data_dir": "missing"}, "<test>", tmp_path)
    assert load_measured(project) is None
    assert project_of({"project": {"name": "x"}}) is None


def test_the_error_table_says_how_a_validation_trial_without_its_contact_is_judged() -> None:
    from smcbayes.report.sections_run import _error_table

    validation = {"b": {"mse_kN2": 9.0, "rmse_kN": 3.0}}
    cal = {"best_errors_kN2": {"a": 4.0}, "contact_offsets_mm": {"a": 0.1}}
    with_contacts = _error_table(cal, validation)
    assert "averaged over the training trials' contact offsets" in with_contacts.caption
    assert [r[1] for r in with_contacts.rows] == ["train", "validation (not fitted)"]
    nominal = _error_table({"best_errors_kN2": {"a": 4.0}}, validation)
    assert "averaged" not in nominal.caption
