"""Plain-language notes on the shape of a posterior sample: mass piled at a search bound,
separated modes, and near-collinear ridges.

None of these makes a posterior wrong (the sample may be a faithful draw from a posterior
that is truncated, bimodal or ridge-shaped), but each changes how its summary must be read,
and each has a remedy the user should hear about: widen the bound (or, at the end of the
parameter's physical range, add physics), look at the corner plot
rather than the mean and sd, fix one of two parameters the data identify only together.
All tests run on unit-cube coordinates (log10 where a parameter is searched so), so the
thresholds are shares of the search range.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from smcbayes.errors import ParameterOnBoundWarning
from smcbayes.forward.parameters import ParameterSpace
from smcbayes.forward.ranges import PHYSICAL_RANGES

Array = NDArray[np.float64]

EDGE = 0.02
"""A 5 % (95 %) quantile within this share of the range from the lower (upper) bound
touches the bound."""
INFORMED = 0.8
"""Only a parameter whose 90 % interval is narrower than this share of its range is said
to pile up at a bound (a posterior spanning the range is the prior, said elsewhere)."""
RIDGE_R = 0.95
"""|correlation| above which two parameters are identified only as a combination."""
BINS = 40
MODE_MASS = 0.1
"""Each of two modes must hold at least this share of the mass."""
VALLEY = 0.25
"""The density between two modes must fall below this share of the lower peak."""


def _bound_notes(space: ParameterSpace, unit: Array) -> list[str]:
    notes = []
    q05, q95 = np.quantile(unit, [0.05, 0.95], axis=0)
    for k, p in enumerate(space.free):
        if q95[k] - q05[k] >= INFORMED:
            continue
        for hit, side, bound, want in ((q05[k] < EDGE, "lower", p.lower, "below"),
                                       (q95[k] > 1.0 - EDGE, "upper", p.upper, "above")):
            if hit:
                known = PHYSICAL_RANGES.get(p.name)
                physical = None if known is None else (known.lower if side == "lower" else known.upper)
                notes.append(f"the posterior of {p.name} piles up at its {side} bound "
                             f"({bound:g} {p.unit}): the data want {p.name} {want} {bound:g}; "
                             + ParameterOnBoundWarning.remedy(p.name, side, bound, physical))
    return notes


def bimodal_split(x: Array) -> float | None:
    """The valley between two separated modes of a 1-D sample on [0, 1], else ``None``.

    The histogram (:data:`BINS` bins, smoothed over three bins) must have two local maxima
    with a minimum between them below :data:`VALLEY` of the lower one, and each side of
    that minimum must hold :data:`MODE_MASS` of the sample.
    """
    hist, edges = np.histogram(np.clip(x, 0.0, 1.0), bins=BINS, range=(0.0, 1.0))
    h = np.convolve(hist.astype(float), np.ones(3) / 3.0, mode="same")
    peaks = [i for i in range(BINS) if h[i] > 0 and h[i] >= h[max(i - 1, 0)]
             and h[i] > h[min(i + 1, BINS - 1)]]
    if len(peaks) < 2:
        return None
    order = sorted(peaks, key=lambda i: h[i], reverse=True)
    for j in order[1:]:
        a, b = sorted((order[0], j))
        valley = a + int(np.argmin(h[a:b + 1]))
        left = hist[:valley + 1].sum() / max(hist.sum(), 1)
        if h[valley] < VALLEY * min(h[a], h[b]) and MODE_MASS <= left <= 1.0 - MODE_MASS:
            return float(0.5 * (edges[valley] + edges[valley + 1]))
    return None


def _mode_notes(space: ParameterSpace, unit: Array) -> list[str]:
    notes = []
    for k, p in enumerate(space.free):
        split = bimodal_split(unit[:, k])
        if split is not None:
            value = float(space.from_unit(np.full((1, space.dim), split))[0, k])
            notes.append(f"the posterior of {p.name} has two separated modes (split near {value:.3g} "
                         f"{p.unit}): its mean and sd describe neither; read the corner plot, and "
                         "check that the sampler visited both")
    return notes


def _ridge_notes(space: ParameterSpace, unit: Array) -> list[str]:
    if space.dim < 2 or unit.shape[0] < 3:
        return []
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.corrcoef(unit, rowvar=False)
    names, notes = space.free_names, []
    for i in range(space.dim):
        for j in range(i + 1, space.dim):
            if np.isfinite(r[i, j]) and abs(r[i, j]) > RIDGE_R:
                notes.append(f"{names[i]} and {names[j]} lie on a ridge (r = {r[i, j]:+.2f}): the data "
                             "identify only their combination; fix one of them or add data that "
                             "separate them")
    return notes


def shape_notes(space: ParameterSpace, unit: Array) -> list[str]:
    """Notes on a posterior sample ``unit`` (S, d) in unit-cube coordinates (equal weights)."""
    unit = np.asarray(unit, dtype=float)
    if unit.ndim != 2 or unit.shape[0] < 20:
        return []
    return _bound_notes(space, unit) + _mode_notes(space, unit) + _ridge_notes(space, unit)
