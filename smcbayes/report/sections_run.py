"""Report sections of the data, the calibration and the reproducibility block."""

from __future__ import annotations

import datetime as dt
import shlex
from pathlib import Path
from typing import Any

from smcbayes import __version__
from smcbayes.errors import ParameterOnBoundWarning
from smcbayes.report.collect import RunFiles, data_dir_of, sha256
from smcbayes.report.document import Block, Bullets, Code, Figure, Heading, Paragraph, Section, Table, fmt


def _config_rows(project: dict[str, Any], with_data: set[str]) -> tuple[tuple[str, ...], ...]:
    rows = []
    for c in project.get("configuration", []):
        charge, press = c.get("charge") or {}, c.get("press") or {}
        rows.append(
            (
                str(c.get("id")),
                str(c.get("role", "train")),
                str(charge.get("shape", "-")),
                fmt(charge.get("coverage_pct")),
                fmt(press.get("speed_mm_s")),
                fmt(charge.get("mass_g")),
                "yes" if c.get("id") in with_data else "no",
            )
        )
    return tuple(rows)


def _truth_blocks(truth: dict[str, Any]) -> list[Block]:
    effects = truth.get("effects") or []
    noise = truth.get("noise") or {}
    on = ", ".join(effects) if effects else "no effect"
    text = (
        f"These curves are synthetic: the forward model was run at known parameter values "
        f"with {on} switched on, and noise was added (white {fmt(noise.get('white_kN'))} kN, "
        f"correlated {fmt(noise.get('correlated_kN'))} kN over "
        f"{fmt(noise.get('correlation_s'))} s; "
        f"seed {truth.get('seed', '-')}). The calibrated model below knows only the effects "
        "listed in the calibration settings, so any effect on here and off there is the "
        "gap the diagnosis should find."
    )
    params = truth.get("parameters") or {}
    rows = tuple((k, fmt(v)) for k, v in params.items())
    return [
        Paragraph(text),
        Table(
            ("parameter", "true value (unit in the name)"),
            rows,
            caption="parameter values of the synthetic truth",
            numeric=(1,),
        ),
    ]


def data_section(run: RunFiles, dataset: Any, measured_png: Path | None) -> Section:
    """Configurations table, synthetic-truth note and measured curves."""
    project = run.config.get("project") or {}
    configs = project.get("configuration", [])
    with_data = set(dataset.measurements) if dataset is not None else set()
    roles = [c.get("role", "train") for c in configs]
    sec = Section("data", "Data")
    sec.add(
        Paragraph(
            f"Project '{project.get('name', '-')}': {len(configs)} configuration(s), "
            f"{roles.count('train')} for training, {roles.count('validation')} for "
            f"validation; measured curves from {data_dir_of(run.config) or 'no data folder'}."
        )
    )
    sec.add(
        Table(
            (
                "configuration",
                "role",
                "charge",
                "coverage (%)",
                "speed (mm/s)",
                "mass (g)",
                "measured data",
            ),
            _config_rows(project, with_data),
            caption="press configurations",
            numeric=(3, 4, 5),
        )
    )
    if run.truth is not None:
        sec.add(*_truth_blocks(run.truth))
    if measured_png is not None:
        sec.add(
            Figure(measured_png, "Measured closing force from first contact to the force limit.")
        )
    elif dataset is None:
        sec.add(
            Paragraph(
                "The measured curves could not be read from the data folder recorded in "
                "the run, so they are not drawn here."
            )
        )
    return sec


def _polish_row(polish: dict[str, Any] | None) -> list[tuple[str, str]]:
    """The calibration's local search as one table row (none without a search)."""
    if not polish:
        return []
    how = "converged" if polish.get("converged") else "its budget spent"
    return [("local search (forward model)",
             f"{fmt(polish.get('evaluations'))} evaluations ({how}), "
             f"loss {fmt(polish.get('start_loss_kN2'))} "
             f"-> {fmt(polish.get('best_loss_kN2'))} kN^2")]


