"""The diagnosis's Gauss-Newton residuals follow the loss's contact offset: with the
simulated closing delayed by the offset, a delayed measurement leaves no residual."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smcbayes.data.curve import Curve
from smcbayes.data.dataset import Measurement
from smcbayes.diagnose.fit import residuals_on, window_end
from smcbayes.forward.result import SimulationResult


def test_residuals_at_the_delay_of_a_contact_offset() -> None:
    t = np.linspace(0.0, 5.0, 300)
    f = 300.0 * (t / 5.0) ** 3
    ones = np.ones((1, t.size))
    res = SimulationResult("c", t[None, :], ones, ones, f[None, :], ones, ones,
                           np.ones((1, t.size), dtype=np.int8), np.array([5.0]), ["ok"])
    delay = 0.25
    tm = np.linspace(0.0, 5.0 + delay, 400)
    fm = 300.0 * (np.clip(tm - delay, 0.0, 5.0) / 5.0) ** 3
    m = Measurement("c", "train", Curve(tm, fm, "force", "kN", Path("c.csv")), None, speed_mm_s=1.0)
    end = float(window_end(res, m, "none", delay)[0])
    assert end == np.float64(5.0 + delay)
    _, resid = residuals_on(res, m, "none", end, 200, delay)
    assert np.max(np.abs(resid)) < 0.5
    _, plain = residuals_on(res, m, "none", end, 200)
    assert np.max(np.abs(plain)) > 20.0


def test_a_held_out_trials_residual_is_that_of_its_curve_mixed_over_the_offsets() -> None:
    """A trial judged over two contact offsets (0 and 0.5 mm at 1 mm/s): the diagnosis's
    residual is the loss's, measured minus the mean of the two delayed curves
    (:func:`smcbayes.data.loss.mixed_force_pair`), on the window of the later one."""
    from types import SimpleNamespace

    from smcbayes.config.specs import LossSpec
    from smcbayes.data.loss import mixed_force_pair
    from smcbayes.diagnose.fit import residual_stack

    t = np.linspace(0.0, 5.0, 300)
    f = 300.0 * (t / 5.0) ** 3
    ones = np.ones((1, t.size))
    res = SimulationResult("c", t[None, :], ones, ones, f[None, :], ones, ones,
                           np.ones((1, t.size), dtype=np.int8), np.array([5.0]), ["ok"])
    tm = np.linspace(0.0, 5.2, 400)
    fm = 300.0 * (np.clip(tm - 0.2, 0.0, 5.0) / 5.0) ** 3
    m = Measurement("c", "train", Curve(tm, fm, "force", "kN", Path("c.csv")), None, speed_mm_s=1.0)
    spec = LossSpec(contact="end_state")
    ctx = SimpleNamespace(simulate=lambda extra, theta, ids: {"c": res},
                          project=SimpleNamespace(loss=spec), dataset={"c": m})
    resid, ends = residual_stack(ctx, (), np.zeros((1, 1)), ["c"], offsets_mm={"c": (0.0, 0.5)})
    assert ends["c"] == 5.5
    mixed = mixed_force_pair(res, m, spec, [0.0, 0.5])
    np.testing.assert_allclose(resid["c"][0], mixed.meas_kN[0] - mixed.sim_kN[0], atol=1e-9)
    single, _ = residual_stack(ctx, (), np.zeros((1, 1)), ["c"], offsets_mm={"c": (0.25,)})
    assert np.max(np.abs(single["c"][0] - resid["c"][0])) > 1.0
    # its held-out loss is the loss of the same averaged curve
    from smcbayes.diagnose.fit import fixed_offset_losses

    loss = fixed_offset_losses(ctx, (), np.zeros((1, 1)), ["c"], {"c": (0.0, 0.5)})
    assert loss[0, 0] == pytest.approx(float(np.mean((mixed.meas_kN[0] - mixed.sim_kN[0]) ** 2)))
    # no fitting trial gave an offset: the nominal contact, not the trial's own (it has no
    # end state to take one from)
    none, ends_none = residual_stack(ctx, (), np.zeros((1, 1)), ["c"], offsets_mm={"c": ()})
    assert ends_none["c"] == 5.2
    np.testing.assert_allclose(none["c"], residuals_on(res, m, "none", 5.2, spec.grid_points)[1])
