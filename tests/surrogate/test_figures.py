"""Calibration figures through their public functions: each writes a PNG and an SVG."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.surrogate.design import latin_hypercube
from smcbayes.surrogate.figures import plot_convergence, plot_landscape
from smcbayes.surrogate.gp import fit_surrogate, gp_session

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from figcheck import assert_png_and_svg

SPACE = ParameterSpace(BASE_PARAMETERS, {"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 1e4})  # tau_c, m


def test_convergence_with_failures(tmp_path: Path) -> None:
    losses = np.array([50.0, np.nan, 20.0, 30.0, np.nan, 5.0, 6.0])
    assert_png_and_svg(plot_convergence(losses, 3, tmp_path / "conv"), tmp_path / "conv")


def test_convergence_when_every_evaluation_failed(tmp_path: Path) -> None:
    out = plot_convergence(np.full(4, np.nan), 5, tmp_path / "failed")
    assert_png_and_svg(out, tmp_path / "failed")


def test_landscape_of_a_two_parameter_gp(tmp_path: Path) -> None:
    u = latin_hypercube(8, 2, np.random.default_rng(0))
    y = np.log(0.1 + np.sum((u - 0.4) ** 2, axis=1))
    with gp_session():
        surrogate = fit_surrogate(u, y, "matern52", seed=0, noise=1e-6)
    theta = SPACE.from_unit(u)
    records = [{"params": {"tau_c_MPa": t[0], "m": t[1], "n": 0.4}} for t in theta]
    out = plot_landscape(surrogate, SPACE, records, 5, np.array([[0.4, 0.4]]),
                         {"tau_c_MPa": 0.05, "m": 1.5}, tmp_path / "landscape", points=20)
    assert_png_and_svg(out, tmp_path / "landscape")
    out = plot_landscape(surrogate, SPACE, records, 8, None, None, tmp_path / "plain", points=20)
    assert_png_and_svg(out, tmp_path / "plain")
