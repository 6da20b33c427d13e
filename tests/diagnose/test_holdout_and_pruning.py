"""The diagnosis's default held-out set for groups of two speeds, and the effects left out
of the forward selection because they cannot absorb the gap."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from smcbayes.diagnose import run
from smcbayes.diagnose.fit import Fit


def _ctx(specs: dict[str, tuple[str, float, float]]) -> Any:
    """A context whose project knows each id's (shape, coverage %, speed mm/s)."""
    def get(cid: str) -> Any:
        shape, cov, speed = specs[cid]
        return SimpleNamespace(charge=SimpleNamespace(shape=shape, coverage_pct=cov),
                               press=SimpleNamespace(speed_mm_s=speed))
    return SimpleNamespace(ids=list(specs), project=SimpleNamespace(get=get))


def test_groups_of_three_give_their_middle_speed() -> None:
    ctx = _ctx({f"{c}-{s}": (c.split("-")[1], float(c[:2]), sp)
                for c in ("60-bar", "80-bar") for s, sp in (("03", 0.3), ("07", 0.7), ("11", 1.1))})
    assert run.default_holdout(ctx) == ["60-bar-07", "80-bar-07"]


def test_groups_of_two_are_tested_at_both_speeds() -> None:
    # a leave-one-speed-out training set: every group has two speeds left
    ctx = _ctx({f"{c}-{s}": (c.split("-")[1], float(c[:2]), sp)
                for c in ("60-bar", "60-center", "80-bar") for s, sp in (("03", 0.3), ("11", 1.1))})
    held = run.default_holdout(ctx)
    assert len(held) == 3
    # one per group, and both speeds appear among the held-out and the fitted trials
    assert sorted(h.rsplit("-", 1)[0] for h in held) == ["60-bar", "60-center", "80-bar"]
    speeds = {h.rsplit("-", 1)[1] for h in held}
    fitted = {c.rsplit("-", 1)[1] for c in ctx.ids if c not in held}
    assert speeds == fitted == {"03", "11"}


def test_single_members_stay_in_the_fit() -> None:
    ctx = _ctx({"a": ("bar", 60.0, 0.3), "b": ("bar", 60.0, 0.7), "c": ("center", 60.0, 0.3)})
    assert run.default_holdout(ctx) == ["b"]
    lone = _ctx({"a": ("bar", 60.0, 0.3), "b": ("center", 60.0, 0.7), "c": ("bar", 80.0, 0.3)})
    assert run.default_holdout(lone) == ["b"]


def _row(effect: str, share: float, shrink: float, score: float) -> dict[str, Any]:
    return {"effect": effect, "absorbable_share": share, "holdout_shrink_pct": shrink, "score": score}


def test_inert_needs_both_no_absorption_and_no_shrink() -> None:
    assert run.inert(_row("heating", 0.0, 0.0002, -6.0))
    assert not run.inert(_row("heating", 0.0, 3.0, -6.0))       # it did shrink the held-out loss
    assert not run.inert(_row("speed_ramp", 0.6, -20.0, -6.0))  # its curves can absorb the gap
    assert not run.inert(_row("x", 0.0, float("nan"), -6.0))    # a failed fit is not evidence
    # moving the curves the wrong way alone is moving them: tried with another effect on
    assert not run.inert(_row("press_compliance", -0.21, -13.7, -4.3))
    assert not run.inert(_row("press_compliance", -0.21, 0.5, -4.3))
    assert not run.inert(_row("press_compliance", 0.005, -13.7, -4.3))


def test_inert_effects_are_not_tried_in_the_selection(monkeypatch) -> None:
    seen: dict[str, Any] = {}

    def forward_selection(ctx: Any, first: Fit, candidates: list[str], *args: Any) -> Any:
        seen["candidates"] = list(candidates)
        return list(first.effects), [], {}

    monkeypatch.setattr(run, "forward_selection", forward_selection)
    rows = [_row("compressibility", 0.9, 95.0, 11.0), _row("press_compliance", 0.5, 80.0, 6.0),
            _row("heating", 0.0, 0.0001, -6.0), _row("curing", 0.0, -0.01, -10.0)]
    fits = {"compressibility": Fit(("compressibility",), {}, np.zeros((1, 1)), 1.0, 1)}
    lines: list[str] = []
    selected, _, _, left_out = run._select(
        None, run.DiagnoseSettings(candidates=("compressibility",)), {"best": "compressibility"}, rows,
        fits, (["f"], ["h"]), {"n_eff_fit": 10.0, "n_eff_holdout": 10.0}, np.random.default_rng(0),
        lines.append)
    assert seen["candidates"] == ["press_compliance"]
    assert left_out == ["heating", "curing"] and selected == ["compressibility"]
    assert any("heating, curing not tried" in line for line in lines)
