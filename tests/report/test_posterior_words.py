"""The posterior section's words match its numbers: trust, convergence and prior-likeness."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from smcbayes.report import write_report

PROJECT = {
    "name": "tiny",
    "configuration": [
        {"id": "bar-03", "role": "train",
         "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 388.0},
         "press": {"speed_mm_s": 0.3}},
    ],
}
BOX = {"n": {"lower": 0.2, "upper": 0.6, "log": False, "unit": "-"},
       "B_Pa_s": {"lower": 1e3, "upper": 1e5, "log": True, "unit": "Pa s"}}
GOOD_WEIGHTS = {"enabled": True, "evaluations": 671, "k_hat": 0.06, "ess": 512.0,
                "reliable": True, "settled": True}


def report_text(tmp_path: Path, params: list[dict], correction: dict | None,
                extra: dict | None = None) -> str:
    """Markdown report of a fake run with a posterior of ``params`` (and ``extra`` keys)."""
    run = tmp_path / "run"
    (run / "posterior").mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"project": PROJECT}), encoding="utf-8")
    summary = {"best_loss_kN2": 12.5, "best_params": {}, "best_errors_kN2": {"bar-03": 12.5},
               "search_box": BOX, "settings": {"seed": 0}}
    (run / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    post = {"parameters": params, **({"correction": correction} if correction else {}), **(extra or {})}
    (run / "posterior" / "summary.json").write_text(json.dumps(post), encoding="utf-8")
    write_report(run, formats=("md",))
    return (run / "report.md").read_text(encoding="utf-8")


NARROW = [{"name": "n", "q05": 0.34, "q95": 0.36, "r_hat": 1.01},
          {"name": "B_Pa_s", "q05": 1.9e4, "q95": 2.1e4, "r_hat": 1.01}]
WIDE = [{"name": "n", "q05": 0.21, "q95": 0.59, "r_hat": 1.19},
        {"name": "B_Pa_s", "q05": 1.1e3, "q95": 9.5e4, "r_hat": 1.12}]


def test_trusted_only_when_chains_and_weights_are_both_fine(tmp_path: Path) -> None:
    text = report_text(tmp_path, NARROW, GOOD_WEIGHTS)
    assert "can be trusted" in text and "did not converge" not in text


def test_high_r_hat_with_good_weights_says_what_holds(tmp_path: Path) -> None:
    params = [dict(p, r_hat=1.19) for p in NARROW]
    text = report_text(tmp_path, params, GOOD_WEIGHTS)
    assert "can be trusted" not in text
    assert ("the corrected posterior rests on the importance weights (k-hat 0.06), the emulator "
            "chains did not converge (R-hat 1.19)") in text


@pytest.mark.parametrize(("r_hat", "words"), [(1.01, "the emulator chains agree"),
                                               (1.19, "the emulator chains did not converge")])
def test_a_weighted_table_shows_no_r_hat_and_the_words_keep_the_chains(
        tmp_path: Path, r_hat: float, words: str) -> None:
    """An importance-weighted table's R-hat is null: its cell reads '-', and the sentences
    on the chains take their R-hat from the chains' own table, as when the table carried it."""
    weighted = [dict(p, r_hat=None, ess=512.0) for p in NARROW]
    chains = [dict(p, r_hat=r_hat, ess=900.0) for p in NARROW]
    text = report_text(tmp_path, weighted, GOOD_WEIGHTS, {"emulator_parameters": chains})
    header = next(line for line in text.splitlines() if line.startswith("| parameter |"))
    column = [c.strip() for c in header.strip("|").split("|")].index("R-hat")
    for name in ("n", "B_Pa_s"):
        row = next(line for line in text.splitlines() if line.startswith(f"| {name} |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[column] == "-" and cells[column + 1] == "512"
    assert f"the largest R-hat of its chains is {r_hat}: {words}." in text
    # the sentences are those of a summary whose table carried the chains' R-hat
    old = report_text(tmp_path / "old", [dict(p, ess=512.0) for p in chains], GOOD_WEIGHTS)
    assert [ln for ln in old.splitlines() if "R-hat" in ln and not ln.startswith("|")] == \
        [ln for ln in text.splitlines() if "R-hat" in ln and not ln.startswith("|")]


@pytest.mark.parametrize("k_hat", [0.75, 0.95])
def test_high_k_hat_is_never_trusted(tmp_path: Path, k_hat: float) -> None:
    weights = dict(GOOD_WEIGHTS, k_hat=k_hat)  # flags say reliable, k-hat says otherwise
    text = report_text(tmp_path, NARROW, weights)
    assert "can be trusted" not in text and "unreliable (k-hat above 0.7)" in text


def test_a_posterior_as_wide_as_the_prior_is_called_the_prior(tmp_path: Path) -> None:
    text = report_text(tmp_path, WIDE, GOOD_WEIGHTS)
    assert "The posterior is essentially the prior" in text
    assert "can be trusted" not in text
    narrow = report_text(tmp_path / "b", NARROW, GOOD_WEIGHTS)
    assert "essentially the prior" not in narrow and "the data identify the parameters" in narrow



@pytest.mark.parametrize(("k_hat", "settled", "words", "tone_word"),
                         [(0.2, True, "the weights are reliable.", None),
                          (0.9, False, "the weights are unreliable (k-hat above 0.7)", "indicative"),
                          (0.3, False, "the sampling did not settle within its draws", "indicative")])
def test_the_emulators_own_importance_sample_is_not_called_a_forward_model_correction(
        tmp_path: Path, k_hat: float, settled: bool, words: str, tone_word: str | None) -> None:
    """The default path samples the emulated posterior by importance, with no forward run:
    the words say so, judge it by its weights, and do not call the chains that started it
    unconverged (the stage's verdict does not read their R-hat either)."""
    sampled = {"enabled": True, "target": "emulator", "draws": 144000, "evaluations": 0, "k_hat": k_hat,
               "ess": 4589.0, "reliable": k_hat <= 0.7, "settled": settled}
    weighted = [dict(p, r_hat=None, ess=4589.0) for p in NARROW]
    chains = [dict(p, r_hat=1.12, ess=300.0) for p in NARROW]
    text = report_text(tmp_path, weighted, sampled, {"emulator_parameters": chains})
    assert "sampled by importance on the emulator, with no forward run" in text
    assert "emulator evaluations" in text and words in text
    assert "with the forward model" not in text and "did not converge" not in text
    assert "the largest R-hat of its chains is 1.12. They only started the importance sampling" in text
    if tone_word:
        assert tone_word in text
