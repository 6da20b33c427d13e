"""Figures of a calibration run: convergence and the 2-parameter GP landscape."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.parameters import ParameterSpace
from smcbayes.plotting import save, subplots

Array = NDArray[np.float64]


def plot_convergence(losses: Array, init: int, path: Path,
                     local: NDArray[np.bool_] | None = None) -> list[Path]:
    """Loss per evaluation and best-so-far (thesis figure 4.22); failures marked at the top.

    Args:
        losses: loss per evaluation in order, NaN for failures, shape ``(N,)`` (kN^2).
        init: size of the initial design (shaded).
        path: output path without suffix.
        local: which evaluations belong to a local search, shape ``(N,)`` (drawn smaller,
            in another colour: hundreds of them would hide the optimisation's).
    """
    fig, ax = subplots(figsize=(7, 4))
    idx = np.arange(1, losses.size + 1)
    ok = np.isfinite(losses)
    local = np.zeros(losses.shape, dtype=bool) if local is None else local
    best = np.fmin.accumulate(np.where(ok, losses, np.inf))
    ax.axvspan(0.5, min(init, losses.size) + 0.5, color="0.92", label="initial design (LHS)")
    ax.plot(idx[ok & ~local], losses[ok & ~local], "o", ms=4, color="tab:blue", label="evaluation")
    if (ok & local).any():
        ax.plot(idx[ok & local], losses[ok & local], ".", ms=2, color="tab:green",
                label="local search (forward model)")
    ax.step(idx, np.where(np.isfinite(best), best, np.nan), where="post", color="tab:red",
            lw=1.6, label="best so far")
    if (~ok).any():
        top = np.nanmax(losses) if ok.any() else 1.0
        ax.plot(idx[~ok], np.full((~ok).sum(), top), "x", color="black", label="failed")
    ax.set_yscale("log")
    ax.set_xlabel("evaluation")
    ax.set_ylabel("loss (kN$^2$)")
    ax.legend(fontsize=8)
    ax.set_title("calibration convergence", fontsize=10)
    fig.tight_layout()
    return save(fig, path)


def _axis(space: ParameterSpace, j: int, u: Array) -> tuple[Array, str]:
    p = space.free[j]
    x = space.from_unit(np.tile(u[:, None], (1, space.dim)))[:, j]
    return (np.log10(x), f"log10 {p.name} ({p.unit})") if p.log else (x, f"{p.name} ({p.unit})")


def plot_landscape(surrogate: Any, space: ParameterSpace, records: list[dict[str, Any]],
                   init: int, candidate: Array | None, truth: Mapping[str, float] | None,
                   path: Path, points: int = 70) -> list[Path]:
    """GP mean and uncertainty of log(loss) over a 2-parameter space (thesis figures 4.8-4.13).

    Args:
        surrogate: fitted :class:`~smcbayes.surrogate.gp.Surrogate` (2 free parameters).
        space: the parameter space.
        records: evaluation records in order (samples and path).
        init: size of the initial design (drawn as crosses; BO points joined by the path).
        candidate: the next candidate in the unit cube, shape ``(1, 2)``, or ``None``.
        truth: true values (synthetic checks), or ``None``.
        path: output path without suffix.
    """
    g = np.linspace(0.0, 1.0, points)
    uu, vv = np.meshgrid(g, g)
    mean, std = surrogate.predict(np.column_stack([uu.ravel(), vv.ravel()]))
    ax_x, label_x = _axis(space, 0, g)
    ax_y, label_y = _axis(space, 1, g)
    names = space.free_names
    theta = np.array([[r["params"][n] for n in names] for r in records], dtype=float)
    u = space.to_unit(theta)
    sx = np.interp(u[:, 0], g, ax_x)
    sy = np.interp(u[:, 1], g, ax_y)
    fig, axes = subplots(1, 2, figsize=(11, 4.4))
    panels = ((mean.reshape(uu.shape) / np.log(10), "GP mean of log10 loss (kN$^2$)", "viridis"),
              (std.reshape(uu.shape) / np.log(10), "GP std of log10 loss", "magma"))
    for ax, (z, title, cmap) in zip(axes, panels, strict=True):
        cs = ax.contourf(ax_x, ax_y, z, levels=30, cmap=cmap)
        fig.colorbar(cs, ax=ax)
        ax.plot(sx[:init], sy[:init], "x", color="white", ms=6, label="initial design")
        ax.plot(sx[init:], sy[init:], "o-", color="white", mfc="black", ms=4, lw=0.8,
                label="BO path")
        if candidate is not None:
            cx = np.interp(candidate[:, 0], g, ax_x)
            cy = np.interp(candidate[:, 1], g, ax_y)
            ax.plot(cx, cy, "*", color="red", ms=13, label="next candidate")
        if truth is not None and all(n in truth for n in names):
            tu = space.to_unit(np.array([[truth[n] for n in names]]))[0]
            ax.plot(np.interp(tu[0], g, ax_x), np.interp(tu[1], g, ax_y), "o", color="tab:blue",
                    ms=9, mec="white", label="truth")
        ax.set_xlabel(label_x)
        ax.set_ylabel(label_y)
        ax.set_title(title, fontsize=10)
    axes[0].legend(fontsize=7, loc="best")
    fig.tight_layout()
    return save(fig, path)
