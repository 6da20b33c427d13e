"""Where a band configuration lies outside the training set, and the training groups whose
leave-out refits put them in the same place.

The bands' error model is learnt from out-of-sample residuals of the training trials
(:mod:`smcbayes.posterior.crossfit`).  A trial at a closing speed outside the fitted range,
or with a charge no training trial has, errs more than a training trial left out on its
own, since that one still has neighbours at its speed and with its charge.  Its residuals
are matched by leaving out a whole group instead: for a speed above the fitted range, every
trial at the highest training speed (predicted from the slower ones); below it, every
trial at the lowest; for a new charge, every trial of each training charge in turn
(predicted from the other charges).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from smcbayes.config.project import ConfigurationSpec, ProjectConfig

SPEED_TOLERANCE = 0.01
"""Relative margin by which a set speed may lie outside the training speeds' range and
still count as inside it."""

Group = tuple[int, ...]


def _charge_key(cfg: ConfigurationSpec) -> tuple[Any, ...]:
    """What makes two charges alike for the bands: shape, size and the mould they fill."""
    c, m = cfg.charge, cfg.mould
    pieces = tuple(tuple(sorted(piece.model_dump().items())) for piece in c.pieces or [])
    return (c.shape, c.coverage_pct, c.length_mm, c.width_mm, pieces, m.length_mm, m.width_mm)


def _speed_side(v: float, speeds: Sequence[float]) -> str | None:
    """``"above"`` or ``"below"`` the range of ``speeds`` (mm/s) beyond the tolerance, else None."""
    lo, hi = min(speeds), max(speeds)
    if v > hi * (1 + SPEED_TOLERANCE):
        return "above"
    if v < lo * (1 - SPEED_TOLERANCE):
        return "below"
    return None


def extrapolation_notes(project: ProjectConfig, train_ids: Sequence[str],
                        band_ids: Sequence[str]) -> dict[str, list[str]]:
    """Why each band configuration lies outside what the training configurations span.

    Two plain checks: a set closing speed outside the range of the training speeds (by more
    than :data:`SPEED_TOLERANCE`), and a charge (shape, size, mould) that no training
    configuration has.

    Returns:
        per band configuration, the reasons in words (empty where it interpolates).
    """
    train = [project.get(c) for c in train_ids]
    if not train:
        return {cid: [] for cid in band_ids}
    speeds = [c.press.speed_mm_s for c in train]
    charges = {_charge_key(c) for c in train}
    notes: dict[str, list[str]] = {}
    for cid in band_ids:
        cfg, why = project.get(cid), []
        v = cfg.press.speed_mm_s
        if _speed_side(v, speeds) is not None:
            why.append(f"set speed {v:g} mm/s outside the fitted {min(speeds):g}-{max(speeds):g} mm/s")
        if _charge_key(cfg) not in charges:
            why.append("a charge none of the fitted trials has")
        notes[cid] = why
    return notes


def leave_out_groups(project: ProjectConfig, train_ids: Sequence[str], cid: str) -> tuple[list[Group], str]:
    """The training groups (indices into ``train_ids``) whose leave-out refits match the gap
    between configuration ``cid`` and the training set, and that gap in words.

    No groups (and an empty text) where ``cid`` interpolates, or where the training set has
    a single speed (for a speed gap) or a single charge (for a charge gap): leaving that out
    would leave nothing to fit.
    """
    train = [project.get(c) for c in train_ids]
    if not train:
        return [], ""
    cfg = project.get(cid)
    speeds = [c.press.speed_mm_s for c in train]
    groups: list[Group] = []
    words: list[str] = []
    side = _speed_side(cfg.press.speed_mm_s, speeds)
    if side is not None and _speed_side(min(speeds), [max(speeds)]) is not None:
        edge = max(speeds) if side == "above" else min(speeds)
        groups.append(tuple(i for i, v in enumerate(speeds) if _speed_side(v, [edge]) is None))
        words.append(f"the {edge:g} mm/s trials predicted from the "
                     f"{'slower' if side == 'above' else 'faster'} ones")
    keys = [_charge_key(c) for c in train]
    distinct = list(dict.fromkeys(keys))
    if _charge_key(cfg) not in distinct and len(distinct) >= 2:
        groups.extend(tuple(i for i, k in enumerate(keys) if k == key) for key in distinct)
        words.append("each training charge predicted from the others")
    return groups, " and ".join(words)
