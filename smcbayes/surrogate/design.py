"""Design of experiments and seeding."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.stats import qmc


def round_seed(seed: int, round_index: int) -> int:
    """A 32-bit seed derived from the run seed and the round, so rounds are reproducible alone.

    Every random step of round ``round_index`` draws from this seed, so a resumed run
    makes the same choices as an uninterrupted one.
    """
    return int(np.random.SeedSequence([int(seed), int(round_index)]).generate_state(1)[0])


def round_rng(seed: int, round_index: int) -> np.random.Generator:
    """A :class:`numpy.random.Generator` for round ``round_index`` of a run seeded ``seed``."""
    return np.random.default_rng(round_seed(seed, round_index))


def latin_hypercube(n: int, dim: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``n`` Latin hypercube points in the unit cube, shape ``(n, dim)``.

    Uses the optimised (random-CD) scipy design, which spreads small designs better than
    a plain random LHS.
    """
    sampler = qmc.LatinHypercube(d=dim, optimization="random-cd", rng=rng)
    return np.asarray(sampler.random(n), dtype=float)
