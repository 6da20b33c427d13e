"""Report sections of the posterior, the predictive bands and the gap diagnosis.

Every summary is read defensively: a missing key leaves a cell '-' or drops a block,
never the whole report.
"""

from __future__ import annotations

from typing import Any

from smcbayes.report.collect import RunFiles
from smcbayes.report.document import Bullets, Figure, Heading, Paragraph, Section, Table, fmt, pct

R_HAT_LIMIT = 1.05
"""R-hat above which the walkers are said to disagree (the posterior stage's own limit)."""


def _num(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) and x == x else float("nan")


def _diagnostics(post: dict[str, Any]) -> list:
    params = post.get("parameters") or []
    sampler = post.get("sampler") or []
    r_hat = max((_num(p.get("r_hat")) for p in params), default=float("nan"))
    ess = min((_num(p.get("ess")) for p in params), default=float("nan"))
    converged = bool(sampler) and all(s.get("converged") for s in sampler)
    steps = ", ".join(str(s.get("steps", "-")) for s in sampler) or "-"
    words = ("The chains met the autocorrelation stopping rule" if converged else
             "The chains stopped at the step limit before the autocorrelation stopping rule was met")
    quality = ("the walkers agree" if r_hat <= R_HAT_LIMIT else
               "the walkers do not yet agree, so treat the numbers as indicative")
    blocks: list = [Paragraph(f"{words} (steps per chain: {steps}); the largest R-hat is {fmt(r_hat, 3)} "
                              f"and the smallest effective sample size {fmt(ess, 3)}: {quality}.")]
    check = post.get("emulator_check") or {}
    if check:
        blocks.append(Paragraph(
            f"Emulator check: at {fmt(check.get('points'))} posterior draws the forward model and the "
            f"Gaussian-process emulator differ in log-likelihood by {fmt(check.get('mean_abs_error'), 3)} "
            f"nats on average (largest {fmt(check.get('max_abs_error'), 3)} nats); errors well below "
            "1 nat mean the emulator can be trusted where the posterior lies."))
    eff = post.get("effective_points") or {}
    if eff.get("n_eff_total") is not None:
        blocks.append(Paragraph(f"Effective number of independent points in the likelihood: "
                                f"{fmt(eff.get('n_eff_total'), 3)} (residuals are autocorrelated, so "
                                "this is far fewer than the resampled points)."))
    warns = [str(w) for w in post.get("warnings") or []]
    if warns:
        blocks.append(Bullets(tuple(warns), tone="warning"))
    return blocks


def _pair_words(pair: dict[str, Any]) -> str:
    r = _num(pair.get("r"))
    strength = "strongly" if abs(r) >= 0.7 else "moderately" if abs(r) >= 0.4 else "weakly"
    sense = ("a larger value of one goes with a larger value of the other" if r > 0 else
             "a larger value of one goes with a smaller value of the other")
    return (f"{pair.get('a')} and {pair.get('b')}: r = {r:+.2f}, {strength} correlated; {sense}, "
            "so the data pin down their combination better than each alone.")


def posterior_section(run: RunFiles) -> Section | None:
    """Summary table, diagnostics in plain words, corner plot, correlations named."""
    post = run.posterior
    if post is None:
        return None
    truth = (run.truth or {}).get("parameters") or post.get("truth") or {}
    s = post.get("settings") or {}
    sec = Section("posterior", "Posterior")
    sec.add(Paragraph(f"The calibration's Gaussian process emulates the likelihood; emcee samples it "
                      f"({fmt(s.get('walkers'))} walkers, up to {fmt(s.get('steps'))} steps, "
                      f"{fmt(s.get('functions'))} GP sample functions, seed {fmt(s.get('seed'))}; "
                      f"{fmt(post.get('seconds'), 3)} s)."))
    rows = tuple((str(p.get("name")), str(p.get("unit", "-")),
                  *(fmt(p.get(k)) for k in ("mean", "sd", "q05", "q50", "q95")),
                  fmt(p.get("r_hat"), 3), fmt(p.get("ess"), 3), fmt(truth.get(p.get("name"))))
                 for p in post.get("parameters") or [])
    sec.add(Table(("parameter", "unit", "mean", "sd", "5 %", "50 %", "95 %", "R-hat", "ESS", "true value"),
                  rows, caption="posterior summary", numeric=tuple(range(2, 10))))
    sec.add(Heading("Diagnostics"), *_diagnostics(post))
    if (fig := run.figure("posterior", "figures", "corner")) is not None:
        sec.add(Figure(fig, "Corner plot of the posterior draws (log10 for log-scaled parameters); "
                            "5/50/95 % quantiles dashed" + ("; true values in red." if truth else ".")))
    sec.add(Heading("Correlations"))
    pairs = (post.get("correlation") or {}).get("strongest") or []
    if pairs:
        sec.add(Bullets(tuple(_pair_words(p) for p in pairs)))
    else:
        sec.add(Paragraph("No pair of parameters is strongly correlated in the posterior."))
    if (fig := run.figure("posterior", "figures", "correlations")) is not None:
        sec.add(Figure(fig, "Posterior correlation matrix (sampled coordinates)."))
    return sec


