"""External-simulator adapter with a real external command (a script on the Python API)."""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from smcbayes.cli import main
from smcbayes.config import load_project
from smcbayes.simulation.executors.external import ExternalSimulator
from smcbayes.simulation.objective import SimulatorObjective, Task
from smcbayes.simulation.problem import build_problem

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "verify-slip-2d.toml"

SCRIPT = textwrap.dedent('''
    """A user's simulator wrapper: params.json in, curves CSV out."""
    import json, sys
    import numpy as np
    from smcbayes.config import load_project
    from smcbayes.forward.model import ForwardModel

    params_file, output, config = sys.argv[1:4]
    job = json.load(open(params_file))
    with open(config + ".calls", "a") as fh:  # one line per run: proves who simulated
        fh.write(job["config_id"] + "\\n")
    model = ForwardModel(load_project(config))
    cid = job["config_id"]
    res = model.simulate_params({k: np.array([v]) for k, v in job["parameters"].items()}, [cid])[cid]
    if output.endswith(".xml"):  # Moldflow-style result: force in N
        from smcbayes.data.readers.moldflow import write_moldflow
        write_moldflow(output, "Clamp force", res.time_s[0], res.force_kN[0] * 1e3, "N", "Force")
        sys.exit(0)
    with open(output, "w") as fh:
        fh.write("time_s,force_kN,displacement_mm\\n")
        for t, f, d in zip(res.time_s[0], res.force_kN[0], res.displacement_mm[0]):
            fh.write(f"{t:.12g},{f:.12g},{d:.12g}\\n")
''')


def one_config(tmp: Path) -> Path:
    """verify-slip-2d reduced to its first configuration."""
    text = CONFIG.read_text()
    head, _, rest = text.partition("[[configuration]]")
    first = "[[configuration]]" + rest.split("[[configuration]]")[0]
    path = tmp / "one.toml"
    path.write_text(head + first)
    return path


@pytest.fixture()
def script(tmp_path: Path) -> Path:
    path = tmp_path / "my_solver.py"
    path.write_text(SCRIPT)
    return path


def test_external_matches_native(tmp_path: Path, script: Path) -> None:
    config = one_config(tmp_path)
    problem = build_problem(load_project(config), tmp_path / "run")
    cmd = f"{sys.executable} {script} {{params}} {{output}} {config}"
    ext = ExternalSimulator(problem.project, problem.model.space, cmd, tmp_path / "work", 120.0)
    obj = SimulatorObjective(ext, problem.objective.dataset, problem.train_ids, problem.project.loss)
    theta = np.array([[0.02, 1.2], [0.3, 1.8]])
    cid = problem.train_ids[0]
    native = problem.objective.evaluate(Task((0, 1), theta, cid))
    external = obj.evaluate(Task((0, 1), theta, cid))
    assert external.status == ["ok", "ok"]
    np.testing.assert_allclose(external.error, native.error, rtol=1e-3)
    job = json.loads(next((tmp_path / "work").glob("*/params.json")).read_text())
    assert job["units"]["tau_c_MPa"] == "MPa" and job["parameters"]["n"] == 0.4


def test_external_moldflow_output(tmp_path: Path, script: Path) -> None:
    config = one_config(tmp_path)
    problem = build_problem(load_project(config), tmp_path / "run")
    cmd = f"{sys.executable} {script} {{params}} {{output}} {config}"
    ext = ExternalSimulator(problem.project, problem.model.space, cmd, tmp_path / "work", 120.0,
                            output_format="moldflow")
    obj = SimulatorObjective(ext, problem.objective.dataset, problem.train_ids, problem.project.loss)
    theta = np.array([[0.05, 1.4]])
    cid = problem.train_ids[0]
    external = obj.evaluate(Task((0,), theta, cid))
    assert external.status == ["ok"]
    assert list((tmp_path / "work").glob("*/curves.xml"))
    np.testing.assert_allclose(external.error, problem.objective.evaluate(Task((0,), theta, cid)).error,
                               rtol=1e-3)