def _settings_table(cal: dict[str, Any]) -> Table:
    s = cal.get("settings") or {}
    fixed = cal.get("fixed_parameters") or {}
    rows = [
        ("free parameters", ", ".join(cal.get("free_parameters") or []) or "-"),
        ("fixed parameters", ", ".join(f"{k} = {fmt(v)}" for k, v in fixed.items()) or "none"),
        ("effects in the model", ", ".join(cal.get("effects") or []) or "none (base model)"),
        ("training configurations", ", ".join(cal.get("config_ids") or []) or "-"),
        (
            "budget / initial design / batch",
            f"{fmt(s.get('budget'))} / {fmt(s.get('init'))} / {fmt(s.get('batch'))}",
        ),
        ("kernel, seed", f"{s.get('kernel', '-')}, {fmt(s.get('seed'))}"),
        ("evaluations (failed)", f"{fmt(cal.get('evaluations'))} ({fmt(cal.get('failures'))})"),
        ("stop reason", str(cal.get("stop_reason", "-"))),
        *_polish_row(cal.get("polish")),
        ("wall time (s)", fmt(cal.get("seconds_wall"), 3)),
    ]
    loss = cal.get("loss") or {}
    if loss:
        rows.append(
            (
                "loss weights (force, displacement), clip",
                f"{fmt(loss.get('w_force'))}, {fmt(loss.get('w_displacement'))}, "
                f"{loss.get('clip', '-')}",
            )
        )
    return Table(("setting", "value"), tuple(rows), caption="calibration settings")


def _best_table(cal: dict[str, Any], truth: dict[str, Any] | None) -> Table:
    true = (truth or {}).get("parameters") or cal.get("truth") or {}
    rows = []
    for name, v in (cal.get("best_params") or {}).items():
        rows.append(
            (
                name,
                fmt(v.get("value")),
                str(v.get("unit", "-")),
                "fixed" if v.get("fixed") else "calibrated",
                fmt(true.get(name)),
            )
        )
    return Table(
        ("parameter", "best value", "unit", "status", "true value"),
        tuple(rows),
        caption=f"best point (evaluation {fmt(cal.get('best_index'))}, loss "
        f"{fmt(cal.get('best_loss_kN2'))} kN²)",
        numeric=(1, 4),
    )


def bound_advice(cal: dict[str, Any]) -> list[str]:
    """One sentence per calibrated parameter on a search bound (``on_bounds`` of the
    calibration summary): which way the data push it and what to do; then one per trial
    whose end state puts its contact beyond the loss's bound (``contact_on_bound``)."""
    out = []
    for b in cal.get("on_bounds") or []:
        text = b.get("advice") or ParameterOnBoundWarning.advice(
            str(b.get("name")), str(b.get("bound")), float(b.get("limit", float("nan"))),
            float(b.get("value", float("nan"))), b.get("physical_limit"))
        out.append(text)
    out.extend(str(c.get("advice")) for c in cal.get("contact_on_bound") or [] if c.get("advice"))
    return out


def _error_table(cal: dict[str, Any], validation: dict[str, dict[str, float]]) -> Table:
    loss = cal.get("loss") or {}
    force_only = loss.get("w_force", 1.0) == 1.0 and not loss.get("w_displacement", 0.0)
    rows = []
    for cid, e in (cal.get("best_errors_kN2") or {}).items():
        rmse = fmt(e**0.5, 3) if force_only and isinstance(e, (int, float)) and e >= 0 else "-"
        rows.append((cid, "train", fmt(e), rmse))
    for cid, e in validation.items():
        rows.append((cid, "validation (not fitted)", fmt(e["mse_kN2"]), fmt(e["rmse_kN"], 3)))
    caption = "errors of the best point per configuration"
    if validation and cal.get("contact_offsets_mm"):
        caption += ("; a validation trial's from its curves averaged over the training trials' "
                    "contact offsets (its own is not known)")
    return Table(
        ("configuration", "role", "error e_k (kN²)", "force RMSE (kN)"),
        tuple(rows),
        caption=caption,
        numeric=(2, 3),
    )


