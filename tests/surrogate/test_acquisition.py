"""Acquisition: candidates inside the cube or box, seeded, near the minimum of a simple GP."""

from __future__ import annotations

import numpy as np
import pytest

from smcbayes.surrogate.acquisition import propose
from smcbayes.surrogate.design import latin_hypercube
from smcbayes.surrogate.gp import Surrogate, fit_surrogate, gp_session

MINIMUM = np.array([0.3, 0.7])


@pytest.fixture(scope="module")
def bowl() -> Surrogate:
    """GP of log(loss) for a smooth bowl with its minimum at (0.3, 0.7), 24 design points."""
    x = latin_hypercube(24, 2, np.random.default_rng(0))
    y = np.log(0.01 + np.sum((x - MINIMUM) ** 2, axis=1))
    with gp_session():
        return fit_surrogate(x, y, "matern52", seed=0, noise=1e-6)


def test_logei_candidate_lies_near_the_minimum(bowl: Surrogate) -> None:
    with gp_session():
        cand, value = propose(bowl, 1, seed=1, restarts=4, raw_samples=64)
    assert cand.shape == (1, 2) and np.isfinite(value)
    assert np.linalg.norm(cand[0] - MINIMUM) < 0.15
    # better than the best design point is expected there: the GP mean is below it
    mean, _ = bowl.predict(cand)
    assert mean[0] < np.min(bowl.log_loss) + 0.5


def test_candidates_are_inside_the_cube_and_reproducible_for_a_seed(bowl: Surrogate) -> None:
    with gp_session():
        a, va = propose(bowl, 2, seed=3, restarts=2, raw_samples=32)
        b, vb = propose(bowl, 2, seed=3, restarts=2, raw_samples=32)
    assert a.shape == (2, 2)
    assert np.all((a >= 0.0) & (a <= 1.0))
    np.testing.assert_array_equal(a, b)
    assert va == vb
    assert np.linalg.norm(a[0] - a[1]) > 1e-3  # a joint batch, not the same point twice


def test_candidates_stay_in_the_trust_region_box(bowl: Surrogate) -> None:
    lo, hi = np.array([0.6, 0.1]), np.array([0.8, 0.3])  # away from the minimum
    with gp_session():
        cand, _ = propose(bowl, 1, seed=2, restarts=2, raw_samples=32, box=(lo, hi))
    assert np.all((cand >= lo) & (cand <= hi))
    with gp_session():
        free, _ = propose(bowl, 1, seed=2, restarts=2, raw_samples=32)
    assert not np.all((free >= lo) & (free <= hi))  # without the box it goes elsewhere
