"""Shared fixtures: repository paths and a small one-configuration project factory."""

from __future__ import annotations

import copy
import logging
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

# One BLAS thread in each pytest-xdist worker (one per core), set before numpy loads its
# BLAS and inherited by the processes the tests start: two workers each running two BLAS
# threads on two cores contend, and the suite takes a fifth longer.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_threads, "1")

from smcbayes import progress
from smcbayes.config import ProjectConfig, build_project

REPO = Path(__file__).resolve().parents[1]

# One thesis-like trial: 60 % full-width bar, 388 g, 8 mm stack, 0.3 mm/s, 1400 kN.
BAR_PROJECT: dict[str, Any] = {
    "name": "test-bar",
    "configuration": [{
        "id": "bar",
        "mould": {"length_mm": 305.0, "width_mm": 305.0, "temperature_C": 135.0},
        "charge": {"shape": "bar", "coverage_pct": 60.0, "mass_g": 388.0, "stack_height_mm": 8.0},
        "press": {"speed_mm_s": 0.3, "force_limit_kN": 1400.0, "hold_s": 500.0},
    }],
}


@pytest.fixture
def repo_root() -> Path:
    """The repository root."""
    return REPO


@pytest.fixture
def thesis_config() -> Path:
    """Path of ``configs/thesis.toml``."""
    return REPO / "configs" / "thesis.toml"


@pytest.fixture
def thesis_data() -> Path:
    """The measured thesis press data; skips the test when the folder is absent."""
    path = (REPO / ".." / "shared" / "data" / "thesis-press").resolve()
    if not path.is_dir():
        pytest.skip(f"measured data not found at {path}")
    return path


@pytest.fixture
def make_project() -> Callable[..., ProjectConfig]:
    """Factory: the one-bar project with top-level keys and per-trial tables overridden.

    ``make_project(solver={...}, charge={...}, press={...}, effects=[...])``: ``charge``,
    ``press`` and ``mould`` update the trial's tables, everything else the top level.
    """

    def build(**over: Any) -> ProjectConfig:
        raw = copy.deepcopy(BAR_PROJECT)
        trial = raw["configuration"][0]
        for key in ("mould", "charge", "press"):
            trial[key].update(over.pop(key, {}))
        raw.update(over)
        return build_project(raw, "<test project>", REPO)

    return build


_LOGGER = logging.getLogger("smcbayes")
_PRISTINE = (list(_LOGGER.handlers), _LOGGER.level, _LOGGER.propagate, warnings.showwarning)


def _reset_application_output() -> None:
    handlers, level, propagate, show = _PRISTINE
    for h in _LOGGER.handlers[:]:
        if h not in handlers:
            _LOGGER.removeHandler(h)
    _LOGGER.setLevel(level)
    _LOGGER.propagate = propagate
    warnings.showwarning = show
    progress.enable(False)


@pytest.fixture(autouse=True)
def _application_output_reset() -> Any:
    """Undo what the command line sets up for an application (log handler, progress,
    warning display), before and after each test, so that a test (or a module fixture)
    calling ``main`` does not change the next test."""
    _reset_application_output()
    yield
    _reset_application_output()
