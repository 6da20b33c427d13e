"""Forward selection of an effect set: the loop's decisions on a scripted scorer, and
``calibrate --effects-from`` reading a diagnosis."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from smcbayes.cli import main
from smcbayes.diagnose import select
from smcbayes.diagnose.fit import Fit, FitSettings
from smcbayes.diagnose.run import decide, pair_members
from smcbayes.diagnose.which import all_trial_evidence, choose

ROOT = Path(__file__).resolve().parents[2]


def _fit(effects: tuple[str, ...]) -> Fit:
    return Fit(effects, {}, np.zeros((1, 1)), 1.0, 1)


@pytest.fixture()
def scripted(monkeypatch: pytest.MonkeyPatch):
    """refit returns a fit of the asked effect set; step_row scores it from a table keyed by
    the set's name (missing sets score -10)."""
    scores: dict[str, float] = {}
    evidence: dict[str, float] = {}
    calls: list[str] = []

    class Ctx:
        def start(self, extra: tuple[str, ...], known: Any = None) -> np.ndarray:
            return np.zeros(1)

    def refit(ctx: Any, extra: tuple[str, ...], *args: Any, **kwargs: Any) -> Fit:
        calls.append("+".join(extra))
        return _fit(tuple(extra))

    def step_row(ctx: Any, current: Fit, cand: Fit, *args: Any) -> dict[str, Any]:
        name = "+".join(cand.effects)
        score = scores.get(name, -10.0)
        return {"effect": name, "score": score, "significant": score >= 3.0,
                "evidence": evidence.get(name, score),
                "holdout_loss_kN2": 1.0, "holdout_loss_base_kN2": 2.0, "holdout_shrink_pct": 50.0,
                "dm_z": 2.0}

    monkeypatch.setattr(select, "refit", refit)
    monkeypatch.setattr(select, "step_row", step_row)

    def run(candidates: list[str], max_effects: int = 3):
        return select.forward_selection(Ctx(), _fit(("a",)), candidates, ["f"], ["h"], FitSettings(),
                                        np.random.default_rng(0), (10.0, 10.0), 3.0, max_effects,
                                        lambda line: None)

    run.evidence = evidence
    return scores, calls, run


def test_nothing_significant_keeps_the_single_effect(scripted) -> None:
    scores, calls, run = scripted
    scores.update({"a+b": 1.0, "a+c": 2.5})
    selected, steps, grown = run(["b", "c"])
    assert selected == ["a"] and grown == {}
    # the selected set searched again, then every remaining candidate tried with it
    assert calls == ["a", "a+b", "a+c"]
    assert len(steps) == 1 and steps[0]["added"] is None and steps[0]["best_candidate"] == "c"


def test_an_effect_that_helps_only_with_the_first_is_added(scripted) -> None:
    scores, calls, run = scripted
    # b is low alone (rank order b, c) but wins together with a; nothing helps a third time
    scores.update({"a+b": 1.0, "a+c": 8.0, "a+c+b": 0.5})
    selected, steps, grown = run(["b", "c"])
    assert selected == ["a", "c"] and list(grown) == ["a+c"]
    assert [s["added"] for s in steps] == ["c", None]
    assert calls == ["a", "a+b", "a+c", "a+c", "a+c+b"]


def test_the_set_stops_at_max_effects(scripted) -> None:
    scores, calls, run = scripted
    scores.update({"a+b": 5.0, "a+b+c": 5.0})
    selected, _, _ = run(["b", "c"], max_effects=2)
    assert selected == ["a", "b"] and calls == ["a", "a+b", "a+c"]
    selected, _, _ = run(["b", "c"], max_effects=1)
    assert selected == ["a"]


def test_a_near_tie_goes_to_the_larger_evidence_on_all_trials(scripted) -> None:
    scores, calls, run = scripted
    # b scores best on the held-out trials but within min_score (3) of c, whose evidence on
    # all trials is larger; then the same scores 5 apart: the held-out score decides
    scores.update({"a+b": 8.0, "a+c": 6.0})
    run.evidence.update({"a+b": 10.0, "a+c": 40.0})
    selected, steps, _ = run(["b", "c"], max_effects=2)
    assert selected == ["a", "c"] and steps[0]["best_candidate"] == "c"
    assert steps[0]["chosen_over"] == "b" and steps[0]["evidence"] == {"a+b": 10.0, "a+c": 40.0}
    scores.update({"a+c": 3.0})
    selected, _, _ = run(["b", "c"], max_effects=2)
    assert selected == ["a", "b"]


def _row(effect: str, score: float, evidence: float, significant: bool = True) -> dict[str, Any]:
    return {"effect": effect, "score": score, "evidence": evidence, "significant": significant,
            "holdout_loss_base_kN2": 100.0, "holdout_loss_kN2": 10.0, "holdout_shrink_pct": 90.0,
            "dm_z": 3.0}


