"""What a run directory holds, read defensively: each stage's summary if it was run.

A stage that was not run (or whose summary cannot be read) is ``None``; the report then
omits its section.  Nothing here raises on a partial run except a directory that is not
a calibration run at all.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from smcbayes.errors import ConfigError
from smcbayes.run import RunDir, read_json


def sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass
class RunFiles:
    """The files of a run directory that the report reads.

    Attributes:
        run_dir: the calibration run directory.
        config: ``config.json`` (resolved project and calibration settings).
        calibration: ``summary.json`` of the calibration.
        posterior: ``posterior/summary.json`` or ``None``.
        diagnosis: the diagnosis ``summary.json`` or ``None``.
        diagnosis_dir: the folder of the diagnosis outputs.
        truth: ``truth.json`` of synthetic data (next to the project's data) or ``None``.
        demo: ``demo.json`` of the demo that made the run, or ``None``.
        states: state of each later stage (``absent``, ``interrupted``, ``complete``).
        commands: the recorded command lines of the run's stages.
    """

    run_dir: Path
    config: dict[str, Any]
    calibration: dict[str, Any]
    posterior: dict[str, Any] | None
    diagnosis: dict[str, Any] | None
    diagnosis_dir: Path
    truth: dict[str, Any] | None
    demo: dict[str, Any] | None
    states: dict[str, str] = field(default_factory=dict)
    commands: list[dict[str, Any]] = field(default_factory=list)

    def figure(self, *parts: str) -> Path | None:
        """``run_dir/parts...`` with a ``.png`` suffix if that file exists."""
        path = self.run_dir.joinpath(*parts).with_suffix(".png")
        return path if path.is_file() else None

    def diagnosis_figure(self, name: str) -> Path | None:
        """A diagnosis figure by name (``heatmap``, ``phase_rmse``, ``before_after``)."""
        path = (self.diagnosis_dir / "figures" / name).with_suffix(".png")
        return path if path.is_file() else None


def _dict_or_none(value: Any) -> dict[str, Any] | None:
    return value if isinstance(value, dict) else None


def data_dir_of(config: dict[str, Any]) -> Path | None:
    """The measured-data folder of the run's project (absolute), if it names one."""
    project = config.get("project") or {}
    data = project.get("data_dir")
    if not data:
        return None
    path = Path(data)
    return (path if path.is_absolute() else Path(project.get("base_dir", ".")) / path).resolve()


def load_run_files(run_dir: Path, diagnosis_dir: Path | None = None) -> RunFiles:
    """Read every stage's summary in ``run_dir``.

    Args:
        run_dir: calibration run directory.
        diagnosis_dir: folder of ``smcbayes diagnose --out`` (default ``run_dir/diagnose``).

    Raises:
        ConfigError: ``run_dir`` has no readable ``config.json`` and ``summary.json``.
    """
    run = RunDir(run_dir)
    config = _dict_or_none(read_json(run_dir / "config.json"))
    calibration = run.calibration_summary()
    if config is None or calibration is None:
        raise ConfigError(
            f"{run_dir}: not a calibration run directory (config.json and "
            "summary.json missing or unreadable); run `smcbayes calibrate` first"
        )
    diag_dir = diagnosis_dir if diagnosis_dir is not None else run.stage_dir("diagnose")
    states = {"posterior": run.stage_state("posterior"),
              "diagnosis": run.stage_state("diagnose", diag_dir)}
    posterior = run.stage_summary("posterior")
    diagnosis = run.stage_summary("diagnose", diag_dir)
    data_dir = data_dir_of(config)
    truth = _dict_or_none(read_json(data_dir / "truth.json")) if data_dir is not None else None
    demo = _dict_or_none(read_json(run_dir / "demo.json"))
    return RunFiles(run_dir, config, calibration, posterior, diagnosis, diag_dir, truth, demo,
                    states, run.commands())
