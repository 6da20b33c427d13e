"""Small synthetic diagnosis cases: three thesis bar configurations, a coarse solver."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from smcbayes.config import ProjectConfig, load_project
from smcbayes.data.dataset import load_dataset
from smcbayes.data.synth import NoiseSpec
from smcbayes.diagnose.fit import DiagnosisContext, FitSettings
from smcbayes.diagnose.synthetic import BASE_TRUTH, make_case

REPO = Path(__file__).resolve().parents[2]
IDS = ["60-bar-03", "60-bar-07", "60-bar-11"]
NOISE = NoiseSpec(white_kN=2.0, correlated_kN=3.0, correlation_s=0.5)
#: A budget small enough for tests; the benchmark uses the defaults.
TINY = FitSettings(population=10, generations=3, lhs_starts=4, global_starts=2, restarts=1,
                   polish=3)


def coarse(project: ProjectConfig, contact_offset_mm: float = 0.0) -> ProjectConfig:
    """The project with a coarse solver and loss grid (fast, still resolving the closing)
    and a loss at the nominal contact unless ``contact_offset_mm`` says otherwise (the
    synthetic charges have no contact scatter)."""
    solver = project.solver.model_copy(update={"closing_steps": 80, "hold_steps": 10,
                                               "output_closing_points": 80, "output_hold_points": 10})
    loss = project.loss.model_copy(update={"grid_points": 150, "contact_offset_mm": contact_offset_mm,
                                           "contact": None})
    return project.model_copy(update={"solver": solver, "loss": loss})


@pytest.fixture(scope="session")
def synthetic_ctx(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str | None], DiagnosisContext]:
    """Factory: diagnosis context of synthetic data with ``effect`` on (None: none).

    The calibrated base point is the true base parameters: the diagnosis re-fits the base
    model itself, so a full calibration would only cost time here.
    """
    cache: dict[str | None, DiagnosisContext] = {}
    source = coarse(load_project(REPO / "configs" / "thesis.toml"))

    def make(effect: str | None) -> DiagnosisContext:
        if effect not in cache:
            folder = tmp_path_factory.mktemp(f"synth-{effect or 'none'}")
            project = coarse(make_case(source, IDS, effect, NOISE, 7, folder))
            dataset = load_dataset(project, ids=IDS, preprocess=project.preprocess)
            cache[effect] = DiagnosisContext(project, dataset, list(IDS), (), {}, None, dict(BASE_TRUTH))
        return cache[effect]

    return make
