"""One round of the curve emulator's active learning: which forward runs it asks for.

All but a share :data:`EXPLORATION` of a round's runs are draws of the emulated posterior
pooled with those of GP sample functions (:mod:`smcbayes.posterior.curve_spread`), leaning
to where the functions disagree and to the quantiles they move
(:func:`~smcbayes.posterior.curve_aim.targeted`); the rest explore: draws of the posterior
mass that the expected loss's variance term hides
(:func:`~smcbayes.posterior.curves.log_hidden_mass`), the difference between the posterior
of the emulator's mean curves and the emulated one, which uses the expected loss
(:data:`~smcbayes.posterior.curve_sample.EXPECTED_LOSS`).  Where the emulator has few
points its variance raises the expected loss, so the emulated posterior stays out of a
region until rounds have put points there, and it creeps into a tail round by round.  The
hidden mass is where the mean curves say the data may fit and the variance keeps the
emulated posterior out; where the emulator is sure it vanishes, so the exploration spends
no runs where the posterior draws already settle the emulator.  The mean curves' posterior
itself leaned there too little: on the accuracy benchmark's second case, whose exact
posterior holds 40 % of its mass at the far end of a curved ridge, the median of the
emulator's log posterior at that end's exact draws lay 22, 16 and 6 nats below its best
after 4, 6 and 9 rounds with the mean curves, 65, 61 and 29 with the expected loss.  The
emulated posterior is sampled by adaptive importance
sampling on the emulator (the correction's algorithm, no forward run): emcee chains started
at the best point under-sample a flat arm of the accuracy benchmark's first case (1.2 % of
the mass where the exact posterior has 6.5 %), and a stopping rule judged on them stopped
early and called a posterior reliable that was 0.34 off in a correlation.  The
exploration's density, which only has to be reached, not weighed, is sampled by emcee,
whose walkers go on from round to round.  :mod:`smcbayes.posterior.curve_stage` decides
from the rounds when the learning stops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from smcbayes.posterior.correct import CorrectionSettings, ImportanceSample
from smcbayes.posterior.curve_aim import targeted
from smcbayes.posterior.curve_sample import ROUND_ESS, START_ROWS, emulator_sample, sample_chains
from smcbayes.posterior.curve_spread import function_posteriors, function_spread
from smcbayes.posterior.curves import CurveEmulator, log_hidden_mass

Array = NDArray[np.float64]

EXPLORATION = 0.25
"""Share of a round's runs drawn from the hidden posterior mass (the exploration); the rest
are draws of the emulated posterior.  The spread that decides the stop falls with the runs where
the posterior lives: on the measured thesis trials an emulator of 60 calibration points and
340 draws of the posterior had a spread of 0.089, while the active learning, with half its
runs exploring, read 0.10-0.15 after 400-800 runs."""

ROUND_STEPS = 1000
"""Most emcee steps of the first round's exploration, whose walkers start at the best
training point."""

WARM_STEPS = 250
"""emcee steps of a later round's exploration: its walkers go on from where the last
round's stopped, already spread over a posterior that a round's new runs only nudge, so
they need no way in.  The sampling only picks the exploration's few runs and a share of
the importance sampling's first proposal."""

ROUND_DRAWS = 20000
"""Most proposal draws of a round's importance sample of the emulated posterior (it stops
at the correction's ESS and k-hat targets)."""


@dataclass
class Round:
    """One round's choice of forward runs and the emulated posterior it was drawn from.

    Attributes:
        new: the rows to simulate ``(B, d)``: the first ``posterior`` are draws of the
            emulated posterior pooled with its GP sample functions', leaning to where
            they disagree and to the quantiles they move
            (:func:`~smcbayes.posterior.curve_aim.targeted`), the rest draws of the
            posterior mass the expected loss's variance hides (the exploration).
        posterior: how many of ``new`` are posterior draws.
        sample: the round's importance sample of the emulated posterior (the mean's).
        spread: how far its sample functions move its 5/50/95 % quantiles (share of the unit cube).
        error_weight: the weights ``(posterior,)`` of the posterior draws' errors in the
            round's mean error (:func:`~smcbayes.posterior.curve_aim.targeted`).
        aim: what ``refine.jsonl`` keeps of the aiming
            (:func:`~smcbayes.posterior.curve_aim.targeted`).
        explorers: where the exploration's walkers stopped ``(W, d)`` (W the ensemble's
            walkers); the next round's go on from there.
    """

    new: Array
    posterior: int
    sample: ImportanceSample
    spread: float
    error_weight: Array
    aim: dict[str, float] = field(default_factory=dict)
    explorers: Array | None = None


