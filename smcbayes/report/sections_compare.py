"""Report section comparing a run with the run it follows: before and after an effect.

A run whose ``demo.json`` names an earlier run (``compare_with``, a path relative to the
run directory) gets a "Before and after" section: the fit (loss and force RMSE per
configuration, best curves), the width of the posterior (90 % intervals against the
search range) with a check against the known truth, and the predictive bands (coverage
and mean width).  Both runs are read, never simulated; a missing file leaves a cell '-'.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

from smcbayes.errors import ConfigError
from smcbayes.plotting import MEASURED, grid_shape, save, subplots
from smcbayes.report.collect import RunFiles, load_run_files
from smcbayes.report.document import Block, Figure, Heading, Paragraph, Section, Table, fmt, pct
from smcbayes.report.measured import load_measured, project_of, search_ranges
from smcbayes.report.sections_diagnosis import truth_check
from smcbayes.report.sections_stages import PRIOR_SHARE, interval_share

"""Band widths measured by ``smcbayes demo`` in a run directory (read if present)."""
COLOURS = {"before": "tab:orange", "after": "tab:blue"}


def _num(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else float("nan")


def _effects(run: RunFiles) -> str:
    return ", ".join(run.calibration.get("effects") or []) or "no effect"


def _rmse_by_config(cal: dict[str, Any]) -> dict[str, tuple[str, float]]:
    """Force RMSE (kN) of the best point per configuration: ``{id: (role, rmse)}``.

    Training errors are mean squared force errors only with a force-only loss; otherwise
    their RMSE is left out (NaN).
    """
    loss = cal.get("loss") or {}
    force_only = loss.get("w_force", 1.0) == 1.0 and not loss.get("w_displacement", 0.0)
    out: dict[str, tuple[str, float]] = {}
    for cid, e in (cal.get("best_errors_kN2") or {}).items():
        e = _num(e)
        out[cid] = ("train", math.sqrt(e) if force_only and e >= 0 else float("nan"))
    for cid, e in (cal.get("validation_errors") or {}).items():
        out[cid] = ("validation", _num((e or {}).get("rmse_kN")))
    return out


def _fit_blocks(before: RunFiles, after: RunFiles) -> list[Block]:
    rb, ra = _rmse_by_config(before.calibration), _rmse_by_config(after.calibration)
    rows = []
    for cid in dict.fromkeys([*rb, *ra]):
        role = (ra.get(cid) or rb.get(cid) or ("-",))[0]
        b, a = rb.get(cid, ("", float("nan")))[1], ra.get(cid, ("", float("nan")))[1]
        rows.append((cid, role, fmt(b, 3), fmt(a, 3), fmt(b / a if a > 0 else float("nan"), 3)))
    lb, la = _num(before.calibration.get("best_loss_kN2")), _num(after.calibration.get("best_loss_kN2"))
    factor = lb / la if la > 0 else float("nan")
    text = (f"Training loss at the best point: {fmt(lb)} kN² before, {fmt(la)} kN² after, "
            f"{fmt(factor, 3)} times lower.")
    noise = (after.truth or {}).get("noise") or {}
    white, corr = _num(noise.get("white_kN")), _num(noise.get("correlated_kN"))
    if white == white and corr == corr:
        level = math.hypot(white, corr)
        worst = max((v[1] for v in ra.values() if v[0] == "train" and v[1] == v[1]), default=float("nan"))
        near = worst == worst and worst <= 3.0 * level
        text += (f" The noise added to the synthetic curves alone gives a force RMSE of about "
                 f"{fmt(level, 2)} kN; the largest training RMSE after is {fmt(worst, 3)} kN"
                 + (", near the noise level: the model with the effect fits the data the loss compares."
                    if near else ", well above the noise level: the fit is not complete."))
    if (after.calibration.get("loss") or {}).get("clip") == "flow_stop":
        text += (" Both losses compare the force up to the incompressible flow stop (the "
                 "project's clipped loss), so the final rise to the force limit is not fitted; "
                 "the figure shows the whole closing.")
    return [
        Heading("Fit"),
        Paragraph(text),
        Table(("configuration", "role", "force RMSE before (kN)", "force RMSE after (kN)",
               "before / after"), tuple(rows),
              caption=f"errors of the best point: before ({_effects(before)}) and after "
                      f"({_effects(after)})", numeric=(2, 3, 4)),
    ]


def _read_curve(path: Path) -> tuple[list[float], list[float]] | None:
    """``(time_s, force_kN)`` of a best-curve CSV, or ``None``."""
    try:
        with path.open(encoding="utf-8", newline="") as fh:
            rows = list(csv.DictReader(fh))
        return [float(r["time_s"]) for r in rows], [float(r["force_kN"]) for r in rows]
    except (OSError, KeyError, ValueError):
        return None


def _limit_time(time_s: list[float], force_kN: list[float]) -> float:
    """Time (s) at which a curve first reaches 99 % of its largest force."""
    top = 0.99 * max(force_kN)
    return next(t for t, f in zip(time_s, force_kN, strict=True) if f >= top)


def plot_fit(before: RunFiles, after: RunFiles, path: Path) -> Path | None:
    """Measured force (black) and the best simulated force before and after (colour) per
    configuration, from the runs' ``best_curves/*.csv``; returns the PNG or ``None``.

    Args:
        before, after: the two runs.
        path: output path without suffix (PNG and SVG are written).
    """
    ids = sorted({p.stem for p in (after.run_dir / "best_curves").glob("*.csv")})
    if not ids:
        return None
    project = project_of(after.config)
    dataset = load_measured(project) if project is not None else None
    nrows, ncols = grid_shape(len(ids), cols=4)
    fig, axes = subplots(nrows, ncols, figsize=(3.4 * ncols, 2.6 * nrows), squeeze=False,
                         sharey=True)
    for k, cid in enumerate(ids):
        ax = axes[k // ncols][k % ncols]
        m = dataset.measurements.get(cid) if dataset is not None else None
        ends: list[float] = []  # the closing only: the hold at the force limit says nothing
        if m is not None and m.force is not None:
            ax.plot(m.force.time_s, m.force.values, color=MEASURED, lw=1.1, label="measured")
            ends.append(float(m.force.time_s[-1]))
        for key, run in (("before", before), ("after", after)):
            curve = _read_curve(run.run_dir / "best_curves" / f"{cid}.csv")
            if curve is not None:
                ax.plot(*curve, color=COLOURS[key], lw=1.0, ls="--" if key == "before" else "-",
                        label=f"simulated {key} ({_effects(run)})")
                ends.append(_limit_time(*curve))
        if ends:
            ax.set_xlim(0.0, 1.15 * max(ends))
        ax.set_title(cid, fontsize=9)
        ax.set_xlabel("time from contact (s)")
        ax.set_ylabel("force (kN)")
        if k == 0:
            ax.legend(fontsize=6, loc="upper left")
    for k in range(len(ids), nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    fig.suptitle("best simulated force before and after, measured force in black", fontsize=10)
    fig.tight_layout()
    return save(fig, path)[0]


def _interval(p: dict[str, Any] | None) -> str:
    if not p:
        return "-"
    return f"{fmt(p.get('q05'), 3)} - {fmt(p.get('q95'), 3)}"


def _inside(p: dict[str, Any] | None, true: Any) -> bool | None:
    t = _num(true)
    if not p or t != t:
        return None
    lo, hi = _num(p.get("q05")), _num(p.get("q95"))
    return None if lo != lo or hi != hi else lo <= t <= hi


def _width_blocks(before: RunFiles, after: RunFiles) -> list[Block]:
    pb = {str(p.get("name")): p for p in (before.posterior or {}).get("parameters") or []}
    pa = {str(p.get("name")): p for p in (after.posterior or {}).get("parameters") or []}
    rb, ra = search_ranges(before.calibration), search_ranges(after.calibration)
    truth = (after.truth or {}).get("parameters") or {}
    rows, inside, outside = [], [], []
    for name in dict.fromkeys([*pb, *pa]):
        lo, hi, _ = ra.get(name) or rb.get(name) or (float("nan"), float("nan"), False)
        hit = _inside(pa.get(name), truth.get(name))
        if hit is True:
            inside.append(name)
        elif hit is False:
            outside.append(name)
        rows.append((
            name, f"{fmt(lo, 3)} - {fmt(hi, 3)}",
            _interval(pb.get(name)) if name in pb else "not in the model",
            pct(interval_share(pb[name], rb)) if name in pb else "-",
            _interval(pa.get(name)), pct(interval_share(pa[name], ra)) if name in pa else "-",
            fmt(truth.get(name)), {True: "yes", False: "no", None: "-"}[hit],
        ))
    blocks: list[Block] = [
        Heading("Posterior width"),
        Table(("parameter", "search range", "90 % interval before", "share of range before",
               "90 % interval after", "share of range after", "true value",
               "truth inside 90 % interval after"), tuple(rows),
              caption="posterior 90 % intervals against the search range (log10 widths for "
                      "log-scaled parameters)", numeric=(3, 5, 6)),
    ]
    shares_b = [interval_share(p, rb) for p in pb.values()]
    shares_a = [interval_share(p, ra) for p in pa.values()]
    words = []
    if shares_b and all(s == s and s > PRIOR_SHARE for s in shares_b):
        words.append(f"Before, the posterior is essentially the prior (every 90 % interval spans "
                     f"more than {pct(PRIOR_SHARE)} of its search range).")
    if shares_a and any(s == s for s in shares_a):
        words.append(f"After, the 90 % intervals span {pct(min(shares_a))} to "
                     f"{pct(max(shares_a))} of the search ranges.")
    if words:
        blocks.append(Paragraph(" ".join(words)))
    if inside or outside:
        total = len(inside) + len(outside)
        text = (f"Check against the known truth: the true value lies inside the 90 % interval "
                f"after for {len(inside)} of {total} parameters")
        text += (f" ({', '.join(inside)})." if not outside else
                 f"; outside it for {', '.join(outside)}"
                 + (f" (inside for {', '.join(inside)})." if inside else "."))
        blocks.append(Paragraph(text, tone="warning" if outside else "normal"))
    return blocks


def _band_blocks(before: RunFiles, after: RunFiles) -> list[Block]:
    bb = (before.posterior or {}).get("bands") or {}
    ba = (after.posterior or {}).get("bands") or {}
    if not (bb or ba):
        return []
    wb, wa = bb, ba  # the posterior stage records coverage and width of each band
    rows = []
    for cid in dict.fromkeys([*bb, *ba]):
        rows.append((
            cid, pct((bb.get(cid) or {}).get("coverage90")), pct((ba.get(cid) or {}).get("coverage90")),
            fmt((wb.get(cid) or {}).get("width90_kN"), 3), fmt((wa.get(cid) or {}).get("width90_kN"), 3),
        ))

    def mean(rows_: dict[str, Any], key: str) -> float:
        vals = [_num((v or {}).get(key)) for v in rows_.values()]
        vals = [v for v in vals if v == v]
        return sum(vals) / len(vals) if vals else float("nan")

    text = (f"Mean over these configurations: coverage of the 90 % band {pct(mean(bb, 'coverage90'))} "
            f"before, {pct(mean(ba, 'coverage90'))} after (about 90 % for a calibrated model); "
            f"mean width of the 90 % band {fmt(mean(wb, 'width90_kN'), 3)} kN before, "
            f"{fmt(mean(wa, 'width90_kN'), 3)} kN after (averaged over the measured closing).")
    return [
        Heading("Predictive bands"),
        Paragraph(text),
        Table(("configuration", "inside 90 % band before", "inside 90 % band after",
               "mean 90 % width before (kN)", "mean 90 % width after (kN)"), tuple(rows),
              caption="predictive bands before and after", numeric=(1, 2, 3, 4)),
    ]


def before_after_section(run: RunFiles, figure_dir: Path) -> Section | None:
    """The comparison with the run named by ``demo.json``'s ``compare_with``, if any.

    Args:
        run: the run of the report (the "after" run).
        figure_dir: folder of the figures the report draws itself.
    """
    rel = (run.demo or {}).get("compare_with")
    if not rel:
        return None
    sec = Section("before-after", "Before and after")
    before_dir = run.run_dir / str(rel)
    try:
        before = load_run_files(before_dir)
    except ConfigError:
        sec.add(Paragraph(f"The run this one follows ({before_dir}) cannot be read, so there is "
                          "no comparison.", tone="warning"))
        return sec
    decision = (before.diagnosis or {}).get("decision") or {}
    intro = (f"Before: the base model ({_effects(before)}) calibrated on the same training "
             f"data (run {before_dir.resolve()}). After: this run, calibrated again with "
             f"{_effects(after := run)} on.")
    if decision.get("statement"):
        intro += f" The gap diagnosis of the run before said: {decision['statement']}."
    sec.add(Paragraph(intro))
    if (check := truth_check(before, decision.get("best"))) is not None:
        sec.add(check)
    sec.add(*_fit_blocks(before, after))
    if (png := plot_fit(before, after, figure_dir / "before_after_fit")) is not None:
        sec.add(Figure(png, "Measured force (black), best simulated force before (dashed) and "
                            "after (solid) per configuration."))
    if before.posterior is not None or after.posterior is not None:
        sec.add(*_width_blocks(before, after))
        sec.add(*_band_blocks(before, after))
    return sec
