"""The forward-run cache: reuse by exact parameter row, durability across a cut line,
identity tags, and the runner's lookup before it simulates."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.forward.result import SimulationResult
from smcbayes.run import cache as cache_module
from smcbayes.run.cache import MODEL_PACKAGES, ForwardCache, cache_tag, file_digests, source_digest
from smcbayes.simulation.objective import Task, TaskResult
from smcbayes.simulation.runner import Runner


class _CurveObjective:
    """Analytic per-row errors and curves; counts the rows it evaluates."""

    def __init__(self) -> None:
        # the runner reads only the space's presence; two free parameters
        self.space = ParameterSpace(BASE_PARAMETERS, {"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 1e4})
        self.config_ids = ["c1", "c2"]
        self.rows = 0

    def evaluate(self, task: Task) -> TaskResult:
        self.rows += len(task.indices)
        th = task.theta
        err = (th[:, 0] - 0.3) ** 2 + (th[:, 1] - 1.1) ** 2 + (1.0 if task.config_id == "c2" else 0.0)
        curves = None
        if task.curves:
            t = np.tile(np.linspace(0.0, 1.0, 5), (len(th), 1))
            f = th[:, :1] * t
            curves = SimulationResult(task.config_id, t, f.copy(), f.copy(), f.copy(), f.copy(), f.copy(),
                                      np.zeros_like(t, dtype=np.int8), th[:, 1].copy(), ["ok"] * len(th))
        return TaskResult(task.indices, task.config_id, err, err * 2, err * 3, ["ok"] * len(th), 0.0, curves)


@pytest.fixture
def objective() -> _CurveObjective:
    return _CurveObjective()


def test_runner_reuses_rows_across_instances(tmp_path: Path, objective: _CurveObjective) -> None:
    rng = np.random.default_rng(0)
    theta = rng.uniform(0, 2, (6, 2))
    plain = Runner(objective).errors(theta)
    objective.rows = 0
    first = Runner(objective, cache=ForwardCache(tmp_path, "t"))
    np.testing.assert_array_equal(first.errors(theta[:4]), plain[:4])
    assert objective.rows == 8 and first.forward_runs_made == 8
    first.cache.close()  # type: ignore[union-attr]
    # a new process: rows 0-3 are read back, only 4-5 are simulated
    objective.rows = 0
    second = Runner(objective, cache=ForwardCache(tmp_path, "t"))
    np.testing.assert_array_equal(second.errors(theta), plain)
    assert objective.rows == 4
    assert (second.forward_runs, second.forward_runs_reused, second.forward_runs_made) == (12, 8, 4)


def test_curves_kept_and_errors_only_rows_rerun_for_curves(tmp_path: Path,
                                                           objective: _CurveObjective) -> None:
    theta = np.array([[0.5, 1.0], [1.5, 0.2], [0.1, 1.9]])
    plain = Runner(objective).simulate(theta, ["c1"])["c1"]
    Runner(objective, cache=ForwardCache(tmp_path, "t")).errors(theta[:1], ["c1"])
    objective.rows = 0
    cached = Runner(objective, cache=ForwardCache(tmp_path, "t"))
    got = cached.simulate(theta, ["c1"])["c1"]
    assert objective.rows == 3  # errors alone cannot give curves
    objective.rows = 0
    again = Runner(objective, cache=ForwardCache(tmp_path, "t")).simulate(theta, ["c1"])["c1"]
    assert objective.rows == 0
    for res in (got, again):
        np.testing.assert_array_equal(res.force_kN, plain.force_kN)
        np.testing.assert_array_equal(res.switch_time_s, plain.switch_time_s)
        assert res.status == plain.status and res.phase.dtype == np.int8


def test_an_earlier_stages_runs_are_read_and_never_written(tmp_path: Path,
                                                           objective: _CurveObjective) -> None:
    theta = np.array([[0.5, 1.0], [1.5, 0.2], [0.1, 1.9]])
    plain = Runner(objective).simulate(theta, ["c1", "c2"])
    earlier = Runner(objective, cache=ForwardCache(tmp_path / "earlier", "t"))
    earlier.simulate(theta[:2], ["c1", "c2"])
    earlier.cache.close()  # type: ignore[union-attr]
    before = (tmp_path / "earlier" / "t.jsonl").read_bytes()
    objective.rows = 0
    cache = ForwardCache(tmp_path / "own", "t", earlier=ForwardCache(tmp_path / "earlier", "t"))
    np.testing.assert_array_equal(cache.holds(["c1", "c2"], theta), [True, True, False])
    assert not cache.holds(["c1", "c2", "c3"], theta[:1])[0]
    runner = Runner(objective, cache=cache)
    got = runner.simulate(theta, ["c1", "c2"])
    assert objective.rows == 2 and runner.forward_runs_reused == 4  # the third row on both
    for cid in ("c1", "c2"):
        np.testing.assert_array_equal(got[cid].force_kN, plain[cid].force_kN)
    cache.close()
    assert (tmp_path / "earlier" / "t.jsonl").read_bytes() == before
    # the new row is this stage's own
    assert ForwardCache(tmp_path / "own", "t").holds(["c1", "c2"], theta).tolist() == [False, False, True]
    # a row whose curves file is gone is not held
    next((tmp_path / "own").glob("t-*.npz")).unlink()
    assert not ForwardCache(tmp_path / "own", "t").holds(["c1", "c2"], theta[2:]).any()


def test_an_earlier_cache_is_read_only_and_of_the_same_model(tmp_path: Path,
                                                            objective: _CurveObjective) -> None:
    theta = np.array([[0.5, 1.0], [1.5, 0.2]])
    first = Runner(objective, cache=ForwardCache(tmp_path / "earlier", "t"))
    first.simulate(theta, ["c1"])
    first.cache.close()  # type: ignore[union-attr]
    log = tmp_path / "earlier" / "t.jsonl"
    with log.open("ab") as fh:  # a line a kill cut short
        fh.write(b'{"k": "cut')
    damaged = log.read_bytes()
    earlier = ForwardCache(tmp_path / "earlier", "t", read_only=True)
    assert log.read_bytes() == damaged and earlier.holds(["c1"], theta).all()
    with pytest.raises(ValueError, match="read only"):
        earlier.begin(1)
    with pytest.raises(ValueError, match="another model"):
        ForwardCache(tmp_path / "own", "u", earlier=earlier)


def test_cut_line_is_dropped_and_appends_stay_readable(tmp_path: Path, objective: _CurveObjective) -> None:
    theta = np.array([[0.5, 1.0], [1.5, 0.2]])
    cache = ForwardCache(tmp_path, "t")
    Runner(objective, cache=cache).errors(theta)
    cache.close()
    with cache.path.open("a", encoding="utf-8") as fh:
        fh.write('{"k": "abc", "c": "c1", "e": 1.')  # a kill in the middle of a line
    cache = ForwardCache(tmp_path, "t")
    assert len(cache) == 4 and cache.stats().started == 4
    Runner(objective, cache=cache).errors(theta + 0.1)
    cache.close()
    reread = ForwardCache(tmp_path, "t")
    assert len(reread) == 8 and reread.stats().stored == 8


def test_failed_rows_are_not_kept(tmp_path: Path, objective: _CurveObjective) -> None:
    cache = ForwardCache(tmp_path, "t")
    task = Task((0, 1), np.array([[0.5, 1.0], [1.5, 0.2]]), "c1")
    cache.store(TaskResult.failed(task, "worker process died"), task.theta)
    assert len(cache) == 0
    assert cache.lookup("c1", task.theta, False) == [None, None]


def test_tags_separate_runs_and_models() -> None:
    ident = {"project": {"name": "a"}, "effects": None}
    assert cache_tag(ident) == cache_tag(dict(ident))
    assert cache_tag(ident) != cache_tag({**ident, "project": {"name": "b"}})
    assert cache_tag(ident) != cache_tag(ident, ("press_compliance",))


def test_the_tag_changes_with_the_model_code(monkeypatch: pytest.MonkeyPatch) -> None:
    """A fixed forward model must not read what its earlier code cached, although the
    package's version is unchanged."""
    ident = {"project": {"name": "a"}}
    before = cache_tag(ident)
    monkeypatch.setattr(cache_module, "model_source", lambda: "another model")
    assert cache_tag(ident) != before


