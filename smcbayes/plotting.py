"""Figures shared across the package: measured in black, simulated in colour.

Figures are :class:`matplotlib.figure.Figure` objects built with the object-oriented API
and written with ``fig.savefig``: they never touch pyplot's global state or the user's
backend (a notebook keeps its own), and need no display.  Every figure is written as PNG
and SVG, with units on every axis and configuration names in titles or legends.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps, rcParams
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.transforms import Bbox
from numpy.typing import NDArray

from smcbayes.forward.result import SimulationResult

Array = NDArray[np.float64]
MEASURED = "black"


def subplots(nrows: int = 1, ncols: int = 1, figsize: tuple[float, float] | None = None,
             **kwargs: Any) -> tuple[Figure, Any]:
    """A new figure (size in inches) and its axes, like ``pyplot.subplots`` but outside
    pyplot: the figure is not registered with any backend; ``kwargs`` go to
    :meth:`matplotlib.figure.Figure.subplots` (``squeeze``, ``sharey``, ``gridspec_kw``)."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def pyplot() -> Any:
    """matplotlib.pyplot, for scripts that want pyplot's figures; the backend is left as the
    user or matplotlib chose it (matplotlib falls back to Agg without a display).  The
    package's own figures use :func:`subplots` instead."""
    # imported on demand: pyplot resolves a backend on first use, which plain figures avoid
    import matplotlib.pyplot as plt

    return plt


