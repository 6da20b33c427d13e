"""Every parameter of the native model has a physical range with a reason, and the
search boxes (the built-in ones and the thesis project's) lie inside it."""

from __future__ import annotations

from pathlib import Path

import pytest

from smcbayes.config import load_project
from smcbayes.errors import ConfigError
from smcbayes.forward.effects import EffectStack, get_effect
from smcbayes.forward.effects.base import registered
from smcbayes.forward.model import build_space
from smcbayes.forward.parameters import BASE_PARAMETERS
from smcbayes.forward.ranges import PHYSICAL_RANGES, physical_range, ranges_table

THESIS = Path(__file__).resolve().parents[2] / "configs" / "thesis.toml"
ALL = list(BASE_PARAMETERS) + [p for cls in registered().values() for p in cls.parameters]


@pytest.mark.parametrize("param", ALL, ids=lambda p: p.name)
def test_range_holds_the_default_and_the_built_in_box_and_is_valid(  # type: ignore[no-untyped-def]
        param) -> None:
    r = physical_range(param.name)
    assert r.lower < r.upper and len(r.reason) > 30
    assert r.contains(param.default) and r.contains(param.lower) and r.contains(param.upper)
    lo, hi = param.valid
    assert lo < r.lower and r.upper < hi  # a physical value is never rejected


def test_no_range_without_a_parameter() -> None:
    assert set(PHYSICAL_RANGES) == {p.name for p in ALL}
    with pytest.raises(ConfigError, match="no physical range"):
        physical_range("viscosity")
    assert ranges_table().count("\n") == len(ALL) + 1


def test_the_thesis_search_box_lies_inside_the_physical_ranges() -> None:
    project = load_project(THESIS)
    effects = EffectStack([get_effect(n) for n in registered()])
    space = build_space(project, effects)
    for p in space.parameters:
        r = physical_range(p.name)
        assert r.contains(p.lower) and r.contains(p.upper), p.name
