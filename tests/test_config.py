"""Project configuration: the thesis file, defaults, data directory, validation errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from smcbayes.config import build_project, load_project, parse_assignments
from smcbayes.errors import ConfigError, InputError, SmcBayesError

TRIAL = {"id": "a", "charge": {"shape": "bar", "coverage_pct": 60.0}, "press": {"speed_mm_s": 0.3}}


def test_thesis_config(thesis_config: Path) -> None:
    project = load_project(thesis_config)
    ids = [c.id for c in project.configuration]
    assert len(ids) == 12 and len(set(ids)) == 12
    train = [c for c in project.configuration if c.role == "train"]
    assert len(train) == 9 and all(c.data is not None and c.data.force for c in train)
    for c in project.configuration:
        assert c.mould.length_mm == 305.0 and c.mould.temperature_C == 135.0  # from [defaults]
        assert c.charge.stack_height_mm == 8.0 and c.press.force_limit_kN == 1400.0
        assert c.press.speed_mm_s in (0.3, 0.7, 1.1)
        assert c.charge.mass_g is not None
    assert project.parameters["tau_c_MPa"].bounds == (0.001, 5.0)
    assert project.data_path() == (thesis_config.parent / "../../shared/data/thesis-press").resolve()


def test_data_dir_override(thesis_config: Path, tmp_path: Path) -> None:
    project = load_project(thesis_config, data_dir=tmp_path)
    assert project.data_path() == tmp_path.resolve()


def test_defaults_merge_and_trial_overrides() -> None:
    raw = {"defaults": {"press": {"force_limit_kN": 900.0, "hold_s": 10.0}},
           "configuration": [TRIAL, {**TRIAL, "id": "b", "press": {"speed_mm_s": 1.1, "hold_s": 5.0}}]}
    project = build_project(raw, "<raw>", Path("."))
    a, b = project.configuration
    assert (a.press.force_limit_kN, a.press.hold_s) == (900.0, 10.0)
    assert (b.press.force_limit_kN, b.press.hold_s, b.press.speed_mm_s) == (900.0, 5.0, 1.1)


@pytest.mark.parametrize(("raw", "expected"), [
    ({"configuration": [TRIAL, TRIAL]}, "unique"),
    ({"configuration": []}, "configuration"),
    ({"configuration": [TRIAL], "solvr": {}}, "did you mean 'solver'"),
    ({"defaults": {"pres": {}}, "configuration": [TRIAL]}, "did you mean 'press'"),
    ({"configuration": [{**TRIAL, "charge": {"shape": "bar"}}]}, "give coverage_pct or length_mm"),
    ({"configuration": [{**TRIAL, "role": "test"}]}, "'train' or 'validation'"),
    ({"configuration": [TRIAL], "solver": {"closing_steps": 5}}, "closing_steps"),
])
def test_invalid_projects_raise_one_line_config_errors(raw: dict, expected: str) -> None:
    with pytest.raises(ConfigError) as err:
        build_project(raw, "<raw>", Path("."))
    message = str(err.value)
    assert expected in message and "\n" not in message
    assert message.startswith("<raw>")
    assert isinstance(err.value, InputError) and isinstance(err.value, SmcBayesError)


def test_bad_toml_and_missing_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n", encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_project(bad)
    with pytest.raises(ConfigError, match="not found"):
        load_project(tmp_path / "missing.toml")


def test_parse_assignments() -> None:
    assert parse_assignments(["n=0.4", " tau_c_MPa = 0.05"]) == {"n": 0.4, "tau_c_MPa": 0.05}
    assert parse_assignments(None) == {}
    for bad in ("n", "=1", "n=x"):
        with pytest.raises(ConfigError, match="--set"):
            parse_assignments([bad])


def test_posterior_defaults_depend_on_the_simulator() -> None:
    """The log-loss emulator is corrected by default with the built-in simulator (with a
    smaller active learning before); with an external one it reports the emulator alone;
    given values are kept."""
    from smcbayes.config import PosteriorSpec
    from smcbayes.config.settings import REFINE_CORRECTED, REFINE_EMULATED

    spec = PosteriorSpec(emulator="loss")
    native, external = spec.resolved(slow=False, curves=True), spec.resolved(slow=True, curves=True)
    assert native.correct_draws == spec.correction.draws > 0 and native.refine == REFINE_CORRECTED
    assert external.correct_draws == 0 and external.refine == REFINE_EMULATED
    assert REFINE_CORRECTED < REFINE_EMULATED
    given = PosteriorSpec(emulator="loss", refine=50, correct_draws=0, round_runs=12)
    assert given.resolved(slow=False, curves=True) == given.resolved(slow=True, curves=True) == given
    assert (PosteriorSpec(emulator="loss", correct_draws=3000).resolved(slow=True, curves=True).refine
            == REFINE_CORRECTED)


def test_auto_takes_the_curve_emulator_where_the_loss_allows_it_without_a_correction() -> None:
    """``auto`` (the default) resolves to the curve emulator where the loss allows it, else to
    the log-loss one; the curve emulator's posterior is reported without a correction unless
    one is asked for, whatever the simulator."""
    from smcbayes.config import PosteriorSpec
    from smcbayes.config.settings import REFINE_CORRECTED, REFINE_CURVES

    assert PosteriorSpec().emulator == "auto"
    for slow in (False, True):
        curves = PosteriorSpec().resolved(slow=slow, curves=True)
        assert (curves.emulator, curves.correct_draws, curves.refine) == ("curves", 0, REFINE_CURVES)
        assert PosteriorSpec(emulator="curves").resolved(slow=slow, curves=False) == curves
    assert PosteriorSpec().resolved(slow=False, curves=False) == \
        PosteriorSpec(emulator="loss").resolved(slow=False, curves=True)
    native = PosteriorSpec().resolved(slow=False, curves=False)
    assert (native.emulator, native.refine) == ("loss", REFINE_CORRECTED) and native.correct_draws > 0
    asked = PosteriorSpec(correct_draws=3000).resolved(slow=True, curves=True)
    assert (asked.emulator, asked.correct_draws) == ("curves", 3000)


def test_the_round_size_defaults_to_the_emulator_s_own() -> None:
    """Rounds of the active learning: 40 runs for the curve emulator, a quarter of the budget
    within 9-30 for the log-loss one, unless ``round_runs`` says otherwise."""
    from smcbayes.config import PosteriorSpec
    from smcbayes.config.settings import ROUND_RUNS_CURVES

    assert (PosteriorSpec(emulator="curves").resolved(slow=True, curves=True).round_runs
            == ROUND_RUNS_CURVES == 40)
    assert PosteriorSpec(emulator="loss").resolved(slow=True, curves=True).round_runs == 30  # a budget of 800
    assert PosteriorSpec(emulator="loss", refine=60).resolved(slow=True, curves=True).round_runs == 15
    assert PosteriorSpec(emulator="loss", refine=16).resolved(slow=True, curves=True).round_runs == 9
    assert (PosteriorSpec(emulator="curves", round_runs=120).resolved(slow=False, curves=True).round_runs
            == 120)
    for outside in (8, 401):
        with pytest.raises(ValueError):
            PosteriorSpec(round_runs=outside)


def test_the_choices_of_a_literal_setting_come_from_its_model() -> None:
    from smcbayes.config import CalibrationSpec, PosteriorSpec, choices_of

    assert choices_of(PosteriorSpec, "emulator") == ("auto", "loss", "curves")
    assert set(choices_of(CalibrationSpec, "kernel")) == {"rbf", "matern52"}
