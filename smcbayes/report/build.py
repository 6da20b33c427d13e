"""Assemble and write the report of a run directory (``report.html`` and ``report.md``)."""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from pathlib import Path

from smcbayes import __version__
from smcbayes.errors import ConfigError
from smcbayes.report.collect import RunFiles, load_run_files
from smcbayes.report.document import Paragraph, Section
from smcbayes.report.measured import (
    load_measured,
    plot_measured,
    project_of,
    search_ranges,
)
from smcbayes.report.render import to_html, to_markdown
from smcbayes.report.sections_compare import before_after_section
from smcbayes.report.sections_diagnosis import diagnosis_section
from smcbayes.report.sections_run import calibration_section, data_section, reproducibility_section
from smcbayes.report.sections_stages import bands_section, posterior_section

FORMATS = ("html", "md")
FIGURE_DIR = "report_figures"
"""Folder (inside the run directory) of the figures the report draws itself."""


def incomplete_section(run: RunFiles) -> Section | None:
    """Stages that started and never finished (a killed or failed process): said, not dropped."""
    broken = [k for k, v in run.states.items() if v == "interrupted"]
    if not broken:
        return None
    rerun = {"posterior": f"smcbayes posterior {run.run_dir}",
             "diagnosis": f"smcbayes diagnose {run.run_dir} --out {run.diagnosis_dir}"}
    sec = Section("incomplete", "Incomplete stages")
    sec.add(Paragraph("These stages started but did not finish (the process was stopped or "
                      "failed), so the report has no section for them; rerun them to complete "
                      "the report: " + "; ".join(f"{k}: `{rerun[k]}`" for k in broken) + "."))
    return sec


def build_sections(run: RunFiles) -> list[Section]:
    """Every section whose stage was run, in reading order."""
    project = project_of(run.config)
    dataset = load_measured(project) if project is not None else None
    measured_png = None
    if dataset is not None:
        paths = plot_measured(dataset, run.run_dir / FIGURE_DIR / "measured")
        measured_png = paths[0] if paths else None
    validation: dict[str, dict[str, float]] = run.calibration.get("validation_errors") or {}
    ranges = search_ranges(run.calibration)
    sections = [
        data_section(run, dataset, measured_png),
        before_after_section(run, run.run_dir / FIGURE_DIR),
        calibration_section(run, validation),
        posterior_section(run, ranges),
        bands_section(run),
        diagnosis_section(run),
    ]
    sections = [s for s in sections if s is not None]
    incomplete = incomplete_section(run)
    if incomplete is not None:
        sections.append(incomplete)
    sections.append(reproducibility_section(run))
    return sections


def write_report(
    run_dir: Path, formats: Sequence[str] = FORMATS, diagnosis_dir: Path | None = None
) -> list[Path]:
    """Write the report of ``run_dir`` in ``formats``; returns the written files.

    Args:
        run_dir: a calibration run directory (posterior and diagnosis optional).
        formats: any of ``"html"`` (self-contained) and ``"md"``.
        diagnosis_dir: folder of ``smcbayes diagnose --out`` (default ``run_dir/diagnose``).

    Raises:
        ConfigError: not a run directory, or an unknown format.
    """
    unknown = [f for f in formats if f not in FORMATS]
    if unknown:
        raise ConfigError(f"report format '{unknown[0]}' unknown; accepted: {', '.join(FORMATS)}")
    run = load_run_files(run_dir, diagnosis_dir)
    sections = build_sections(run)
    name = (run.config.get("project") or {}).get("name", "run")
    title = f"smcbayes report: {name}"
    now = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    stages = ", ".join(
        s.title.lower() for s in sections if s.key not in ("data", "reproducibility")
    )
    subtitle = (
        f"Run directory {run_dir.resolve()}; stages: {stages}; smcbayes {__version__}; "
        f"written {now}."
    )
    out = []
    if "html" in formats:
        path = run_dir / "report.html"
        path.write_text(to_html(title, subtitle, sections), encoding="utf-8")
        out.append(path)
    if "md" in formats:
        path = run_dir / "report.md"
        path.write_text(to_markdown(title, subtitle, sections, run_dir), encoding="utf-8")
        out.append(path)
    return out
