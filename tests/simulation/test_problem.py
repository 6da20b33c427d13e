"""A calibration problem with training and validation trials: what is loaded, what is
scored, what is refused."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import build_project
from smcbayes.data.synth import NoiseSpec, write_synthetic
from smcbayes.errors import ConfigError, DataWarning
from smcbayes.forward.model import ForwardModel
from smcbayes.simulation.problem import ExternalSpec, build_problem
from smcbayes.surrogate.calibration import validation_errors

TRUTH = {"n": 0.35, "tau_star_Pa": 2.0e4, "B_Pa_s": 2.0e4, "tau_c_MPa": 0.05, "m": 1.4}
TRIALS = [
    {"id": "bar-07", "role": "train", "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 384.0},
     "press": {"speed_mm_s": 0.7, "hold_s": 50.0}},
    {"id": "bar-11", "role": "validation", "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 384.0},
     "press": {"speed_mm_s": 1.1, "hold_s": 50.0}},
]


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("trials")
    model = ForwardModel(build_project({"name": "t", "configuration": TRIALS}, "<test>", folder),
                         overrides=TRUTH)
    write_synthetic(model, ["bar-07", "bar-11"], NoiseSpec(white_kN=2.0), 3, folder, TRUTH)
    return folder


def project_with(data: Path, validation: dict, w_displacement: float = 1.0):
    trials = [{**TRIALS[0], "data": {"force": "force/bar-07.csv", "hold": "hold/bar-07.csv"}},
              {**TRIALS[1], "data": validation}]
    raw = {"name": "t", "data_dir": str(data), "configuration": trials,
           "loss": {"w_displacement": w_displacement}}
    return build_project(raw, "<test>", data)


def test_validation_without_hold_is_simulated_and_scored_on_force_only(data: Path, tmp_path: Path) -> None:
    """The loss scores the training trials only; a validation trial without a measured
    hold (while the loss weighs the hold) still gets its curves and its force error."""
    problem = build_problem(project_with(data, {"force": "force/bar-11.csv"}), tmp_path)
    theta = np.array([[TRUTH[n] for n in problem.space.free_names]])
    with problem.runner() as runner:
        results = runner.simulate(theta, problem.model.config_ids)
        errors = runner.errors(theta, ["bar-07", "bar-11"])
    assert np.isfinite(errors[0, 0]) and np.isnan(errors[0, 1])  # only the loss's trial is scored
    assert results["bar-11"].ok.all()
    val = validation_errors(problem, results)
    assert list(val) == ["bar-11"] and 0.5 < val["bar-11"]["rmse_kN"] < 20.0
    # over the training trials' contacts the curve is their mean, not the one at their mean
    from smcbayes.data.loss import force_pair, mixed_force_pair

    m, spec = problem.dataset.measurements["bar-11"], problem.project.loss
    mixed = mixed_force_pair(results["bar-11"], m, spec, [-0.5, 0.5])
    assert validation_errors(problem, results, [-0.5, 0.5])["bar-11"]["mse_kN2"] == \
        pytest.approx(float(np.mean((mixed.sim_kN[0] - mixed.meas_kN[0]) ** 2)))
    at_mean = force_pair(results["bar-11"], m, spec, offset_mm=0.0)
    assert abs(np.mean((at_mean.sim_kN[0] - at_mean.meas_kN[0]) ** 2) - val["bar-11"]["mse_kN2"]) < 1e-9
    assert validation_errors(problem, results, [-0.5, 0.5])["bar-11"]["rmse_kN"] > val["bar-11"]["rmse_kN"]


def test_an_unreadable_validation_file_is_left_out_with_a_warning(data: Path, tmp_path: Path) -> None:
    with pytest.warns(DataWarning, match="validation configuration 'bar-11' left out"):
        problem = build_problem(project_with(data, {"force": "force/missing.csv"}), tmp_path)
    assert list(problem.dataset.measurements) == ["bar-07"]


def test_a_training_trial_without_data_is_refused_even_for_an_external_solver(data: Path,
                                                                               tmp_path: Path) -> None:
    raw = {"name": "t", "data_dir": str(data), "configuration": [TRIALS[0], TRIALS[1]]}
    project = build_project(raw, "<test>", data)
    with pytest.raises(ConfigError, match="bar-07 have no measured force curve"):
        build_problem(project, tmp_path, external=ExternalSpec("python solver.py {params} {output}"))


def test_a_truth_check_ignores_the_validation_files(data: Path, tmp_path: Path) -> None:
    """A known-truth check calibrates against synthetic training curves written into the
    run; the validation trials' files (not synthesised there) are not looked for."""
    project = project_with(data, {"force": "force/bar-11.csv"}, w_displacement=0.0)
    project = project.model_copy(update={"calibration": project.calibration.model_copy(
        update={"truth": {"tau_c_MPa": 0.05}})})
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        problem = build_problem(project, tmp_path)
    assert set(problem.dataset.measurements) == {"bar-07"}
    assert (tmp_path / "truth-data" / "force" / "bar-07.csv").is_file()


def test_the_external_solvers_files_are_kept_absolute_and_must_exist(data: Path, tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "study.sdy").write_text("mesh\n")
    (tmp_path / "link.sdy").symlink_to(tmp_path / "study.sdy")
    # as JSON gives them; sorted, once each, absolute, a link kept as the link
    spec = ExternalSpec("python solver.py {params} {output}", files=["study.sdy", "link.sdy", "study.sdy"])
    assert spec.files == (str(tmp_path / "link.sdy"), str(tmp_path / "study.sdy")) and spec.missing() == []
    assert spec.to_json()["files"] == list(spec.files)
    with pytest.raises(ConfigError, match="not the one string"):
        ExternalSpec("python solver.py {params} {output}", files="study.sdy")  # type: ignore[arg-type]
    # a run without files records what it recorded before they existed
    assert "files" not in ExternalSpec("python solver.py {params} {output}").to_json()
    (tmp_path / "study.sdy").unlink()
    project = project_with(data, {"force": "force/bar-11.csv"})
    with pytest.raises(ConfigError, match="study.sdy .*are missing"):
        build_problem(project, tmp_path / "run", external=spec)
