"""Measured data of a run and the search box of its calibration, read, never simulated.

The measured curves need the project's data folder; without it they are skipped
(``None``), never fatal.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from smcbayes.config import ProjectConfig
from smcbayes.data.dataset import load_dataset
from smcbayes.errors import SmcBayesError
from smcbayes.plotting import MEASURED, grid_shape, save, subplots


def project_of(config: Mapping[str, Any]) -> ProjectConfig | None:
    """The run's validated project, or ``None`` if ``config.json`` does not hold one."""
    try:
        return ProjectConfig.model_validate(config["project"])
    except (KeyError, ValueError):
        return None


def search_ranges(calibration: Mapping[str, Any]) -> dict[str, tuple[float, float, bool]]:
    """Search bounds ``(lower, upper, log)`` of the run's free parameters (user units), as
    recorded by the calibration."""
    box = calibration.get("search_box") or {}
    return {k: (float(v["lower"]), float(v["upper"]), bool(v["log"])) for k, v in box.items()}


def load_measured(project: ProjectConfig) -> Any:
    """The project's dataset (all configurations with data), or ``None`` if unreadable."""
    root = project.data_path()
    if root is None or not root.is_dir():
        return None
    try:
        return load_dataset(project)
    except SmcBayesError:
        return None


def plot_measured(dataset: Any, path: Path) -> list[Path] | None:
    """Measured closing force (black) vs time, one panel per configuration named in its title.

    Args:
        dataset: :class:`smcbayes.data.dataset.Dataset`.
        path: output path without suffix (PNG and SVG are written).
    """
    ids = [cid for cid, m in dataset.measurements.items() if m.force is not None]
    if not ids:
        return None
    nrows, ncols = grid_shape(len(ids), cols=4)
    fig, axes = subplots(
        nrows, ncols, figsize=(3.4 * ncols, 2.6 * nrows), squeeze=False, sharey=True
    )
    for k, cid in enumerate(ids):
        ax = axes[k // ncols][k % ncols]
        m = dataset.measurements[cid]
        ax.plot(m.force.time_s, m.force.values, color=MEASURED, lw=1.1, label=f"{cid} measured")
        ax.set_title(f"{cid} ({m.role})", fontsize=9)
        ax.set_xlabel("time from contact (s)")
        ax.set_ylabel("force (kN)")
        ax.legend(fontsize=7, loc="upper left")
    for k in range(len(ids), nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    fig.suptitle("measured closing force per configuration", fontsize=10)
    fig.tight_layout()
    return save(fig, path)
