"""Notes on the shape of a posterior sample and the verdict of noise-free training data."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from smcbayes.config import build_project
from smcbayes.forward.model import ForwardModel
from smcbayes.posterior.context import RunContext
from smcbayes.posterior.reliability import assess
from smcbayes.posterior.shape import bimodal_split, shape_notes

RAW = {"name": "t", "configuration": [{"id": "a", "charge": {"shape": "bar", "coverage_pct": 60.0},
                                       "press": {"speed_mm_s": 0.5}}]}


def _space():
    return ForwardModel(build_project(RAW, "<t>", Path("."))).space


def test_a_unimodal_sample_gets_no_note() -> None:
    space = _space()
    unit = np.random.default_rng(0).uniform(0.3, 0.5, size=(4000, space.dim))
    assert shape_notes(space, unit) == []


def test_mass_at_a_bound_is_named_with_what_to_do() -> None:
    space = _space()
    rng = np.random.default_rng(1)
    unit = rng.uniform(0.3, 0.5, size=(4000, space.dim))
    unit[:, 0] = 1.0 - rng.uniform(0.0, 0.2, 4000) ** 2  # piled against the upper bound
    notes = shape_notes(space, unit)
    name = space.free_names[0]
    assert len(notes) == 1 and f"posterior of {name} piles up at its upper bound" in notes[0]
    assert "widen the bound" in notes[0]


def test_mass_at_the_end_of_the_physical_range_asks_for_physics_not_a_wider_bound() -> None:
    raw = {**RAW, "parameters": {"n": {"value": 0.5, "bounds": [0.2, 1.0]}}}  # 1: a Newtonian bulk
    space = ForwardModel(build_project(raw, "<t>", Path("."))).space
    rng = np.random.default_rng(1)
    unit = rng.uniform(0.3, 0.5, size=(4000, space.dim))
    k = space.free_names.index("n")
    unit[:, k] = 1.0 - rng.uniform(0.0, 0.2, 4000) ** 2
    (note,) = shape_notes(space, unit)
    assert "posterior of n piles up at its upper bound" in note
    assert "end of its physical range (1), so do not widen the bound" in note


def test_a_wide_posterior_is_not_said_to_pile_at_a_bound() -> None:
    space = _space()
    unit = np.random.default_rng(2).uniform(0.0, 1.0, size=(4000, space.dim))
    assert not any("bound" in n for n in shape_notes(space, unit))


def test_two_separated_modes_are_found_and_one_is_not() -> None:
    rng = np.random.default_rng(3)
    two = np.concatenate([rng.normal(0.25, 0.04, 3000), rng.normal(0.7, 0.04, 1500)])
    split = bimodal_split(two)
    assert split is not None and 0.35 < split < 0.6
    assert bimodal_split(rng.normal(0.5, 0.1, 4000)) is None
    # a small bump (5 % of the mass) is not a mode
    bump = np.concatenate([rng.normal(0.3, 0.05, 3800), rng.normal(0.8, 0.02, 200)])
    assert bimodal_split(bump) is None


def test_a_ridge_is_named() -> None:
    space = _space()
    rng = np.random.default_rng(4)
    unit = rng.uniform(0.3, 0.5, size=(4000, space.dim))
    unit[:, 1] = unit[:, 0] + rng.normal(0.0, 0.005, 4000)
    notes = shape_notes(space, unit)
    names = space.free_names
    assert len(notes) == 1 and f"{names[0]} and {names[1]} lie on a ridge" in notes[0]


def test_notes_are_kept_beside_the_verdict() -> None:
    space = _space()
    narrow = [{"name": p.name, "q05": p.lower + 0.4 * (p.upper - p.lower),
               "q95": p.lower + 0.5 * (p.upper - p.lower), "r_hat": 1.01} for p in space.free]
    info = {"parameters": narrow, "shape": ["a note"],
            "correction": {"enabled": True, "k_hat": 0.2, "ess": 2500, "settled": True}}
    assert assess(info, space, 10.0) == {"reliable": True, "reasons": [], "notes": ["a note"]}
    noise_free = assess(info, space, 10.0, noise_free=True)
    assert not noise_free["reliable"] and "noise-free" in noise_free["reasons"][0]


def _context(project_raw: dict, folder: Path) -> RunContext:
    project = build_project(project_raw, "<t>", folder)
    problem = SimpleNamespace(project=project)
    return RunContext(None, problem, {}, np.zeros((1, 1)), None)  # type: ignore[arg-type]


def test_noise_free_data_are_recognised(tmp_path: Path) -> None:
    truth_check = {**RAW, "calibration": {"truth": {"m": 1.5}}}
    assert _context(truth_check, tmp_path).noise_free
    data = tmp_path / "data"
    data.mkdir()
    raw = {**RAW, "data_dir": "data"}
    assert not _context(raw, tmp_path).noise_free  # measured: no truth.json
    (data / "truth.json").write_text(json.dumps({"noise": {"white_kN": 0.0, "correlated_kN": 0.0,
                                                           "resolution_kN": 0.0, "white_mm": 0.01}}))
    assert _context(raw, tmp_path).noise_free
    (data / "truth.json").write_text(json.dumps({"noise": {"white_kN": 5.0, "correlated_kN": 0.0}}))
    assert not _context(raw, tmp_path).noise_free


def test_noise_free_data_is_the_one_reason_given() -> None:
    """Failed sampling diagnostics follow from the spike; their remedies are not repeated."""
    space = _space()
    info = {"parameters": [{"name": p.name, "q05": p.lower, "q95": p.lower, "r_hat": 1.6}
                           for p in space.free],
            "correction": {"enabled": True, "k_hat": 1.9, "ess": 7, "settled": False}}
    assert len(assess(info, space, 3.0)["reasons"]) == 1  # k-hat
    verdict = assess(info, space, 3.0, noise_free=True)
    assert verdict["reasons"] == [verdict["reasons"][0]] and "noise-free" in verdict["reasons"][0]


def test_a_curve_emulator_out_of_budget_names_its_last_rounds_and_spread() -> None:
    space = _space()
    narrow = [{"name": p.name, "q05": p.lower + 0.4 * (p.upper - p.lower),
               "q95": p.lower + 0.5 * (p.upper - p.lower), "r_hat": 1.01} for p in space.free]
    active = {"enabled": True, "kind": "curves", "converged": False, "evaluations": 640, "rounds": 16,
              "tolerance_nats": 1.0,
              "last_errors_nats": [0.7, None, 0.9], "last_quantile_shifts": [0.02, 0.03, None],
              "last_spreads": [0.08, 0.23, None]}
    info = {"parameters": narrow, "active_learning": active, "emulator_check": {"mean_abs_error": 0.5},
            "correction": {"enabled": True, "target": "emulator", "k_hat": 0.2, "ess": 2500, "settled": True}}
    verdict = assess(info, space, 10.0)
    assert not verdict["reliable"] and len(verdict["reasons"]) == 1
    reason = verdict["reasons"][0]
    assert "640 forward runs" in reason and "0.7 nats, not measured, 0.9 nats" in reason
    assert "0.02, 0.03, not measured" in reason
    assert "moving a quantile by 0.08, 0.23, not measured, their mean" in reason
    assert reason.endswith("raise --refine") and "rounds last passed" not in reason
    assert "over those rounds" not in reason  # no drift measured: the rest did not pass
    # a drift measured (the rest passed) is named with its bound
    active["drift"] = 0.083
    reason = assess(info, space, 10.0)["reasons"][0]
    assert "the posterior's quantiles moving by 0.083 over those rounds, to be at most 0.05" in reason
    del active["drift"]
    # rounds that passed but whose reported posterior did not confirm them: the last such reading
    active["confirmations"] = [{"rounds": 9, "forward_runs": 360, "spread": 0.16, "passed": False},
                               {"rounds": 13, "forward_runs": 520, "spread": 0.12, "passed": False}]
    reason = assess(info, space, 10.0)["reasons"][0]
    assert ("after 520 forward runs, the reported posterior's sample functions moved a quantile by 0.12"
            in reason) and "asked for none" not in reason
    # a third failure at the budget's end asked for nothing more: nothing was left to ask
    active["confirmations"].append({"rounds": 16, "forward_runs": 640, "spread": 0.11, "passed": False})
    reason = assess(info, space, 10.0)["reasons"][0]
    assert "asked for none" not in reason
    # a third failure before it: no more were asked until the budget's end
    active["confirmations"][-1].update(rounds=15, forward_runs=600)
    reason = assess(info, space, 10.0)["reasons"][0]
    assert "after 3 failed confirmations it asked for none until its budget's end" in reason
    # a reading just above the bound prints apart from it
    active["confirmations"][-1]["spread"] = 0.10018
    reason = assess(info, space, 10.0)["reasons"][0]
    assert "moved a quantile by 0.1002 (> 0.1)" in reason


def test_a_sample_function_resting_on_few_points_leaves_the_spread_unmeasured() -> None:
    space = _space()
    narrow = [{"name": p.name, "q05": p.lower + 0.4 * (p.upper - p.lower),
               "q95": p.lower + 0.5 * (p.upper - p.lower), "r_hat": 1.01} for p in space.free]
    spread = {"max_quantile_shift": 0.04, "per_parameter": {p.name: 0.04 for p in space.free},
              "function_ess": [300.0, 12.4, 250.0, 80.0]}
    info = {"parameters": narrow, "emulator_spread": spread, "emulator_check": {"mean_abs_error": 0.5},
            "correction": {"enabled": True, "target": "emulator", "k_hat": 0.2, "ess": 2500, "settled": True}}
    verdict = assess(info, space, 10.0)
    assert not verdict["reliable"] and len(verdict["reasons"]) == 1
    assert "rests on 12 effective points" in verdict["reasons"][0]
    spread["function_ess"] = [300.0, 60.0]
    assert assess(info, space, 10.0)["reliable"]
    # a spread that bounds nine functions in ten may leave one in ten thin, not more
    spread.update(shift_level=0.9, function_ess=[300.0] * 18 + [12.4, 40.0])
    assert assess(info, space, 10.0)["reliable"]
    spread["function_ess"] = [300.0] * 17 + [12.4, 49.0, 9.0]
    verdict = assess(info, space, 10.0)
    assert not verdict["reliable"]
    assert "3 of 20 GP sample functions' posteriors, more than one in 10, rest on 9-49 effective" \
        in verdict["reasons"][0]


def test_a_spread_too_large_after_a_validation_at_the_budgets_end_asks_for_more_runs() -> None:
    """A validated learning would stop at the same point with a larger budget, so a spread
    above the bound asks for a tighter tolerance; one that only the budget's end let stop
    (rounds from before a failed confirmation counted, or a confirmation after the last
    allowed failure) asks for more runs."""
    space = _space()
    narrow = [{"name": p.name, "q05": p.lower + 0.4 * (p.upper - p.lower),
               "q95": p.lower + 0.5 * (p.upper - p.lower), "r_hat": 1.01} for p in space.free]
    spread = {"max_quantile_shift": 0.14, "per_parameter": {p.name: 0.14 for p in space.free}}
    active = {"enabled": True, "kind": "curves", "converged": True, "evaluations": 1461}
    info = {"parameters": narrow, "emulator_spread": spread, "active_learning": active,
            "emulator_check": {"mean_abs_error": 0.5},
            "correction": {"enabled": True, "target": "emulator", "k_hat": 0.2, "ess": 2500, "settled": True}}
    reasons = assess(info, space, 10.0)["reasons"]
    assert len(reasons) == 1 and "lower refine_tolerance_nats" in reasons[0] and "--refine" not in reasons[0]
    active["validated_at_budget_end"] = True
    reasons = assess(info, space, 10.0)["reasons"]
    assert len(reasons) == 1 and reasons[0].endswith("raise --refine or use the correction (--correct-draws)")
    # a learning that confirms after its last allowed failed confirmation stops only at its budget's end
    active["validated_at_budget_end"] = False
    active["confirmations"] = [{"rounds": r, "forward_runs": 40 * r, "spread": 0.12, "passed": False}
                               for r in (10, 15, 20)] + [{"rounds": 35, "forward_runs": 1461, "passed": True}]
    reasons = assess(info, space, 10.0)["reasons"]
    assert len(reasons) == 1 and reasons[0].endswith("raise --refine or use the correction (--correct-draws)")
