"""The simulation figure: a trial without a contact of its own is drawn as the mean of its
curves over the training trials' contacts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smcbayes.forward.result import SimulationResult
from smcbayes.plotting import mixed_force, plot_simulation


def test_the_mixed_force_is_the_mean_of_the_delayed_curves() -> None:
    """A ramp delayed by 0.1 and 0.3 s: inside, the mean is the ramp delayed by 0.2 s; before
    the earliest contact it is the curve's first value, beyond its end its last."""
    t = np.linspace(0.0, 4.0, 81)
    grid, f = mixed_force(t, 100.0 * t, np.array([0.1, 0.3]), 5.0, points=501)
    inside = (grid >= 0.3) & (grid <= 4.1)
    np.testing.assert_allclose(f[inside], 100.0 * (grid[inside] - 0.2), atol=1e-9)
    assert f[0] == 0.0 and f[-1] == 400.0
    bad = np.where(t > 2.0, np.nan, t)
    assert np.all(np.isfinite(mixed_force(bad, 100.0 * bad, np.array([0.0, 0.1]), 3.0)[1]))


def test_a_figure_with_mixed_contacts_is_written(tmp_path: Path) -> None:
    t = np.tile(np.linspace(0.0, 4.0, 81), (1, 1))
    res = SimulationResult("c1", t, 8.0 - t, t, 100.0 * t, np.ones_like(t), np.ones_like(t),
                           np.ones_like(t, dtype=np.int8), np.array([4.0]), ["ok"])
    paths = plot_simulation({"c1": res, "c2": res}, {"c1": (t[0], 100.0 * t[0])}, tmp_path / "fig", "title",
                            delays_s={"c1": 0.2, "c2": 0.2}, mixed_delays_s={"c2": [0.1, 0.3]})
    assert paths and all(p.is_file() and p.stat().st_size > 0 for p in paths)
