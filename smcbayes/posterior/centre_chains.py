"""Metropolis-Hastings chains on the exact posterior that carry centres of the proposals.

A posterior can have a long arm that a weighted sample sees mostly near its root; centres
drawn afresh from the sample stay there, while a chain that reaches the arm walks along it
and takes its kernel with it (see :mod:`smcbayes.posterior.correct`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from smcbayes.posterior.proposal import Proposal, log_t_pairwise

Array = NDArray[np.float64]


@dataclass
class CentreChains:
    """Metropolis-Hastings chains on the exact posterior that carry the first centres.

    A draw from the Student-t kernel centred at a chain's position is that chain's proposal
    (see :meth:`advance`), so each iteration moves every chain whose kernel was drawn from
    at no extra forward run.  A chain starts at a centre of the first proposal (an emulator
    draw or a GP training point) with an unknown target value and accepts its first draw
    with a finite target.

    Attributes:
        position: chain positions in the unit cube, ``(C, d)``.
        log_target: exact log posterior at the positions, ``(C,)`` (-inf before the first move).
    """

    position: Array
    log_target: Array = field(default_factory=lambda: np.empty(0))

    def __post_init__(self) -> None:
        if self.log_target.size != self.position.shape[0]:
            self.log_target = np.full(self.position.shape[0], -np.inf)

    def advance(self, proposal: Proposal, draws: Array, kernel: Array, log_target: Array,
                rng: np.random.Generator) -> None:
        """One Metropolis-Hastings step per chain from the ``draws`` ``(n, d)`` of ``proposal``,
        the kernel each came from ``(n,)`` and their exact log posterior ``(n,)``.

        Chain c at x proposes y, the first draw of kernel c, and accepts with probability
        ``min(1, pi(y) t(x; y, V(y)) / (pi(x) t(y; x, V(x))))``, V the kernel scale the fit
        gives a centre at that position (``proposal.chol_at``; equal scales cancel).  A chain
        whose kernel is not centred at its position (a proposal kept from an earlier
        iteration) does not move.
        """
        count = min(self.position.shape[0], proposal.centres.shape[0])
        centred = np.all(proposal.centres[:count] == self.position[:count], axis=1)
        own = np.flatnonzero((kernel >= 0) & (kernel < count))
        own = own[centred[kernel[own]]]
        _, first = np.unique(kernel[own], return_index=True)
        pick = own[first]
        chain, y = kernel[pick], draws[pick]
        with np.errstate(invalid="ignore"):
            log_ratio = log_target[pick] - self.log_target[chain]
        if proposal.chol_at is not None and pick.size:
            x = self.position[chain]
            log_ratio += (log_t_pairwise(x, y, proposal.chol_at(y), proposal.nu)
                          - log_t_pairwise(y, x, proposal.chol[chain], proposal.nu))
        move = np.isfinite(log_target[pick]) & (np.log(rng.random(pick.size))
                                                < np.nan_to_num(log_ratio, nan=-np.inf))
        self.position[chain[move]], self.log_target[chain[move]] = y[move], log_target[pick][move]
