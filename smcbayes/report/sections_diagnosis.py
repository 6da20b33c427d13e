"""Report section of the sim-to-real gap diagnosis: where, which effect, how far it shrinks.

The diagnosis summary is read defensively: a missing key leaves a cell '-' or drops a
block, never the whole report.
"""

from __future__ import annotations

from typing import Any

from smcbayes.report.collect import RunFiles
from smcbayes.report.document import Block, Bullets, Figure, Heading, Paragraph, Section, Table, fmt, pct


def _ranking(rows: list[dict[str, Any]], named: str | None) -> Table:
    """The ranking table; ``named`` (the decision's effect) is marked in the last column,
    which need not be rank 1 when a near-tie went to the larger evidence on all trials."""
    body = tuple(
        (
            fmt(r.get("rank")),
            str(r.get("effect")),
            fmt(r.get("extra_parameters")),
            pct(r.get("absorbable_share")),
            fmt(r.get("holdout_loss_base_kN2")),
            fmt(r.get("holdout_loss_kN2")),
            fmt(r.get("holdout_shrink_pct"), 3),
            fmt(r.get("dm_z"), 3),
            fmt(r.get("score"), 3),
            fmt(r.get("evidence"), 3),
            ("yes" if r.get("significant") else "no") + (", named" if r.get("effect") == named else ""),
        )
        for r in rows
    )
    return Table(
        (
            "rank",
            "effect",
            "extra parameters",
            "absorbable share",
            "held-out loss, base (kN²)",
            "held-out loss, with effect (kN²)",
            "shrink (%)",
            "z",
            "score",
            "evidence, all trials",
            "significant",
        ),
        body,
        caption="candidate effects ranked by their penalised held-out score",
        numeric=(0, 2, 3, 4, 5, 6, 7, 8, 9),
    )


def _shrink(shrink: dict[str, Any]) -> Table:
    rows = []
    for label, m in (shrink.get("models") or {}).items():
        fit, hold = m.get("fit") or {}, m.get("holdout") or {}
        rows.append(
            (
                label,
                ", ".join(m.get("effects") or []) or "none",
                fmt(fit.get("loss_kN2")),
                fmt(fit.get("shrink_pct"), 3),
                fmt(hold.get("loss_kN2")),
                fmt(hold.get("shrink_pct"), 3),
            )
        )
    sets = shrink.get("sets") or {}
    return Table(
        (
            "model",
            "effects",
            "fitting loss (kN²)",
            "shrink (%)",
            "held-out loss (kN²)",
            "shrink (%)",
        ),
        tuple(rows),
        caption=f"gap before and after (fitting: {', '.join(sets.get('fit') or [])}; "
        f"held out: {', '.join(sets.get('holdout') or [])})",
        numeric=(2, 3, 4, 5),
    )


def truth_check(run: RunFiles, best: str | None) -> Paragraph | None:
    if run.truth is None:
        return None
    base = set(run.calibration.get("effects") or [])
    withheld = [e for e in run.truth.get("effects") or [] if e not in base]
    named = best or "no effect"
    if not withheld:
        return Paragraph(
            f"Check against the known truth: the synthetic data have no withheld effect; "
            f"the diagnosis names {named}."
        )
    hit = best in withheld
    return Paragraph(
        f"Check against the known truth: the synthetic data were made with "
        f"{', '.join(withheld)} on, which the calibrated model lacks; the diagnosis names "
        f"{named}{' (correct)' if hit else ' (not the withheld effect)'}.",
        tone="normal" if hit else "warning",
    )


def _selection(diag: dict[str, Any]) -> list[Block]:
    """The forward selection's steps and the next command, or the single effect's next step
    for a summary written before effect sets were selected."""
    best = (diag.get("decision") or {}).get("best")
    if not best:
        return []
    chosen = [str(e) for e in diag.get("selected_effects") or [best]]
    steps = (diag.get("selection") or {}).get("steps") or []
    lines = tuple(
        (f"with {st.get('added')}: held-out loss {fmt(st.get('holdout_loss_before_kN2'))} -> "
         f"{fmt(st.get('holdout_loss_after_kN2'))} kN^2, score {fmt(st.get('score'), 3)}: added")
        if st.get("added") else
        (f"best next candidate {st.get('best_candidate')}: held-out loss "
         f"{fmt(st.get('holdout_loss_before_kN2'))} -> {fmt(st.get('holdout_loss_after_kN2'))} kN^2, "
         f"score {fmt(st.get('score'), 3)}: not significant, the selection stops")
        for st in steps)
    left_out = (diag.get("selection") or {}).get("left_out") or []
    if left_out:
        lines += (f"not tried: {', '.join(map(str, left_out))} (alone, their parameters could not move "
                  "the curves along the gap and the held-out loss changed by less than 1 %)",)
    blocks: list[Block] = []
    if lines:
        blocks += [Paragraph(f"Forward selection from {best}:"), Bullets(lines)]
    flags = " ".join(f"--effect {e}" for e in chosen)
    blocks.append(Paragraph(
        f"Selected effect set: {' + '.join(chosen)}. Next step: calibrate again with it on, e.g. "
        f"smcbayes calibrate CONFIG --effects-from DIAGNOSIS_DIR --out RUN2 (or {flags}), and "
        "compare the posteriors and the coverage of the bands."))
    return blocks


def diagnosis_section(run: RunFiles) -> Section | None:
    """Where (verdict, heat map), which (ranking), how far it shrinks (tables, before/after)."""
    diag = run.diagnosis
    if diag is None:
        return None
    sec = Section("diagnosis", "Sim-to-real gap diagnosis")
    where = diag.get("where") or {}
    sec.add(Heading("Where the model misses"))
    if where.get("verdict"):
        verdict = str(where["verdict"])
        sec.add(Paragraph(verdict[:1].upper() + verdict[1:]))
    if (fig := run.diagnosis_figure("heatmap")) is not None:
        sec.add(
            Figure(
                fig,
                "Force residual (measured minus simulated, kN) per configuration over the "
                "normalised closing time.",
            )
        )
    decision = diag.get("decision") or {}
    if diag.get("ranking"):
        sec.add(Heading("Which effect explains it"), _ranking(diag["ranking"], decision.get("best")))
    if decision.get("statement"):
        sec.add(Paragraph(str(decision["statement"])))
    if (check := truth_check(run, decision.get("best"))) is not None:
        sec.add(check)
    sec.add(*_selection(diag))
    if diag.get("shrink"):
        sec.add(Heading("How far the gap shrinks"), _shrink(diag["shrink"]))
    if (fig := run.diagnosis_figure("phase_rmse")) is not None:
        sec.add(Figure(fig, "Force RMSE per phase and configuration, before and after (kN)."))
    if (fig := run.diagnosis_figure("before_after")) is not None:
        sec.add(
            Figure(fig, "Measured force (black) and the simulated force of each model (colour).")
        )
    return sec
