"""Figures of the posterior stage: corner plot, correlation matrix, predictive bands, and the
curve emulator's active learning round by round."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter
from numpy.typing import NDArray

from smcbayes.errors import ConfigError
from smcbayes.forward.parameters import ParameterSpace
from smcbayes.plotting import MEASURED, grid_shape, save, subplots
from smcbayes.posterior.predictive import Band
from smcbayes.posterior.summary import sampled_coordinates

Array = NDArray[np.float64]


def corner_plot(space: ParameterSpace, theta: Array, path: Path,
                truth: Mapping[str, float] | None = None) -> list[Path]:
    """Corner plot of the draws ``theta`` ``(N, d)`` (user units) in sampled coordinates
    (log10 of log-searched parameters), the truth overlaid if known; written as ``path``
    .png and .svg, whose paths are returned."""
    try:
        # corner imports pyplot at its top: loaded only when a corner plot is drawn
        import corner
    except ImportError:
        raise ConfigError("the corner plot needs the 'corner' package: pip install corner") from None
    x, labels = sampled_coordinates(space, theta)
    truths = None
    if truth is not None:
        t = np.array([[truth[n] for n in space.free_names]])
        truths = list(sampled_coordinates(space, t)[0][0])
    fig = corner.corner(x, fig=Figure(figsize=(_corner_inches(x.shape[1]),) * 2), labels=labels,
                        truths=truths, truth_color="tab:red",
                        quantiles=[0.05, 0.5, 0.95], show_titles=True, title_fmt=".3g",
                        title_kwargs={"fontsize": 8}, label_kwargs={"fontsize": 8},
                        # the density's cells as one image per panel: as vector paths they made an
                        # SVG of about 3 MB that took seconds to write and to open
                        pcolor_kwargs={"rasterized": True})
    return save(fig, path)


def _corner_inches(d: int) -> float:
    """Side (inches) of the figure ``corner.corner`` would make itself for ``d`` parameters:
    2-inch panels 5 % apart, margins of 1 inch (left, bottom) and 0.4 inch."""
    panel, gap = 2.0, 0.05
    return 0.5 * panel + panel * d + panel * (d - 1.0) * gap + 0.2 * panel


def correlation_plot(matrix: Array, labels: Sequence[str], path: Path) -> list[Path]:
    """Heat map of the posterior correlation matrix ``(d, d)`` with the coordinates'
    ``labels`` ``(d,)``; written as ``path`` .png and .svg, whose paths are returned."""
    d = len(labels)
    fig, ax = subplots(figsize=(1.1 * d + 2.5, 1.0 * d + 1.5))
    im = ax.imshow(matrix, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(d), labels, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(d), labels, fontsize=8)
    for i in range(d):
        for j in range(d):
            ax.text(j, i, f"{matrix[i, j]:.2f}", ha="center", va="center", fontsize=7)
    fig.colorbar(im, ax=ax, label="correlation (-)")
    ax.set_title("posterior correlations (sampled coordinates)", fontsize=9)
    fig.tight_layout()
    return save(fig, path)


def bands_plot(bands: Mapping[str, Band], path: Path, title: str) -> list[Path]:
    """Force bands (kN; model 50/90 %, predictive 90 %), the model's median and the
    predictive mean (the point prediction) vs time (s) per configuration, the measured force
    in black; written as ``path`` .png and .svg, whose paths are returned."""
    ids = list(bands)
    nrows, ncols = grid_shape(len(ids))
    fig, axes = subplots(nrows, ncols, figsize=(4.2 * ncols, 3.0 * nrows), squeeze=False)
    for k, cid in enumerate(ids):
        b, ax = bands[cid], axes[k // ncols][k % ncols]
        ax.fill_between(b.time_s, b.force_pred_kN[0], b.force_pred_kN[4], color="tab:blue", alpha=0.15,
                        label="predictive 90 %")
        ax.fill_between(b.time_s, b.force_kN[0], b.force_kN[4], color="tab:blue", alpha=0.3,
                        label="model 90 %")
        ax.fill_between(b.time_s, b.force_kN[1], b.force_kN[3], color="tab:blue", alpha=0.5,
                        label="model 50 %")
        ax.plot(b.time_s, b.force_kN[2], color="tab:blue", lw=1.2, label="model median")
        if b.force_pred_mean_kN is not None:
            ax.plot(b.time_s, b.force_pred_mean_kN, color="tab:orange", lw=1.2, ls="--",
                    label="predictive mean")
        if b.measured is not None:
            ax.plot(*b.measured, color=MEASURED, lw=1.0, label="measured")
            ax.set_title(f"{cid}: coverage 50 % {b.coverage50:.0%}, 90 % {b.coverage90:.0%}", fontsize=9)
        else:
            ax.set_title(f"{cid} (no measured curve)", fontsize=9)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("force (kN)")
        if k == 0:
            ax.legend(fontsize=7, loc="upper left")
    for k in range(len(ids), nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save(fig, path)


def learning_plot(rounds: Sequence[Mapping[str, Any]], active: Mapping[str, Any], path: Path) -> list[Path]:
    """The curve emulator's active learning round by round (:func:`learning_figure`);
    written as ``path`` .png and .svg, whose paths are returned."""
    return save(learning_figure(rounds, active), path)


def learning_figure(rounds: Sequence[Mapping[str, Any]], active: Mapping[str, Any]) -> Figure:
    """Three panels against the active learning's forward runs (those of its starting
    points included), each measure beside the bound the stop asks of the last rounds: the
    emulator's error at fresh posterior draws (nats, log scale); the posterior's move at
    each round and its drift over the last rounds (share of a parameter's range); the
    spread of GP sample functions' posteriors at each round, its running mean over the
    rounds a validation counts, and the reported posterior's spread at each confirmation
    (passed or failed).

    Args:
        rounds: one record a round, as ``refine.jsonl`` keeps them (``round``,
            ``forward_runs`` of the rounds alone, ``error_nats``, ``quantile_shift``,
            ``spread``; ``None`` where a measure was not taken or not finite).
        active: the active learning's record (``start_runs``, ``tolerance_nats``,
            ``bounds``, ``validated_rounds``, ``drifts``, ``confirmations`` (their
            ``forward_runs`` counted with the starting points), ``evaluations``,
            ``converged``).
    """
    start = int(active.get("start_runs") or 0)
    bounds = active.get("bounds") or {}
    x = np.array([start + r["forward_runs"] for r in rounds], dtype=float)
    at_round = {int(r["round"]): start + r["forward_runs"] for r in rounds}
    fig, axes = subplots(3, 1, figsize=(7.0, 7.5), sharex=True)
    err, move, spread = axes
    err.plot(x, _values(rounds, "error_nats"), "o-", color="tab:blue", ms=3,
             label="error at fresh posterior draws")
    err.set_yscale("log")
    # plain numbers (a log axis within a decade labels its ticks as 4 x 10^0), and of the
    # ticks between powers of ten only 2, 3 and 5, which do not crowd
    err.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    err.yaxis.set_minor_formatter(FuncFormatter(_sparse_log_label))
    _bound(err, active.get("tolerance_nats"), "nats")
    err.set_ylabel("error (nats)")
    move.plot(x, _values(rounds, "quantile_shift"), "o-", color="tab:blue", ms=3, label="move over the round")
    drifts = [d for d in active.get("drifts") or [] if d.get("drift") is not None and d["rounds"] in at_round]
    if drifts:
        over = active.get("validated_rounds", 3)
        move.plot([at_round[d["rounds"]] for d in drifts], [d["drift"] for d in drifts], "s",
                  color="tab:purple", ms=5, label=f"drift over the last {over} rounds")
    _bound(move, bounds.get("quantile_shift"), "")
    move.set_ylabel("quantile move (share of range)")
    _spread_panel(spread, x, rounds, active)
    spread.set_xlabel("forward runs of the active learning (its starting points' included)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    verdict = "validated" if active.get("converged") else "not validated"
    fig.suptitle(f"active learning: {len(rounds)} rounds, {active.get('evaluations')} forward runs, "
                 f"{verdict}", fontsize=10)
    fig.tight_layout()
    return fig


def _spread_panel(ax: Any, x: Array, rounds: Sequence[Mapping[str, Any]], active: Mapping[str, Any]) -> None:
    """The spread panel of :func:`learning_figure`: each round's reading, their running mean
    over the rounds a validation counts (the stop bounds that mean), the confirmations'."""
    k = int(active.get("validated_rounds") or 3)
    spreads = _values(rounds, "spread")
    ax.plot(x, spreads, "o", color="tab:blue", ms=3, label="round's spread")
    if len(spreads) >= k:
        # NaN where a round's spread was not finite: its window's mean is not drawn
        mean = np.convolve(spreads, np.full(k, 1.0 / k), mode="valid")
        ax.plot(x[k - 1:], mean, "-", color="tab:blue", lw=1.2, label=f"mean of the last {k} rounds")
    for passed, colour, words in ((True, "tab:green", "confirmed"), (False, "tab:red", "not confirmed")):
        hits = [c for c in active.get("confirmations") or [] if bool(c.get("passed")) == passed
                and c.get("spread") is not None]
        if hits:
            ax.plot([c["forward_runs"] for c in hits], [c["spread"] for c in hits], "*", color=colour, ms=10,
                    label=f"reported posterior's spread, {words}")
    _bound(ax, (active.get("bounds") or {}).get("spread"), "")
    ax.set_ylabel("spread (share of range)")


def _sparse_log_label(value: float, _: Any) -> str:
    """A log axis's minor tick label: the value where its leading digit is 2, 3 or 5."""
    if value <= 0.0:
        return ""
    lead = round(value / 10.0 ** np.floor(np.log10(value)))
    return f"{value:g}" if lead in (2, 3, 5) else ""


def _values(rounds: Sequence[Mapping[str, Any]], key: str) -> Array:
    """``key`` of each round's record ``(R,)``, NaN where it is missing."""
    return np.array([np.nan if r.get(key) is None else float(r[key]) for r in rounds], dtype=float)


def _bound(ax: Any, value: float | None, unit: str) -> None:
    """The stop's bound as a dashed line, when the record gives it."""
    if value is not None:
        ax.axhline(float(value), color="0.3", ls="--", lw=1.0, label=f"bound {value:g} {unit}".rstrip())
