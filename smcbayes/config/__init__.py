"""Typed, validated configuration: the project file and the settings of every stage.

The bottom layer of the package with :mod:`smcbayes.errors`: it imports nothing else of
smcbayes, so every other layer can take its settings from here.
"""

from smcbayes.config.project import (
    ChargeSpec,
    ConfigurationSpec,
    DataSpec,
    MaterialSpec,
    MouldSpec,
    ParameterSpec,
    PartSpec,
    PieceSpec,
    PressSpec,
    ProjectConfig,
    SolverSpec,
    build_project,
    format_validation_error,
    load_project,
    parse_assignments,
)
from smcbayes.config.settings import (
    CalibrationSpec,
    CorrectionSpec,
    DiagnoseSpec,
    PosteriorSpec,
    Strict,
    choices_of,
    default_of,
    help_of,
    override,
)
from smcbayes.config.specs import ClipMode, LossSpec, PreprocessSpec

__all__ = [
    "CalibrationSpec", "ChargeSpec", "ClipMode", "ConfigurationSpec", "DataSpec", "LossSpec",
    "MaterialSpec", "MouldSpec", "ParameterSpec", "PartSpec", "PieceSpec", "PreprocessSpec", "PressSpec",
    "ProjectConfig", "SolverSpec", "Strict", "build_project", "format_validation_error",
    "load_project", "parse_assignments", "PosteriorSpec", "DiagnoseSpec", "CorrectionSpec", "choices_of",
    "default_of", "help_of", "override",
]