def test_external_failures_have_reasons(tmp_path: Path) -> None:
    config = one_config(tmp_path)
    problem = build_problem(load_project(config), tmp_path / "run")
    cid = problem.train_ids[0]
    space = problem.model.space
    fail = ExternalSimulator(problem.project, space, f"{sys.executable} -c \"import sys; sys.exit(3)\"",
                             tmp_path / "w1", 30.0)
    slow = ExternalSimulator(problem.project, space, f"{sys.executable} -c \"import time; time.sleep(20)\"",
                             tmp_path / "w2", 0.5)
    for sim, reason in ((fail, "exited with 3"), (slow, "timed out after 0.5 s")):
        obj = SimulatorObjective(sim, problem.objective.dataset, problem.train_ids)
        res = obj.evaluate(Task((0,), np.array([[0.02, 1.2]]), cid))
        assert res.status[0].startswith("failed") and reason in res.status[0]
        assert np.isnan(res.error[0])


def test_calibrate_with_external_command(tmp_path: Path, script: Path) -> None:
    config = one_config(tmp_path)
    out = tmp_path / "run"
    cmd = f"{sys.executable} {script} {{params}} {{output}} {config}"
    code = main(["calibrate", str(config), "--out", str(out), "--budget", "3", "--init", "2",
                 "--external", cmd, "--no-figures"])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["evaluations"] == 3 and summary["failures"] == 0
    assert len(list((out / "work").glob("*/curves.csv"))) == 3


def test_posterior_of_an_external_run_uses_the_external_command(tmp_path: Path, script: Path) -> None:
    """Every forward run of the posterior stage is a call of the run's external command."""
    config = one_config(tmp_path)
    out = tmp_path / "run"
    cmd = f"{sys.executable} {script} {{params}} {{output}} {config}"
    assert main(["calibrate", str(config), "--out", str(out), "--budget", "4", "--init", "3",
                 "--external", cmd, "--no-figures"]) == 0
    calls = Path(str(config) + ".calls")
    before = len(calls.read_text().splitlines())
    # the log-loss emulator, whose stage without learning makes no run but these below
    assert main(["posterior", str(out), "--emulator", "loss", "--walkers", "8",
                 "--steps", "60", "--functions",
                 "0", "--draws", "2", "--refine", "0"]) == 0
    info = json.loads((out / "posterior" / "summary.json").read_text())
    made = len(calls.read_text().splitlines()) - before
    assert info["simulator"] == "external"
    assert made == info["forward_runs_made"] > 0
    # sensitivities (2 d + 1 = 5), emulator check and bands (2 draws each) on the one
    # configuration; the best point's run is the calibration's, kept with its curves, and
    # read again for the bands' error model
    assert made == 5 + 2 + 2 - 1
    assert info["simulator_runs"] == made + info["forward_runs_reused"] == made + 2
    assert json.loads((out / "posterior" / "status.json").read_text())["state"] == "complete"


def _quantiles(run: Path) -> np.ndarray:
    info = json.loads((run / "posterior" / "summary.json").read_text())
    return np.array([[p[k] for k in ("q05", "q50", "q95")] for p in info["parameters"]])


