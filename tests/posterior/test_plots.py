"""Posterior figures through their public functions: each writes a PNG and an SVG."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from smcbayes.errors import ConfigError
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.posterior.plots import bands_plot, corner_plot, correlation_plot, learning_figure, learning_plot
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


def learning_record() -> tuple[list[dict], dict]:
    """Four rounds of 40 runs after 60 starting runs, one error and one spread not measured
    (``None``), one drift, a failed and a passed confirmation."""
    measures = [(3.0, None, 0.2), (None, 0.08, 0.12), (0.8, 0.03, None), (0.5, 0.02, 0.07)]
    rounds = [{"round": k + 1, "forward_runs": 40 * (k + 1), "error_nats": e, "quantile_shift": q,
               "spread": s} for k, (e, q, s) in enumerate(measures)]
    active = {"start_runs": 60, "tolerance_nats": 1.0, "validated_rounds": 3, "evaluations": 220,
              "converged": True, "bounds": {"quantile_shift": 0.05, "drift": 0.05, "spread": 0.1},
              "drifts": [{"rounds": 4, "drift": 0.04}],
              "confirmations": [{"forward_runs": 180, "spread": 0.13, "passed": False},
                                {"forward_runs": 220, "spread": 0.06, "passed": True}]}
    return rounds, active


def _line(ax, label: str) -> tuple[np.ndarray, np.ndarray]:
    line = next(ln for ln in ax.get_lines() if ln.get_label().startswith(label))
    return np.asarray(line.get_xdata(), dtype=float), np.asarray(line.get_ydata(), dtype=float)


def test_the_learning_figure_draws_each_measure_against_the_runs_beside_its_bound() -> None:
    rounds, active = learning_record()
    err, move, spread = learning_figure(rounds, active).axes
    runs = np.array([100.0, 140.0, 180.0, 220.0])  # the starting runs counted
    x, y = _line(err, "error")
    np.testing.assert_array_equal(x, runs)
    np.testing.assert_array_equal(y, [3.0, np.nan, 0.8, 0.5])
    assert _line(err, "bound")[1][0] == 1.0 and err.get_yscale() == "log"
    np.testing.assert_array_equal(_line(move, "move")[1], [np.nan, 0.08, 0.03, 0.02])
    assert [v.tolist() for v in _line(move, "drift")] == [[220.0], [0.04]]
    assert _line(move, "bound")[1][0] == 0.05 and _line(spread, "bound")[1][0] == 0.1
    # the mean over the last three rounds: NaN wherever one of them was not measured
    x, y = _line(spread, "mean of the last 3")
    np.testing.assert_array_equal(x, runs[2:])
    assert np.isnan(y).all()
    assert [v.tolist() for v in _line(spread, "reported posterior's spread, not")] == [[180.0], [0.13]]
    assert [v.tolist() for v in _line(spread, "reported posterior's spread, confirmed")] == [[220.0], [0.06]]
    rounds[2]["spread"] = 0.1
    x, y = _line(learning_figure(rounds, active).axes[2], "mean of the last 3")
    np.testing.assert_allclose(y, [(0.2 + 0.12 + 0.1) / 3, (0.12 + 0.1 + 0.07) / 3])


def test_the_learning_plot_writes_both_files(tmp_path: Path) -> None:
    rounds, active = learning_record()
    out = learning_plot(rounds[:1], {**active, "drifts": [], "confirmations": []}, tmp_path / "learning")
    assert_png_and_svg(out, tmp_path / "learning")
