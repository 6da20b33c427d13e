"""Figures of the gap diagnosis (PNG and SVG): heat map, phase bars, curves before/after."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from smcbayes.diagnose.fit import DiagnosisContext, Fit
from smcbayes.diagnose.where import WhereReport
from smcbayes.forward.result import PHASE_NAMES
from smcbayes.plotting import MEASURED, grid_shape, save, subplots

COLOURS = ("tab:blue", "tab:red", "tab:green")


def heat_map(rep: WhereReport, path: Path) -> list[Path]:
    """Residual (measured - simulated, kN) per configuration x normalised closing time."""
    fig, ax = subplots(figsize=(8.0, 0.45 * len(rep.ids) + 1.8))
    lim = float(np.nanmax(np.abs(rep.heat_kN))) or 1.0
    im = ax.imshow(rep.heat_kN, aspect="auto", cmap="RdBu_r", vmin=-lim, vmax=lim,
                   extent=(0.0, 1.0, len(rep.ids) - 0.5, -0.5), interpolation="nearest")
    ax.set_yticks(range(len(rep.ids)), rep.ids)
    ax.set_xlabel("normalised closing time (-), 0 = contact, 1 = force limit")
    ax.set_title("force residual of the calibrated model")
    fig.colorbar(im, ax=ax, label="measured - simulated force (kN)")
    return save(fig, path)


def phase_bars(shrink: dict[str, Any], path: Path) -> list[Path]:
    """RMSE per phase and configuration (kN), one bar group per model."""
    models = shrink["models"]
    ids = shrink["sets"]["fit"] + shrink["sets"]["holdout"]
    size = (4.0 * len(PHASE_NAMES), 0.35 * len(ids) + 2.0)
    fig, axes = subplots(1, len(PHASE_NAMES), figsize=size, sharey=True)
    y = np.arange(len(ids))
    h = 0.8 / max(len(models), 1)
    for a, (ax, phase) in enumerate(zip(axes, PHASE_NAMES, strict=True)):
        for i, (label, entry) in enumerate(models.items()):
            table = {**entry["fit"]["per_config"], **entry["holdout"]["per_config"]}
            vals = [table[c]["phase_rmse_kN"][phase] or 0.0 for c in ids]
            ax.barh(y + (i - (len(models) - 1) / 2) * h, vals, h, color=COLOURS[i % 3],
                    label=label if a == 0 else None)
        ax.set_title(f"{phase}")
        ax.set_xlabel("force RMSE (kN)")
    held = set(shrink["sets"]["holdout"])
    axes[0].set_yticks(y, [f"{c} (held out)" if c in held else c for c in ids])
    axes[0].invert_yaxis()
    axes[0].legend(loc="lower right", fontsize=8)
    fig.suptitle("force error per phase, before and after", y=1.06)
    return save(fig, path)


def before_after(ctx: DiagnosisContext, fits: dict[str, Fit], ids: Sequence[str],
                 holdout: Sequence[str], path: Path) -> list[Path]:
    """Measured force (black) and each model's simulated force vs time per configuration."""
    rows, cols = grid_shape(len(ids))
    fig, axes = subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    sims = {label: ctx.simulate(fit.effects, fit.theta, ids) for label, fit in fits.items()}
    for k, cid in enumerate(ids):
        ax = axes[k // cols][k % cols]
        m = ctx.dataset[cid].force
        ax.plot(m.time_s, m.values, color=MEASURED, lw=1.5, label="measured")
        for i, (label, res) in enumerate(sims.items()):
            r = res[cid]
            ts = r.switch_time_s[0] if np.isfinite(r.switch_time_s[0]) else r.time_s[0, -1]
            keep = r.time_s[0] <= ts
            ax.plot(r.time_s[0, keep], r.force_kN[0, keep], color=COLOURS[i % 3], lw=1.1,
                    label=label)
        ax.set_title(cid + (" (held out)" if cid in holdout else ""), fontsize=9)
        ax.set_xlabel("time from contact (s)")
        ax.set_ylabel("force (kN)")
    for k in range(len(ids), rows * cols):
        axes[k // cols][k % cols].axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle("closing force before and after adding the effect")
    fig.tight_layout()
    return save(fig, path)
