"""The README's Python API example runs as written, from a folder holding `configs/`."""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import pytest

import smcbayes
from smcbayes.api import CalibrationResult, PosteriorResult

REPO = Path(__file__).resolve().parents[1]


def readme_example() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## Python API", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1
    return blocks[0]


def test_readme_example_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "configs").symlink_to(REPO / "configs")
    cwd = Path.cwd()
    os.chdir(tmp_path)
    try:
        namespace: dict = {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            exec(compile(readme_example(), "README.md", "exec"), namespace)
    finally:
        os.chdir(cwd)
    cal, post = namespace["cal"], namespace["post"]
    assert isinstance(cal, CalibrationResult) and isinstance(post, PosteriorResult)
    # the 10 of the optimisation, then the local search on the 1-D model
    assert cal.summary["evaluations"] == 10 + cal.summary["polish"]["evaluations"]
    assert set(post.table()) == {"tau_c_MPa", "m"}
    out = capsys.readouterr().out
    assert "best loss" in out and "tau_c_MPa: median" in out
    # the API wrote a run directory the command line can read
    assert (tmp_path / "runs" / "api-example" / "posterior" / "status.json").is_file()


def test_package_exposes_the_api_lazily() -> None:
    """The stage functions are reachable from the package, even once the subpackages of
    the same stages are imported (their names must not collide)."""
    import smcbayes.diagnose
    import smcbayes.posterior
    import smcbayes.report

    for name in ("calibrate", "sample_posterior", "diagnose_gap", "write_report", "load_project"):
        assert callable(getattr(smcbayes, name)), name
    assert smcbayes.calibrate is smcbayes.api.calibrate
    with pytest.raises(AttributeError):
        smcbayes.no_such_thing  # noqa: B018


def test_calibrate_takes_a_truth_and_diagnose_refuses_bad_effects_before_any_run(tmp_path: Path) -> None:
    """`truth=` makes a known-truth check (synthetic curves in the run); a misspelt effect
    stops the diagnosis before its stage starts."""
    from smcbayes.errors import ConfigError

    project = smcbayes.load_project(REPO / "configs" / "verify-slip-2d.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = smcbayes.calibrate(project, tmp_path / "run", fidelity="1d", budget=4, init=3, figures=False,
                                 truth={"tau_c_MPa": 0.02, "m": 1.4})
    assert cal.summary["truth"]["tau_c_MPa"] == 0.02
    assert (tmp_path / "run" / "truth-data" / "force").is_dir()
    with pytest.raises(ConfigError, match="unknown effect 'press_complience'.*press_compliance"):
        smcbayes.diagnose_gap(cal.run_dir, effects=["press_complience"])
    assert not (tmp_path / "run" / "diagnose").exists()