def test_the_source_digest_follows_every_model_file(tmp_path: Path) -> None:
    assert source_digest(tmp_path) == "unknown"
    for package in MODEL_PACKAGES:
        (tmp_path / package / "sub").mkdir(parents=True)
        (tmp_path / package / "sub" / "law.py").write_text("K = 1\n")
    (tmp_path / "report.py").write_text("X = 1\n")  # outside the model: not hashed
    first = source_digest(tmp_path)
    (tmp_path / "report.py").write_text("X = 2\n")
    assert source_digest(tmp_path) == first
    (tmp_path / "forward" / "sub" / "law.py").write_text("K = 2\n")
    assert source_digest(tmp_path) not in (first, "unknown")


def test_the_tag_follows_the_external_solvers_files(tmp_path: Path) -> None:
    """The files an external solver depends on join the tag by their contents; a run
    without them keeps the tag it had before they existed."""
    study = tmp_path / "study.sdy"
    study.write_text("mesh 1\n")
    plain = {"project": {"name": "a"}, "external": {"command": "solve {params} {output}"}}
    with_files = {**plain, "external": {**plain["external"], "files": [str(study)]}}
    first = cache_tag(with_files)
    assert first != cache_tag(plain) and cache_tag(with_files) == first
    study.write_text("mesh 2\n")
    second = cache_tag(with_files)
    assert second not in (first, cache_tag(plain))
    study.unlink()
    assert file_digests([str(study)]) == {str(study): "missing"}
    assert cache_tag(with_files) not in (first, second)


def test_a_cache_names_the_other_models_runs_beside_it_not_its_own(tmp_path: Path) -> None:
    cache = ForwardCache(tmp_path / "forward_cache", "a" * 16)
    assert cache.other_models() == []
    (tmp_path / "forward_cache").mkdir()
    (tmp_path / "forward_cache" / f"{'a' * 16}.jsonl").write_text("")
    assert cache.other_models() == []
    (tmp_path / "forward_cache" / f"{'b' * 16}.jsonl").write_text("")
    assert cache.other_models() == ["b" * 16]


def test_a_run_directorys_tag_ignores_its_projects_stage_tables(tmp_path: Path) -> None:
    """A resume rewrites the run's project with its stage tables; those do not change a
    forward run, so the run's caches keep their tag."""
    import json

    from smcbayes.run.directory import RunDir

    project = {"name": "a", "calibration": {"polish": 600}, "posterior": {"walkers": 32}}
    ident = {"project": project, "effects": None, "overrides": {}, "fidelity": None, "external": None}
    run = RunDir(tmp_path / "run")
    run.root.mkdir()
    (run.root / "config.json").write_text(json.dumps(ident))
    before = run.forward_cache("posterior").tag
    edited = {**project, "calibration": {"polish": 50}, "posterior": {"walkers": 64}}
    (run.root / "config.json").write_text(json.dumps({**ident, "project": edited}))
    assert run.forward_cache("posterior").tag == before
    (run.root / "config.json").write_text(json.dumps({**ident, "project": {**edited, "name": "b"}}))
    assert run.forward_cache("posterior").tag != before