def test_choose_breaks_only_near_ties_among_significant_rows() -> None:
    rows = [_row("timing", 30.6, 131.0), _row("shape", 29.2, 175.0), _row("far", 27.0, 500.0),
            _row("weak", 30.0, 900.0, significant=False)]
    assert choose(rows, 3.0)["effect"] == "shape"
    assert choose(rows, 1.0)["effect"] == "timing"
    # nothing named when the best score is not significant, whatever the evidence
    assert choose([_row("a", 2.0, 50.0, significant=False), _row("b", 1.5, 60.0, significant=False)],
                  3.0) is None
    assert choose([_row("nan", float("nan"), 1.0)], 3.0) is None
    # the window's edge is inside; a top without finite evidence keeps its place
    assert choose([_row("a", 10.0, 1.0), _row("b", 7.0, 5.0)], 3.0)["effect"] == "b"
    assert choose([_row("a", 10.0, float("nan")), _row("b", 9.0, 5.0)], 3.0)["effect"] == "a"
    decision = decide(rows, 3.0)
    assert decision["best"] == "shape" and "within 3 of timing's" in decision["statement"]
    assert decide(rows, 1.0)["best"] == "timing"
    assert "within" not in decide(rows, 1.0)["statement"]


def test_pair_keeps_the_named_effect() -> None:
    rows = [_row("timing", 30.6, 131.0), _row("shape", 29.2, 175.0), _row("far", 27.0, 500.0)]
    assert pair_members(rows, 3.0) == ("shape", "timing")
    assert pair_members(rows, 1.0) == ("timing", "shape")
    weak = [_row("a", 2.0, 50.0, significant=False), _row("b", 1.5, 60.0, significant=False)]
    assert pair_members(weak, 3.0) == ("a", "b")
    with pytest.raises(ValueError, match="two candidate effects"):
        pair_members(rows[:1], 3.0)


def test_all_trial_evidence_is_the_chain_rule_sum() -> None:
    # (10 / 2) ln 2 + (4 / 2) ln 4 - (1 / 2) ln 10
    want = 5.0 * np.log(2.0) + 2.0 * np.log(4.0) - 0.5 * np.log(10.0)
    assert all_trial_evidence(10.0, 4.0, (2.0, 1.0), (4.0, 1.0), 1) == pytest.approx(want)
    assert np.isnan(all_trial_evidence(10.0, 4.0, (2.0, 0.0), (4.0, 1.0), 1))


def _diagnosis(folder: Path, summary: dict[str, Any]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    return folder


@pytest.mark.parametrize("summary, words", [
    (None, "no diagnosis summary.json"),
    ({"decision": {}}, "records no selected effect set"),
    ({"selected_effects": [], "decision": {"statement": "no effect explains the gap"}},
     "selected no effect (no effect explains the gap)"),
])
def test_effects_from_says_what_is_missing(tmp_path: Path, capsys: pytest.CaptureFixture,
                                           summary: dict[str, Any] | None, words: str) -> None:
    folder = tmp_path / "diag"
    if summary is not None:
        _diagnosis(folder, summary)
    code = main(["calibrate", str(ROOT / "configs" / "verify-slip-2d.toml"), "--out", str(tmp_path / "run"),
                 "--effects-from", str(folder)])
    assert code == 2 and words in capsys.readouterr().err
    assert not (tmp_path / "run" / "evaluations.jsonl").exists()


def test_effects_from_switches_on_the_selected_set(tmp_path: Path) -> None:
    folder = _diagnosis(tmp_path / "diag", {"selected_effects": ["press_compliance", "speed_ramp"]})
    out = tmp_path / "run"
    assert main(["calibrate", str(ROOT / "configs" / "verify-slip-2d.toml"), "--out", str(out),
                 "--effects-from", str(folder / "summary.json"), "--effect", "press_compliance",
                 "--fidelity", "1d", "--budget", "3", "--init", "2", "--no-figures"]) == 0
    config = json.loads((out / "config.json").read_text(encoding="utf-8"))
    assert config["effects"] == ["press_compliance", "speed_ramp"]


def test_the_api_result_gives_the_selected_set() -> None:
    from smcbayes.api import DiagnosisResult

    result = DiagnosisResult(Path("d"), {"selected_effects": ["compressibility", "press_compliance"],
                                         "decision": {"best": "compressibility"}})
    assert result.selected_effects == ["compressibility", "press_compliance"]
    assert result.best_effect == "compressibility"
    assert DiagnosisResult(Path("d"), {"decision": {"best": None}}).selected_effects == []
