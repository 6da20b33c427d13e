"""The shared laws and press-programme decisions: one definition, equal on every path.

The NumPy paths call :mod:`smcbayes.forward.laws` and :mod:`smcbayes.forward.programme`
on arrays; the compiled kernel compiles the same functions and calls them on floats.
Both must give the same numbers, bit for bit, including at the edges (no pores, gelation,
no elapsed time, infinite force).
"""

from __future__ import annotations

import numpy as np
import pytest

from smcbayes.forward import _march_kernel as kernel
from smcbayes.forward import laws, programme
from smcbayes.forward.effects.registry import BUILT_IN
from smcbayes.forward.kernel_layout import KERNEL_EFFECTS, ROW, STATE

RNG = np.random.default_rng(3)

CASES = [
    (kernel._compaction_pressure, laws.compaction_pressure,
     [np.array([0.5, 0.6, 0.99, 1.0, 0.7]), np.array([0.58, 0.58, 0.58, 0.58, 1.0]),
      np.full(5, 1e6), np.full(5, 5.0)]),
    (kernel._relax_temperature, laws.mould_temperature_relaxation,
     [RNG.uniform(290, 420, 5), 423.15, RNG.uniform(1e-3, 8e-3, 5), np.full(5, 3e-7), RNG.uniform(0, 2, 5)]),
    (kernel._arrhenius, laws.arrhenius_factor, [RNG.uniform(290, 420, 5), 423.15, np.full(5, 5000.0)]),
    (kernel._cure_rk4_step, laws.cure_rk4_step,
     [np.array([0.0, 0.2, 0.9, 1.0, -0.1]), np.full(5, 1e-3), np.full(5, 2e-2), np.full(5, 3.0)]),
    (kernel._cure_factor, laws.cure_factor,
     [np.array([0.0, 0.3, 0.5, 0.7, 0.49999]), np.full(5, 0.5), np.full(5, 3.0), np.full(5, 5.0), 1e12]),
    (kernel._crossing, programme.crossing_fraction,
     [np.array([0.0, 1.0, 5.0, 2.0, 3.0]), np.array([2.0, np.inf, 5.0, 9.0, 1.0]), 4.0]),
    (kernel._stretch, programme.closing_stretch,
     [np.array([0.0, 1e-3, 1e-3, 1e-6, 0.0]), np.array([np.nan, 0.0, 1e9, 1.0, np.inf]),
      np.array([np.nan, 0.0, 0.0, 1e-9, 0.0]), np.full(5, 1.2), np.full(5, 20.0), 1e-3, 1e6]),
    (kernel._load_travel, programme.load_travel,
     [np.array([1e5, 5e5, 1e5, 1.5e6, 0.0]), 1e6, np.array([1e-9, 1e-9, 0.0, 1e-9, 2e-8]),
      np.array([0.0, 0.6, 0.3, 0.0, 0.9])]),
    (kernel._hold_step, programme.hold_step,
     [np.array([10.0, 10.0, 30.0, 11.0, 12.0]), np.full(5, 10.0), np.array([0.0, 1e-4, 1e-5, 0.0, 1.0]),
      np.full(5, 0.05), 60.0, 60.0, np.full(5, 2e-5)]),
]


@pytest.mark.parametrize(("compiled", "law", "args"), CASES, ids=lambda v: getattr(v, "__name__", ""))
def test_compiled_law_equals_the_numpy_law_bit_for_bit(compiled: object, law: object, args: list) -> None:
    with np.errstate(all="ignore"):
        vector = law(*args)
    for i in range(5):
        scalar = compiled(*[float(a[i]) if isinstance(a, np.ndarray) else a for a in args])
        assert isinstance(scalar, float)
        np.testing.assert_array_equal(scalar, vector[i])


def test_press_programme_decisions() -> None:
    press = programme.PressProgramme(speed=1e-3, force_limit=1e6, hold=30.0, jump_time=0.05)
    force = np.array([0.5e6, 1e6, np.nan, np.inf])
    np.testing.assert_array_equal(press.reaches_limit(force), [False, True, False, True])
    np.testing.assert_array_equal(press.crossing(np.zeros(4), force), [1.0, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(press.crossing(np.array([0.5e6]), np.array([1.5e6])), [0.5])
    np.testing.assert_array_equal(press.hold_over(np.array([39.0, 40.0 - 1e-10]), np.array([10.0, 10.0])),
                                  [False, True])
    stops = programme.fills_and_stops(np.array([True, True, False]), np.array([1.0, 1.0, 1.0]), 1.0,
                                      np.array([False, True, False]))
    np.testing.assert_array_equal(stops, [True, False, False])


@pytest.mark.parametrize("beta", [0.0, 0.6])
def test_load_time_integrates_the_loading_of_the_frame(beta: float) -> None:
    """A full cavity on a compliant frame: dF/dt = k free (1 - beta F / F_limit) integrated
    finely from F0 to the limit takes the closed form's time; a rigid frame (and a stiff
    one that would take less) takes the jump time."""
    k, free, f0, limit = 1e9, 7e-4, 1e5, 1.4e6
    dt, force, t = 1e-5, f0, 0.0
    while force < limit:  # midpoint rule
        half = force + 0.5 * dt * k * free * (1.0 - beta * force / limit)
        force, t = force + dt * k * free * (1.0 - beta * half / limit), t + dt
    t -= (force - limit) / (k * free * (1.0 - beta))  # back from the overshoot at the limit's rate
    assert float(programme.load_time(f0, limit, 1.0 / k, free, beta, 0.05)) == pytest.approx(t, rel=1e-5)
    assert float(programme.load_time(f0, limit, 0.0, free, beta, 0.05)) == 0.05
    assert float(programme.load_time(f0, limit, 1e-15, free, beta, 0.05)) == 0.05
    assert float(programme.load_travel(1.2 * limit / max(beta, 0.5), limit, 1.0 / k, beta)) == 0.0


def test_kernel_layout_covers_every_kernel_effect() -> None:
    assert KERNEL_EFFECTS == BUILT_IN
    for cls in KERNEL_EFFECTS:
        assert f"on:{cls.name}" in ROW.names
        assert all(slot in ROW.names for slot in cls.kernel_slots or ())
        assert all(name in STATE.names and f"{name}0" in ROW.names for name in cls.kernel_state)