def calibration_section(run: RunFiles, validation: dict[str, dict[str, float]]) -> Section:
    """Settings, convergence, best parameters with units, curves, per-configuration errors."""
    cal = run.calibration
    sec = Section("calibration", "Calibration")
    sec.add(
        Paragraph(
            "Bayesian optimisation of the free parameters on the training configurations: "
            "a Latin hypercube design, then a Gaussian process on log(loss) proposing "
            "new points by expected improvement"
            + ("; then a local search (Powell's method) on the forward model from the best point."
               if cal.get("polish") else ".")
        )
    )
    sec.add(_settings_table(cal))
    if (fig := run.figure("figures", "convergence")) is not None:
        sec.add(
            Figure(
                fig,
                "Loss per evaluation and best so far (log scale, kN²); the shaded "
                "part is the initial design"
                + ("; small green points are the local search's." if cal.get("polish") else "."),
            )
        )
    if cal.get("best_params"):
        sec.add(_best_table(cal, run.truth))
        for text in bound_advice(cal):
            sec.add(Paragraph(text, tone="warning"))
    else:
        sec.add(Paragraph("No evaluation succeeded, so there is no best point.", tone="warning"))
    if (fig := run.figure("figures", "best_curves")) is not None:
        sec.add(
            Figure(
                fig,
                "Simulated force (colour) at the best point against the measured force "
                "(black), per configuration; dashed: simulated ram displacement.  Where each "
                "trial has a contact of its own, a validation trial's force is the mean of "
                "its curves at the training trials' contacts.",
            )
        )
    if cal.get("best_errors_kN2"):
        sec.add(_error_table(cal, validation))
    if (fig := run.figure("figures", "landscape")) is not None:
        sec.add(
            Figure(fig, "Gaussian-process landscape of log(loss) over the two free parameters.")
        )
    return sec


def _quoted(argv: list[str]) -> str:
    return " ".join(shlex.quote(str(a)) for a in argv)


def _commands(run: RunFiles) -> tuple[str, str]:
    """The command lines that made the run, as recorded by each stage (with the folder they
    ran in, since their paths are relative to it), else those recorded by the demo."""
    recorded = run.commands
    if recorded:
        lines, cwd = [], None
        for rec in recorded:
            if rec.get("cwd") and rec["cwd"] != cwd:
                cwd = rec["cwd"]
                lines.append(f"cd {shlex.quote(cwd)}")
            lines.append(_quoted(rec["argv"]))
        return "\n".join(lines), "as recorded by each stage"
    if run.demo and run.demo.get("commands"):
        return "\n".join(run.demo["commands"]), "as recorded by `smcbayes demo`"
    return "(no command line recorded: the run was made from the Python API)", "none recorded"


def reproducibility_section(run: RunFiles) -> Section:
    """Package version, config hash, seeds, command lines, dates."""
    cfg = run.run_dir / "config.json"
    started = dt.datetime.fromtimestamp(cfg.stat().st_mtime, dt.UTC)
    seeds = [
        ("calibration", (run.calibration.get("settings") or {}).get("seed", run.config.get("seed")))
    ]
    if run.posterior:
        seeds.append(("posterior", (run.posterior.get("settings") or {}).get("seed")))
    if run.diagnosis:
        seeds.append(("diagnosis", run.diagnosis.get("seed")))
    if run.truth:
        seeds.append(("synthetic data", run.truth.get("seed")))
    rows = (
        ("smcbayes version", __version__),
        ("config hash (SHA-256 of config.json)", sha256(cfg)),
        ("run started (UTC)", started.strftime("%Y-%m-%d %H:%M:%S")),
        ("report written (UTC)", dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M:%S")),
        ("seeds", ", ".join(f"{k} {fmt(v)}" for k, v in seeds)),
        ("run directory", str(run.run_dir.resolve())),
    )
    text, origin = _commands(run)
    sec = Section("reproducibility", "Reproducibility")
    sec.add(Table(("item", "value"), rows, caption="what this report was made from"))
    sec.add(Heading(f"Command lines ({origin})"), Code(text))
    if run.demo and run.demo.get("timings_s"):
        sec.add(
            Heading("Stage times of the demo"),
            Bullets(tuple(f"{k}: {v:.1f} s" for k, v in run.demo["timings_s"].items())),
        )
    return sec