def save(fig: Figure, path: str | Path) -> list[Path]:
    """Write ``fig`` as ``path`` with .png and .svg suffixes; returns both paths.

    A figure made through pyplot is closed afterwards (pyplot would keep it alive); a plain
    :class:`~matplotlib.figure.Figure` is left to the caller, who may still display it.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    out = [path.with_suffix(".png"), path.with_suffix(".svg")]
    box = _tight_box(fig)
    fig.savefig(out[0], dpi=130, bbox_inches=box)
    fig.savefig(out[1], bbox_inches=box)
    plt = sys.modules.get("matplotlib.pyplot")
    if plt is not None and getattr(fig.canvas, "manager", None) is not None:
        plt.close(fig)
    return out


def _tight_box(fig: Figure) -> Bbox | str:
    """The box (inches) around ``fig``'s drawn content and the saving margin
    (``savefig.pad_inches``), measured once for both of its files; ``"tight"`` (measured by
    each save) for a figure with a layout engine, which every save lays out again anyway
    (``tight_layout`` leaves one), or a margin that is not a number.  With ``"tight"`` each
    save would lay out a figure without an engine once more just to measure it: the
    posterior's corner plot of eight parameters took 4.5 s to write that way, 2.9 s with
    one box."""
    pad = rcParams["savefig.pad_inches"]
    if fig.get_layout_engine() is not None or not isinstance(pad, (int, float)):
        return "tight"
    fig.draw_without_rendering()
    return fig.get_tightbbox().padded(pad)


def grid_shape(count: int, cols: int = 3) -> tuple[int, int]:
    """Rows and columns of a panel grid for ``count`` panels."""
    cols = min(cols, max(count, 1))
    return math.ceil(count / cols), cols


def mixed_force(time_s: Array, force_kN: Array, delays_s: Array, t_end_s: float,
                points: int = 600) -> tuple[Array, Array]:
    """The mean of one simulated force curve ``(T,)`` delayed by each of ``delays_s``
    ``(S,)`` (its first value before, its last after), on ``points`` times over [0,
    ``t_end_s``]: ``(time_s, force_kN)``."""
    ok = np.isfinite(time_s) & np.isfinite(force_kN)
    t, f = time_s[ok], force_kN[ok]
    grid = np.linspace(0.0, t_end_s, points)
    if not t.size:
        return grid, np.full(points, np.nan)
    return grid, np.mean([np.interp(grid - d, t, f) for d in delays_s], axis=0)


def plot_simulation(results: Mapping[str, SimulationResult],
                    measured: Mapping[str, tuple[Array, Array]], path: str | Path,
                    title: str, row: int = 0, delays_s: Mapping[str, float] | None = None,
                    mixed_delays_s: Mapping[str, Sequence[float]] | None = None) -> list[Path]:
    """Force and ram displacement vs time per configuration over the closing phase.

    Args:
        results: simulation per configuration (row ``row`` is drawn).
        measured: measured force curve per configuration, ``(time_s, force_kN)``.
        path: output path without suffix.
        title: figure title (e.g. parameters and effects that were on).
        delays_s: per configuration, a delay (s) of the simulated closing (a contact
            offset over the set speed), drawn and named in the panel's title.
        mixed_delays_s: per configuration without a contact of its own (a trial not
            fitted), the delays (s) of the training trials' contacts: its force is drawn
            as the mean of the curves at each (as its errors are judged,
            :func:`smcbayes.data.loss.mixed_force_pair`), its displacement at their mean.
    """
    ids = list(results)
    nrows, ncols = grid_shape(len(ids))
    fig, axes = subplots(nrows, ncols, figsize=(4.2 * ncols, 3.0 * nrows), squeeze=False)
    colours = colormaps["tab10"]
    for k, cid in enumerate(ids):
        ax = axes[k // ncols][k % ncols]
        res = results[cid]
        mixed = np.asarray((mixed_delays_s or {}).get(cid, ()), dtype=float)
        delay = float(np.mean(mixed)) if mixed.size else float((delays_s or {}).get(cid, 0.0))
        t, f, d = res.time_s[row] + delay, res.force_kN[row], res.displacement_mm[row]
        switch = res.switch_time_s[row] + (float(np.max(mixed)) if mixed.size else delay)
        t_end = switch * 1.15 if np.isfinite(switch) else t[-1]
        if cid in measured:
            tm, fm = measured[cid]
            ax.plot(tm, fm, color=MEASURED, lw=1.2, label="measured force")
            t_end = max(t_end, tm[-1] * 1.05)
        mask = t <= t_end
        if mixed.size > 1:
            tf, ff = mixed_force(res.time_s[row], f, mixed, t_end)
            ax.plot(tf, ff, color=colours(0), lw=1.5, label="simulated force")
            ax.set_title(f"{cid} (mean over {mixed.size} training contacts)", fontsize=10)
        else:
            ax.plot(t[mask], f[mask], color=colours(0), lw=1.5, label="simulated force")
            ax.set_title(cid if delays_s is None and not mixed.size
                         else f"{cid} (contact offset: closing {delay:+.2f} s later)", fontsize=10)
        ax.set_xlim(0, t_end)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("force (kN)")
        ax2 = ax.twinx()
        ax2.plot(t[mask], d[mask], color=colours(1), lw=1.0, ls="--", label="simulated ram displacement")
        ax2.set_ylabel("ram displacement (mm)")
        if k == 0:
            lines = ax.get_lines() + ax2.get_lines()
            ax.legend(lines, [ln.get_label() for ln in lines], fontsize=7, loc="upper left")
    for k in range(len(ids), nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save(fig, path)


def plot_flow_front(result: SimulationResult, time_s: Array, fill: Array, x_faces_mm: Array,
                    y_faces_mm: Array, path: str | Path, title: str, row: int = 0,
                    solid: Array | None = None) -> list[Path]:
    """Filled area of the mould at a few instants (2-D solver) next to the force curve.

    Args:
        result: simulation of one configuration (row ``row`` is drawn).
        time_s: snapshot times (s), ``(K,)``.
        fill: fill fraction per cell at those times, ``(K, NX, NY)`` (NX along the length).
        x_faces_mm, y_faces_mm: cell faces relative to the mould centre (mm).
        path: output path without suffix.
        title: figure title.
        solid: solid fraction per cell at those times, ``(K, NX, NY)`` (NaN where empty), for
            a porous charge; its last snapshot is drawn in a third panel.
    """
    if solid is None:
        fig, (ax, axf) = subplots(1, 2, figsize=(10.0, 4.2), gridspec_kw={"width_ratios": [1, 1.3]})
    else:
        fig, (ax, axs, axf) = subplots(1, 3, figsize=(14.5, 4.2),
                                       gridspec_kw={"width_ratios": [1, 1, 1.3]})
        _solid_panel(fig, axs, solid[-1], float(time_s[-1]), x_faces_mm, y_faces_mm)
    # cell centres plus the walls (edge values), so that a filled wall cell reaches the wall
    xc = np.concatenate([x_faces_mm[:1], 0.5 * (x_faces_mm[1:] + x_faces_mm[:-1]), x_faces_mm[-1:]])
    yc = np.concatenate([y_faces_mm[:1], 0.5 * (y_faces_mm[1:] + y_faces_mm[:-1]), y_faces_mm[-1:]])
    colours = colormaps["viridis"](np.linspace(0.0, 0.9, max(len(time_s), 2)))
    for k in range(len(time_s) - 1, -1, -1):  # latest first, so earlier areas are drawn on top
        ax.contourf(xc, yc, np.pad(fill[k], 1, mode="edge").T, levels=[0.5, 2.0], colors=[colours[k]],
                    alpha=0.85)
        ax.plot([], [], color=colours[k], lw=6, label=f"t = {time_s[k]:.2f} s")
    ax.add_patch(Rectangle((x_faces_mm[0], y_faces_mm[0]), x_faces_mm[-1] - x_faces_mm[0],
                           y_faces_mm[-1] - y_faces_mm[0], fill=False, color="black", lw=1.5))
    ax.set_xlim(x_faces_mm[0] * 1.04, x_faces_mm[-1] * 1.04)
    ax.set_ylim(y_faces_mm[0] * 1.04, y_faces_mm[-1] * 1.04)
    ax.set_aspect("equal")
    ax.set_xlabel("x along the mould (mm)")
    ax.set_ylabel("y across the mould (mm)")
    ax.set_title("filled area (fill fraction > 0.5)", fontsize=10)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    t, f = result.time_s[row], result.force_kN[row]
    t_end = result.switch_time_s[row] * 1.1 if np.isfinite(result.switch_time_s[row]) else t[-1]
    mask = t <= t_end
    axf.plot(t[mask], f[mask], color=colormaps["tab10"](0), lw=1.5, label="simulated force")
    for k, tk in enumerate(time_s):
        axf.axvline(tk, color=colours[k], lw=1.0, ls=":")
    axf.set_xlim(0, t_end)
    axf.set_xlabel("time (s)")
    axf.set_ylabel("force (kN)")
    axf.set_yscale("log")
    positive = f[mask][f[mask] > 0]
    if positive.size:
        # the first contact starts from zero force; show four decades below the peak
        axf.set_ylim(bottom=max(float(positive.min()), 1e-4 * float(positive.max())))
    axf.set_title(result.config_id, fontsize=10)
    axf.legend(fontsize=7, loc="upper left")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save(fig, path)


def _solid_panel(fig: Figure, ax: Any, solid: Array, time_s: float, x_faces_mm: Array,
                 y_faces_mm: Array) -> None:
    """Solid fraction per cell ``(NX, NY)`` (NaN where empty) over the mould outline."""
    mesh = ax.pcolormesh(x_faces_mm, y_faces_mm, np.ma.masked_invalid(solid).T, cmap="magma",
                         shading="flat")
    fig.colorbar(mesh, ax=ax, label="solid fraction (-)", shrink=0.85)
    ax.set_aspect("equal")
    ax.set_xlabel("x along the mould (mm)")
    ax.set_ylabel("y across the mould (mm)")
    ax.set_title(f"solid fraction at t = {time_s:.2f} s", fontsize=10)
