"""Posterior figures through their public functions: each writes a PNG and an SVG."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from smcbayes.errors import ConfigError
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.posterior.plots import bands_plot, corner_plot, correlation_plot
from smcbayes.posterior.predictive import Band

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from figcheck import assert_png_and_svg

SPACE = ParameterSpace(BASE_PARAMETERS, {"tau_star_Pa": 1e4, "B_Pa_s": 1e4, "m": 1.5})


def band(cid: str, measured: bool) -> Band:
    t = np.linspace(0.0, 10.0, 50)
    q = np.array([0.8, 0.9, 1.0, 1.1, 1.2])[:, None] * (10.0 * t)[None, :]
    meas = (t[::5], 10.0 * t[::5]) if measured else None
    return Band(cid, t, q, -0.01 * q, q * 1.05, 2.0, meas, 0.5 if measured else float("nan"),
                0.9 if measured else float("nan"), 40)


def test_corner_plot_with_truth(tmp_path: Path) -> None:
    pytest.importorskip("corner")
    theta = SPACE.from_unit(np.random.default_rng(0).random((300, 2)))
    out = corner_plot(SPACE, theta, tmp_path / "corner", truth={"n": 0.4, "tau_c_MPa": 0.05})
    assert_png_and_svg(out, tmp_path / "corner")


def test_corner_plot_without_the_package_names_the_fix(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "corner", None)  # import corner -> ImportError
    with pytest.raises(ConfigError, match="pip install corner"):
        corner_plot(SPACE, np.full((5, 2), 0.4), tmp_path / "corner")
    assert not (tmp_path / "corner.png").exists()


def test_correlation_plot(tmp_path: Path) -> None:
    matrix = np.array([[1.0, -0.8, 0.1], [-0.8, 1.0, 0.0], [0.1, 0.0, 1.0]])
    out = correlation_plot(matrix, ["n", "log10 tau_c_MPa", "m"], tmp_path / "fig" / "corr")
    assert_png_and_svg(out, tmp_path / "fig" / "corr")


def test_bands_plot_with_and_without_measurements(tmp_path: Path) -> None:
    bands = {cid: band(cid, cid != "b") for cid in ("a", "b", "c", "d")}  # 2 x 3 grid, 2 panels empty
    out = bands_plot(bands, tmp_path / "bands", "held-out configurations")
    assert_png_and_svg(out, tmp_path / "bands")
