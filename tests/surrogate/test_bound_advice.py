"""A calibrated parameter on a search bound is said, with what to do, in the terminal
(a warning), the calibration summary and the report."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import pytest

from smcbayes.errors import ParameterOnBoundWarning
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.report.sections_run import bound_advice
from smcbayes.surrogate.calibration import on_bounds, warn_on_bounds

BEST = {"n": 0.6, "tau_star_Pa": 1e4, "B_Pa_s": 1e3, "tau_c_MPa": 0.05, "m": 1.5}


def _on_bounds() -> list[dict]:
    problem = SimpleNamespace(space=ParameterSpace(BASE_PARAMETERS))
    return on_bounds(problem, BEST)  # type: ignore[arg-type]


def test_the_summary_names_each_parameter_on_a_bound_with_the_advice() -> None:
    found = {b["name"]: b for b in _on_bounds()}
    assert set(found) == {"n", "B_Pa_s"}
    assert found["n"]["bound"] == "upper" and found["n"]["limit"] == 0.6
    assert "the data want n above 0.6;" in found["n"]["advice"]
    assert "the data want B_Pa_s below 1000;" in found["B_Pa_s"]["advice"]
    assert "widen the bound in [parameters.n]" in found["n"]["advice"]
    assert "add the missing physics" in found["n"]["advice"]


def test_the_warning_carries_the_advice() -> None:
    with pytest.warns(ParameterOnBoundWarning, match=r"the data want n above 0\.6; widen the bound"):
        warn_on_bounds({"on_bounds": _on_bounds()})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_on_bounds({"on_bounds": []})  # nothing on a bound: silent


def test_the_report_says_it_also_for_summaries_written_without_the_advice() -> None:
    old = [{k: v for k, v in b.items() if k != "advice"} for b in _on_bounds()]
    texts = bound_advice({"on_bounds": old})
    assert texts == [b["advice"] for b in _on_bounds()]
    assert bound_advice({}) == []
