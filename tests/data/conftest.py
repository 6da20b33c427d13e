"""Shared builders for the data tests (fixture ``dh``): projects in tmp_path, hand-made simulations."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from smcbayes.config import ProjectConfig, build_project
from smcbayes.forward.result import SimulationResult

REPO = Path(__file__).resolve().parents[2]
REAL_DATA = REPO / ".." / "shared" / "data" / "thesis-press"
THESIS_TOML = REPO / "configs" / "thesis.toml"


def project(tmp_path: Path, configs: list[dict[str, Any]], **top: Any) -> ProjectConfig:
    """A project with the given configurations, data_dir = tmp_path."""
    raw: dict[str, Any] = {"data_dir": str(tmp_path), "configuration": configs}
    raw.update(top)
    return build_project(raw, "test.toml", tmp_path)


def config(cid: str = "c1", data: dict[str, Any] | None = None, role: str = "train",
           coverage_pct: float = 50.0, speed_mm_s: float = 4.0,
           force_limit_kN: float = 300.0) -> dict[str, Any]:
    """One configuration table (8 mm stack)."""
    out: dict[str, Any] = {
        "id": cid, "role": role,
        "charge": {"shape": "bar", "coverage_pct": coverage_pct, "stack_height_mm": 8.0},
        "press": {"speed_mm_s": speed_mm_s, "force_limit_kN": force_limit_kN},
    }
    if data is not None:
        out["data"] = data
    return out


def sim_result(cid: str, time_s: np.ndarray, force_kN: np.ndarray, switch_s: np.ndarray,
               displacement_mm: np.ndarray | None = None, phase: np.ndarray | None = None,
               status: list[str] | None = None) -> SimulationResult:
    """A SimulationResult from (P, T) arrays (other curves filled with zeros)."""
    t = np.atleast_2d(np.asarray(time_s, float))
    f = np.broadcast_to(np.atleast_2d(np.asarray(force_kN, float)), t.shape).copy()
    d = np.zeros_like(t) if displacement_mm is None else np.broadcast_to(
        np.atleast_2d(np.asarray(displacement_mm, float)), t.shape).copy()
    ph = (np.where(t <= np.atleast_1d(switch_s)[:, None], 1, 3) if phase is None
          else np.broadcast_to(np.atleast_2d(phase), t.shape)).astype(np.int8)
    P = t.shape[0]
    return SimulationResult(cid, t, 8.0 - d, d, f, np.ones_like(t), np.ones_like(t), ph,
                            np.atleast_1d(np.asarray(switch_s, float)), status or ["ok"] * P)


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` (UTF-8) creating parent folders."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture
def dh() -> SimpleNamespace:
    """The builders of this module."""
    return SimpleNamespace(project=project, config=config, sim_result=sim_result,
                           write_text=write_text, REAL_DATA=REAL_DATA, THESIS_TOML=THESIS_TOML,
                           REPO=REPO)