@pytest.mark.parametrize("emulator", ["curves", "loss"])
def test_external_run_gives_the_native_posterior(tmp_path: Path, script: Path, emulator: str) -> None:
    """The same calibration and posterior, once with the native model in process and once
    with an external command that wraps it, with either emulator (the data are a truth
    check's, on which ``auto`` takes the log-loss one): the same numbers (up to the 12
    digits of the exchanged CSV), and every forward run of the external posterior is a
    counted call."""
    config = one_config(tmp_path)
    cmd = f"{sys.executable} {script} {{params}} {{output}} {config}"
    runs = {"native": tmp_path / "native", "external": tmp_path / "external"}
    for kind, out in runs.items():
        extra = ["--external", cmd] if kind == "external" else []
        # the same calibration: the native model's default local search left out
        assert main(["calibrate", str(config), "--out", str(out), "--budget", "5", "--init", "3",
                     "--seed", "2", "--polish", "0", "--no-figures", *extra]) == 0
    calls = Path(str(config) + ".calls")
    before = len(calls.read_text().splitlines())
    for out in runs.values():
        assert main(["posterior", str(out), "--emulator", emulator, "--walkers", "8", "--steps", "80",
                     "--functions", "0", "--refine", "9", "--draws", "2", "--correct-draws", "0",
                     "--seed", "3"]) == 0
    made = len(calls.read_text().splitlines()) - before
    ext = json.loads((runs["external"] / "posterior" / "summary.json").read_text())
    nat = json.loads((runs["native"] / "posterior" / "summary.json").read_text())
    assert ext["settings"]["emulator"] == nat["settings"]["emulator"] == emulator
    assert made == ext["forward_runs_made"] == nat["forward_runs_made"] > 0
    assert ext["forward_evaluations"] == nat["forward_evaluations"]
    np.testing.assert_allclose(_quantiles(runs["external"]), _quantiles(runs["native"]), rtol=1e-6)


def test_the_external_solvers_files_decide_which_runs_are_reused(tmp_path: Path, script: Path,
                                                                  capsys: pytest.CaptureFixture) -> None:
    """With ``--external-file`` the caches' tag follows the solver's files: after the script
    changes behind the same command line, the calibration's runs are not reused, a resume
    that would mix both solvers' evaluations is refused and the posterior stage says why."""
    from smcbayes.errors import StaleRunsWarning
    from smcbayes.posterior.context import load_run
    from smcbayes.posterior.stage import PosteriorSettings, _begin
    from smcbayes.run.directory import RunDir

    config = one_config(tmp_path)
    out = tmp_path / "run"
    cmd = f"{sys.executable} {script} {{params}} {{output}} {config}"
    assert main(["calibrate", str(config), "--out", str(out), "--budget", "3", "--init", "2",
                 "--external", cmd, "--external-file", str(script), "--no-figures"]) == 0
    recorded = RunDir(out).identity().external
    assert recorded is not None and recorded["files"] == [str(script)]
    assert len(RunDir(out).calibration_cache(read_only=True)) == 3
    assert load_run(out).stale_calibration_runs is None
    script.write_text(SCRIPT + "# the solver's study file changed\n")
    fresh = RunDir(out).calibration_cache(read_only=True)
    assert len(fresh) == 0 and len(fresh.other_models()) == 1
    assert RunDir(out).changed_external_files() == [str(script)]
    capsys.readouterr()
    assert main(["calibrate", "--out", str(out), "--resume", "--budget", "4"]) == 2
    assert "changed since the run began" in capsys.readouterr().err
    ctx = load_run(out)
    assert ctx.stale_calibration_runs is not None and "my_solver.py changed" in ctx.stale_calibration_runs
    with pytest.warns(StaleRunsWarning, match="are of another model"):
        _begin(ctx, PosteriorSettings(emulator="loss", correct_draws=0))
    # a bare resume does not drop a file it is given without its command
    assert main(["calibrate", "--out", str(out), "--resume", "--external-file", str(script)]) == 2
    assert "give --external COMMAND too" in capsys.readouterr().err


def test_an_external_file_must_exist_and_needs_the_external_command(tmp_path: Path, script: Path,
                                                                     capsys: pytest.CaptureFixture) -> None:
    config = one_config(tmp_path)
    cmd = f"{sys.executable} {script} {{params}} {{output}} {config}"
    assert main(["calibrate", str(config), "--out", str(tmp_path / "a"), "--external", cmd,
                 "--external-file", str(tmp_path / "study.sdy")]) == 2
    assert "study.sdy: no such file" in capsys.readouterr().err
    assert main(["calibrate", str(config), "--out", str(tmp_path / "b"),
                 "--external-file", str(script)]) == 2
    assert "give --external COMMAND too" in capsys.readouterr().err
