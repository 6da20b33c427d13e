"""The re-calibration escapes the basin of a base optimum that mimics the missing effect."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from smcbayes.diagnose.fit import FitSettings, initial_population, refit
from smcbayes.diagnose.synthetic import BASE_TRUTH, EFFECT_TRUTH
from smcbayes.errors import ConfigError

#: A base optimum of compliant-press data: slip-dominated, viscosity at its upper bound,
#: where the truth is viscous (tau_c = 0.5 MPa); found by calibrating the base model.
SLIP_OPTIMUM = {"n": 0.31, "tau_star_Pa": 9.3e4, "B_Pa_s": 9.9e4, "tau_c_MPa": 0.019, "m": 1.41}


def test_refit_leaves_the_base_basin_on_compliance_data(synthetic_ctx) -> None:
    """From the wrong-basin warm start the default strategy reaches the noise level.

    The search of the earlier releases (warm start and effect scan only, crossover 0.7)
    ends at 44 and 60 times the loss of the true parameters for two of these three seeds.
    """
    ctx = synthetic_ctx("press_compliance")
    effect = ("press_compliance",)
    space = ctx.model(effect).space
    truth = {**BASE_TRUTH, **EFFECT_TRUTH["press_compliance"]}
    floor = float(np.mean(ctx.losses(effect, np.array([[truth[n] for n in space.free_names]]),
                                     ctx.ids)[0]))
    start = ctx.start(effect, SLIP_OPTIMUM)
    assert float(np.mean(ctx.losses(effect, start, ctx.ids)[0])) > 100.0 * floor
    settings = replace(FitSettings(), population=32, generations=25, polish=3)
    losses = [refit(ctx, effect, ctx.ids, start, settings, np.random.default_rng(s)).loss
              for s in range(3)]
    assert float(np.median(losses)) < 5.0 * floor


def test_initial_population_holds_warm_start_scan_and_global_starts() -> None:
    rng = np.random.default_rng(0)
    u0 = np.full(6, 0.5)
    settings = FitSettings(population=20, lhs_starts=4, global_starts=5)
    pop = initial_population(u0, [5], settings, rng)
    assert pop.shape == (20, 6)
    np.testing.assert_array_equal(pop[0], u0)
    scan = pop[1:5]
    np.testing.assert_array_equal(scan[:, :5], 0.5)  # base parameters at the optimum
    assert np.ptp(scan[:, 5]) > 0.5  # the effect parameter spread over its range
    glob = pop[5:10]
    assert np.all(np.ptp(glob, axis=0) > 0.3)  # every parameter spread
    assert np.all((pop >= 0.0) & (pop <= 1.0))


@pytest.mark.parametrize("bad", [{"restarts": 0}, {"crossover": 1.5}, {"global_starts": -1}])
def test_fit_settings_reject_unusable_budgets(bad: dict) -> None:
    with pytest.raises(ConfigError):
        FitSettings(**bad).check()


def test_small_population_keeps_perturbations_of_the_base_parameters() -> None:
    """A population of 6 still varies every base parameter (the scan rows do not)."""
    pop = initial_population(np.full(6, 0.5), [5], FitSettings(population=6),
                             np.random.default_rng(1))
    assert pop.shape == (6, 6)
    assert np.all(np.ptp(pop[:, :5], axis=0) > 0.0)
    assert np.sum(np.all(pop[:, :5] == 0.5, axis=1)) <= 2  # warm start and one scan row


def test_a_process_pool_gives_the_serial_diagnosis(synthetic_ctx) -> None:
    """The diagnosis's forward runs go through the executor: a pool of two processes gives
    the same re-fit as in process, and the runs are counted."""
    from smcbayes.simulation.executors.local import LocalExecutor

    serial = synthetic_ctx("press_compliance")
    pooled = replace(serial, executor=lambda: LocalExecutor(2))
    fits = []
    for ctx in (serial, pooled):
        fresh = replace(ctx, _models={}, _runners={})
        try:
            fits.append(refit(fresh, ("press_compliance",), fresh.ids, fresh.start(("press_compliance",)),
                              FitSettings(population=10, generations=2, lhs_starts=4, global_starts=2,
                                          restarts=1, polish=2), np.random.default_rng(3)))
            assert fresh.forward_runs > 0
        finally:
            fresh.close()
    np.testing.assert_array_equal(fits[0].theta, fits[1].theta)
    assert fits[0].loss == fits[1].loss
