"""The posterior command's printed summary."""

from __future__ import annotations

from typing import Any

import pytest

from smcbayes.commands.posterior import print_summary


def _info(confirmations: list[dict[str, Any]], converged: bool) -> dict[str, Any]:
    """A minimal curve-emulator summary."""
    return {"parameters": [], "correlation": {"strongest": []}, "bands": {},
            "emulator_check": {"points": 20, "mean_abs_error": 0.4, "max_abs_error": 1.2},
            "active_learning": {"kind": "curves", "error_nats": 0.5, "converged": converged,
                                "evaluations": 700, "start_runs": 60, "components": 6,
                                "confirmations": confirmations},
            "reliability": {"reliable": converged, "reasons": [] if converged else ["budget spent"]}}


def test_the_curve_emulator_line_counts_the_validations_its_reported_posterior_did_not_confirm(
        capsys: pytest.CaptureFixture[str]) -> None:
    print_summary(_info([{"passed": True}], True))
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("curve emulator:"))
    assert line.endswith("validated") and "700 forward runs (60 at the calibration's points)" in line
    print_summary(_info([{"passed": False}, {"passed": False}], False))
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("curve emulator:"))
    assert line.endswith("not validated (budget spent), 2 validation(s) not confirmed by the reported "
                         "posterior's spread")
    info = _info([{"passed": True}], True)
    info["active_learning"].update(start_runs=1, start_runs_from_calibration=59)
    print_summary(info)
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("curve emulator:"))
    assert "(1 at the calibration's points, the calibration's curves of 59 more reused)" in line


def test_the_table_prints_no_r_hat_for_an_importance_weighted_posterior(
        capsys: pytest.CaptureFixture[str]) -> None:
    """'-' in the R-hat column for an importance-weighted table (NaN in the stage's summary,
    null once read from ``summary.json``), the chains' R-hat where they are the posterior."""
    row = {"unit": "-", "mean": 0.4, "sd": 0.05, "q05": 0.3, "q50": 0.4, "q95": 0.5, "ess": 2500.0}
    info = {**_info([], True), "parameters": [{**row, "name": "n", "r_hat": float("nan")},
                                              {**row, "name": "m", "r_hat": None},
                                              {**row, "name": "k", "r_hat": 1.0123}]}
    print_summary(info)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[-2:] == ["R-hat", "ESS"]
    cells = {line.split()[0]: line.split()[-2:] for line in lines[1:4]}
    assert cells == {"n": ["-", "2500"], "m": ["-", "2500"], "k": ["1.012", "2500"]}
