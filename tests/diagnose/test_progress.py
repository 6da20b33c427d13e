"""The diagnosis reports progress per re-calibration and logs its steps; it prints nothing."""

from __future__ import annotations

import logging

from smcbayes import progress
from smcbayes.diagnose.run import DiagnoseSettings, diagnose

from .conftest import TINY


def test_diagnosis_progress_names_each_effect_and_its_generations(synthetic_ctx, capsys,
                                                                  caplog) -> None:
    ctx = synthetic_ctx("press_compliance")
    settings = DiagnoseSettings(candidates=("press_compliance", "heating"), seed=1, fit=TINY,
                                figures=False)
    progress.enable(True, interval_s=0.0)
    try:
        with caplog.at_level(logging.INFO):
            summary = diagnose(ctx, settings, None)
    finally:
        progress.enable(False)
    assert capsys.readouterr().err == ""
    lines = [r.getMessage() for r in caplog.records if r.name == "smcbayes.progress"]
    for desc in ("diagnosis: base model (1/3)", "diagnosis: press_compliance (2/3)",
                 "diagnosis: heating (3/3)"):
        mine = [ln for ln in lines if ln.startswith(desc + ":")]
        # one line per batched forward call: every generation of the evolution is reported
        assert len(mine) >= TINY.generations + 1, (desc, lines)
        assert "generation 0/" in mine[0] and "restart 1/1" in mine[0] and "kN^2" in mine[0]
    steps = [r.getMessage() for r in caplog.records if r.name == "smcbayes.diagnose.run"]
    assert steps[0].startswith("where: ") and summary["decision"]["statement"] in steps
    # forward selection follows the decision: the selected set is searched again, then each
    # remaining candidate is tried with it
    after = steps[steps.index(summary["decision"]["statement"]) + 1:]
    assert all(s.startswith(("selection: ", "selected effect set: ")) for s in after)
    # the truth has the frame's compliance only: heating must not join it
    assert summary["selected_effects"] == ["press_compliance"]
    assert any(s.startswith("heating: absorbable") for s in steps)
