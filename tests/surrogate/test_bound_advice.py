"""A calibrated parameter on a search bound is said, with what to do, in the terminal
(a warning), the calibration summary and the report."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import pytest

from smcbayes.errors import ContactOffsetWarning, ParameterOnBoundWarning
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.report.sections_run import bound_advice
from smcbayes.surrogate.calibration import on_bounds, warn_on_bounds

BEST = {"n": 0.6, "tau_star_Pa": 1e4, "B_Pa_s": 1e3, "tau_c_MPa": 0.05, "m": 1.5}
#: n on its built-in upper bound 0.6 (physical range to 1); B on 1e3 (physical range from 1e2)


def _on_bounds() -> list[dict]:
    problem = SimpleNamespace(space=ParameterSpace(BASE_PARAMETERS))
    return on_bounds(problem, BEST)  # type: ignore[arg-type]


def test_the_summary_names_each_parameter_on_a_bound_with_the_advice() -> None:
    found = {b["name"]: b for b in _on_bounds()}
    assert set(found) == {"n", "B_Pa_s"}
    assert found["n"]["bound"] == "upper" and found["n"]["limit"] == 0.6
    assert "the data want n above 0.6;" in found["n"]["advice"]
    assert "the data want B_Pa_s below 1000;" in found["B_Pa_s"]["advice"]
    assert "widen the bound in [parameters.n] (its physical range ends at 1)" in found["n"]["advice"]
    assert "add the missing physics" in found["n"]["advice"]
    assert found["B_Pa_s"]["physical_limit"] == 100.0


def test_a_bound_at_the_physical_limit_asks_for_physics_not_a_wider_box() -> None:
    problem = SimpleNamespace(space=ParameterSpace(BASE_PARAMETERS).with_bounds({"n": (0.2, 1.0)}))
    (b,) = on_bounds(problem, {**BEST, "n": 1.0, "B_Pa_s": 1e4})  # type: ignore[arg-type]
    assert "the end of its physical range (1), so do not widen the bound" in b["advice"]
    text = ParameterOnBoundWarning.advice("x", "lower", 1.0, 1.0)  # no known range
    assert "widen the bound in [parameters.x] if that is physical" in text


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


def test_the_report_also_names_the_trials_whose_contact_lies_beyond_the_bound() -> None:
    contact = [{"config_id": "c1", "offset_mm": 1.4, "bound_mm": 1.0,
                "advice": ContactOffsetWarning.advice("c1", 1.4, 1.0)}]
    texts = bound_advice({"on_bounds": _on_bounds(), "contact_on_bound": contact})
    assert texts[:-1] == [b["advice"] for b in _on_bounds()]
    assert texts[-1].startswith("c1: its end state puts its contact +1.40 mm from the nominal stack height")
