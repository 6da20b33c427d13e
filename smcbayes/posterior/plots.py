"""Figures of the posterior stage: corner plot, correlation matrix, predictive bands."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
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
        ax.fill_between(b.time_s, b.force_kN[0], b.force_kN[4], color="tab:blue", alpha=0.3, label="model 90 %")
        ax.fill_between(b.time_s, b.force_kN[1], b.force_kN[3], color="tab:blue", alpha=0.5, label="model 50 %")
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