def next_round(emulator: CurveEmulator, n_eff: float, size: int, start: Array, spec: CorrectionSettings,
               rng: np.random.Generator, walkers: int, explorers: Array | None = None) -> Round:
    """The next batch of ``size`` rows: all but a share :data:`EXPLORATION` (fewer when the
    posterior rests on fewer support points) drawn from the emulated posterior, sampled by
    importance (:data:`ROUND_DRAWS` emulator evaluations; its first proposal fitted to the
    earlier round's posterior draws ``start`` ``(S, d)`` and the exploration's draws, a
    quarter of :data:`~smcbayes.posterior.curve_sample.START_ROWS` or as many as
    the chains hold; on the first round, whose ``start`` holds only the best training
    points, nearly all the exploration's; twice as many draws once more when its ESS is below
    :data:`~smcbayes.posterior.curve_sample.ROUND_ESS`) and pooled with the posteriors of GP
    sample functions on a support of its points, leaning to where they disagree and to the
    quantiles they move (:func:`~smcbayes.posterior.curve_aim.targeted`), the rest from the
    hidden posterior mass (:func:`~smcbayes.posterior.curves.log_hidden_mass`; emcee,
    :data:`ROUND_STEPS` steps from the best training point or,
    given the last round's walkers ``explorers`` ``(W, d)``, :data:`WARM_STEPS` from there;
    the round keeps where they stopped)."""
    d = emulator.x.shape[1]
    centre = emulator.x[np.argmin(emulator.features.loss(emulator.y))]
    steps = ROUND_STEPS if explorers is None else WARM_STEPS
    chains = sample_chains(emulator, n_eff, rng, centre, steps, walkers, start=explorers,
                           log_prob=log_hidden_mass(emulator, n_eff))
    # a rejected emcee move repeats its walker's row: simulated twice it would add nothing
    explored = np.unique(chains.samples.reshape(-1, d), axis=0)
    # after the first round mostly the last round's posterior, the exploration's draws a
    # quarter that widens it; on the first round nearly all are the exploration's, which
    # avoid where the emulator is sure, and the adaptive iterations find the posterior
    count = min(len(explored), max(START_ROWS // 4, START_ROWS - len(start)))
    share = explored[rng.choice(len(explored), count, replace=False)]
    sample = emulator_sample(emulator, n_eff, np.vstack([start, share]), spec, ROUND_DRAWS, rng)
    if sample.ess < ROUND_ESS:
        # too few to measure the round's move by: once more, twice as long, from what it found
        found = sample.resample(START_ROWS // 2, rng)
        sample = emulator_sample(emulator, n_eff, np.vstack([found, share]), spec, 2 * ROUND_DRAWS, rng)
    # the posterior draws from the pooled posterior the stage reports, leaning to where its
    # functions disagree and to the quantiles they move: there the next runs settle it
    posteriors = function_posteriors(emulator, n_eff, sample, rng)
    # functions resting on few points of a round's sample (fewer draws than the stage's
    # final one; an ESS of a few hundred on the measured thesis trials) still count: there
    # some did in every round, and the rounds could never validate; the stage's own check asks it
    spread = function_spread([posteriors], sample, [str(k) for k in range(d)])
    rows, error_weight, aim = targeted(posteriors, sample.unit[posteriors.rows],
                                      max(1, size - math.ceil(EXPLORATION * size)), rng)
    # fewer distinct posterior points (a posterior on few support points): more exploration
    drawn = len(rows)
    new = np.vstack([sample.unit[posteriors.rows[rows]],
                     explored[rng.choice(len(explored), size - drawn, replace=size - drawn > len(explored))]])
    return Round(new, drawn, sample, spread["max_quantile_shift"], error_weight, aim, chains.last)
