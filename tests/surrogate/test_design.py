"""Design of experiments: Latin hypercube strata, seeding, per-round seeds."""

from __future__ import annotations

import numpy as np
import pytest

from smcbayes.surrogate.design import latin_hypercube, round_rng, round_seed


@pytest.mark.parametrize(("n", "dim"), [(1, 3), (7, 2), (20, 5)])
def test_latin_hypercube_puts_one_point_in_every_stratum_of_every_axis(n: int, dim: int) -> None:
    x = latin_hypercube(n, dim, np.random.default_rng(0))
    assert x.shape == (n, dim) and x.dtype == float
    assert np.all((x >= 0.0) & (x < 1.0))
    for j in range(dim):
        np.testing.assert_array_equal(np.sort(np.floor(n * x[:, j]).astype(int)), np.arange(n))


def test_latin_hypercube_is_reproducible_for_a_seed() -> None:
    a = latin_hypercube(10, 3, np.random.default_rng(5))
    b = latin_hypercube(10, 3, np.random.default_rng(5))
    c = latin_hypercube(10, 3, np.random.default_rng(6))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_latin_hypercube_spreads_better_than_a_random_one() -> None:
    """The optimised design has a lower centred discrepancy than plain random points."""
    from scipy.stats import qmc

    rng = np.random.default_rng(1)
    lhs = np.mean([qmc.discrepancy(latin_hypercube(12, 3, rng)) for _ in range(5)])
    plain = np.mean([qmc.discrepancy(rng.random((12, 3))) for _ in range(5)])
    assert lhs < 0.5 * plain


def test_round_seed_depends_on_seed_and_round_only() -> None:
    assert round_seed(3, 4) == round_seed(3, 4)
    seeds = {round_seed(s, r) for s in range(5) for r in range(20)}
    assert len(seeds) == 100  # every (seed, round) its own
    assert all(0 <= s < 2**32 for s in seeds)
    assert round_seed(1, 2) != round_seed(2, 1)
    assert round_seed(np.int64(3), np.int32(4)) == round_seed(3, 4)


def test_round_rng_gives_the_same_stream_for_the_same_round() -> None:
    """A resumed run draws in round r exactly what an uninterrupted one draws."""
    a = round_rng(7, 3).random(5)
    np.testing.assert_array_equal(a, round_rng(7, 3).random(5))
    np.testing.assert_array_equal(a, np.random.default_rng(round_seed(7, 3)).random(5))
    assert not np.allclose(a, round_rng(7, 4).random(5))
