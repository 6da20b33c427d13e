"""Diagnosis figures through their public functions: each writes a PNG and an SVG."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from smcbayes.diagnose.figures import before_after, heat_map, phase_bars
from smcbayes.diagnose.fit import DiagnosisContext, Fit
from smcbayes.diagnose.shrink import shrink_summary
from smcbayes.diagnose.where import analyse

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from figcheck import assert_png_and_svg

FIT_IDS, HOLD_IDS = ["60-bar-03", "60-bar-11"], ["60-bar-07"]


def fits(ctx: DiagnosisContext) -> dict[str, Fit]:
    out = {}
    for label, change in (("base", {"n": 0.3}), ("truth", {})):
        theta = ctx.start((), {**ctx.base_params, **change})
        out[label] = Fit((), dict(zip(ctx.model().space.free_names, theta[0], strict=True)), theta, 0.0, 0)
    return out


def test_heat_map_of_residuals(synthetic_ctx: Callable[[str | None], DiagnosisContext],
                               tmp_path: Path) -> None:
    ctx = synthetic_ctx(None)
    rep = analyse(ctx, (), fits(ctx)["base"].theta, FIT_IDS + HOLD_IDS, bins=10)
    assert_png_and_svg(heat_map(rep, tmp_path / "figures" / "heatmap"), tmp_path / "figures" / "heatmap")


def test_heat_map_of_zero_residuals(synthetic_ctx: Callable[[str | None], DiagnosisContext],
                                    tmp_path: Path) -> None:
    """A perfect fit (all residuals 0) still gives a figure (colour range falls back to 1 kN)."""
    ctx = synthetic_ctx(None)
    rep = analyse(ctx, (), fits(ctx)["base"].theta, FIT_IDS, bins=10)
    rep.heat_kN[...] = 0.0
    assert_png_and_svg(heat_map(rep, tmp_path / "zero"), tmp_path / "zero")


def test_phase_bars_and_before_after(synthetic_ctx: Callable[[str | None], DiagnosisContext],
                                     tmp_path: Path) -> None:
    ctx = synthetic_ctx(None)
    models = fits(ctx)
    shrink = shrink_summary(ctx, models, FIT_IDS, HOLD_IDS)
    # a phase a configuration never reaches is None in the summary: drawn as a zero bar
    shrink["models"]["truth"]["holdout"]["per_config"]["60-bar-07"]["phase_rmse_kN"]["contact"] = None
    assert_png_and_svg(phase_bars(shrink, tmp_path / "phase_rmse"), tmp_path / "phase_rmse")
    out = before_after(ctx, models, FIT_IDS + HOLD_IDS, HOLD_IDS, tmp_path / "before_after")
    assert_png_and_svg(out, tmp_path / "before_after")