def bands_section(run: RunFiles) -> Section | None:
    """Predictive bands and their coverage of the measured curves."""
    post = run.posterior
    if post is None or not post.get("bands"):
        return None
    bands = post["bands"]
    roles = {str(b.get("role", "-")) for b in bands.values()}
    sec = Section("bands", "Predictive bands")
    kind = "validation configurations, not used in the calibration" if roles == {"validation"} else \
        "training configurations (the project has no validation configuration with data)"
    sec.add(Paragraph(f"Posterior draws pushed through the forward model on the {kind}. Coverage is the "
                      "share of measured points inside the band; a calibrated model covers about 50 % "
                      "and 90 % of the points with its 50 % and 90 % bands. Much lower coverage means "
                      "the model misses the measurements by more than its uncertainty."))
    rows = tuple((cid, str(b.get("role", "-")), pct(b.get("coverage50")), pct(b.get("coverage90")),
                  fmt(b.get("noise_kN"), 3), fmt(b.get("draws"))) for cid, b in bands.items())
    sec.add(Table(("configuration", "role", "inside 50 % band", "inside 90 % band", "noise sd (kN)",
                   "draws"), rows, caption="coverage of the measured force", numeric=(2, 3, 4, 5)))
    if (fig := run.figure("posterior", "figures", "bands")) is not None:
        sec.add(Figure(fig, "Predicted force bands (colour) and the measured force (black) per configuration."))
    return sec


def _ranking(rows: list[dict[str, Any]]) -> Table:
    body = tuple((fmt(r.get("rank")), str(r.get("effect")), fmt(r.get("extra_parameters")),
                  pct(r.get("absorbable_share")), fmt(r.get("holdout_loss_base_kN2")),
                  fmt(r.get("holdout_loss_kN2")), fmt(r.get("holdout_shrink_pct"), 3), fmt(r.get("dm_z"), 3),
                  fmt(r.get("score"), 3), "yes" if r.get("significant") else "no") for r in rows)
    return Table(("rank", "effect", "extra parameters", "absorbable share", "held-out loss, base (kN²)",
                  "held-out loss, with effect (kN²)", "shrink (%)", "z", "score", "significant"), body,
                 caption="candidate effects ranked by their penalised held-out score",
                 numeric=(0, 2, 3, 4, 5, 6, 7, 8))


def _shrink(shrink: dict[str, Any]) -> Table:
    rows = []
    for label, m in (shrink.get("models") or {}).items():
        fit, hold = m.get("fit") or {}, m.get("holdout") or {}
        rows.append((label, ", ".join(m.get("effects") or []) or "none", fmt(fit.get("loss_kN2")),
                     fmt(fit.get("shrink_pct"), 3), fmt(hold.get("loss_kN2")), fmt(hold.get("shrink_pct"), 3)))
    sets = shrink.get("sets") or {}
    return Table(("model", "effects", "fitting loss (kN²)", "shrink (%)", "held-out loss (kN²)", "shrink (%)"),
                 tuple(rows), caption=f"gap before and after (fitting: {', '.join(sets.get('fit') or [])}; "
                                      f"held out: {', '.join(sets.get('holdout') or [])})",
                 numeric=(2, 3, 4, 5))


def _truth_check(run: RunFiles, best: str | None) -> Paragraph | None:
    if run.truth is None:
        return None
    base = set((run.calibration.get("effects") or []))
    withheld = [e for e in run.truth.get("effects") or [] if e not in base]
    named = best or "no effect"
    if not withheld:
        return Paragraph(f"Check against the known truth: the synthetic data have no withheld effect; "
                         f"the diagnosis names {named}.")
    hit = best in withheld
    return Paragraph(f"Check against the known truth: the synthetic data were made with "
                     f"{', '.join(withheld)} on, which the calibrated model lacks; the diagnosis names "
                     f"{named}{' (correct)' if hit else ' (not the withheld effect)'}.",
                     tone="normal" if hit else "warning")


def diagnosis_section(run: RunFiles) -> Section | None:
    """Where (verdict, heat map), which (ranking), how far it shrinks (tables, before/after)."""
    diag = run.diagnosis
    if diag is None:
        return None
    sec = Section("diagnosis", "Sim-to-real gap diagnosis")
    where = diag.get("where") or {}
    sec.add(Heading("Where the model misses"))
    if where.get("verdict"):
        sec.add(Paragraph(str(where["verdict"])))
    if (fig := run.diagnosis_figure("heatmap")) is not None:
        sec.add(Figure(fig, "Force residual (measured minus simulated, kN) per configuration over the "
                            "normalised closing time."))
    decision = diag.get("decision") or {}
    if diag.get("ranking"):
        sec.add(Heading("Which effect explains it"), _ranking(diag["ranking"]))
    if decision.get("statement"):
        sec.add(Paragraph(str(decision["statement"])))
    if (check := _truth_check(run, decision.get("best"))) is not None:
        sec.add(check)
    if diag.get("shrink"):
        sec.add(Heading("How far the gap shrinks"), _shrink(diag["shrink"]))
    if (fig := run.diagnosis_figure("phase_rmse")) is not None:
        sec.add(Figure(fig, "Force RMSE per phase and configuration, before and after (kN)."))
    if (fig := run.diagnosis_figure("before_after")) is not None:
        sec.add(Figure(fig, "Measured force (black) and the simulated force of each model (colour)."))
    return sec
