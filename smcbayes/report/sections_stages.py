"""Report sections of the posterior and the predictive bands.

Every summary is read defensively: a missing key leaves a cell '-' or drops a block,
never the whole report.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from smcbayes.posterior.spread import SPREAD_MAX, pooled_words, spread_words
from smcbayes.report.collect import RunFiles
from smcbayes.report.document import Block, Bullets, Figure, Heading, Paragraph, Section, Table, fmt, pct
from smcbayes.report.sampling_words import num as _num
from smcbayes.report.sampling_words import sampler_paragraphs

PRIOR_SHARE = 0.8
"""Share of the search range above which a 90 % interval says the data hardly moved the
prior; when every parameter is above it, the posterior is essentially the prior."""


def _diagnostics(post: dict[str, Any]) -> list[Block]:
    """The posterior's diagnostics: the sampler's
    (:func:`~smcbayes.report.sampling_words.sampler_paragraphs`), the emulator check, its
    spread, the likelihood's effective points, the warnings and the notes of the chains that
    started the importance sampling."""
    blocks = sampler_paragraphs(post)
    check = post.get("emulator_check") or {}
    if check:
        blocks.append(
            Paragraph(
                f"Emulator check: at {fmt(check.get('points'))} posterior draws the forward model "
                "and the Gaussian-process emulator differ in log-likelihood by "
                f"{fmt(check.get('mean_abs_error'), 3)} nats on average (largest "
                f"{fmt(check.get('max_abs_error'), 3)} nats); errors well below 1 nat mean the "
                "emulator can be trusted where the posterior lies."
            )
        )
    if (spread := _spread_paragraph(post.get("emulator_spread") or {})) is not None:
        blocks.append(spread)
    eff = post.get("effective_points") or {}
    if eff.get("n_eff_total") is not None:
        blocks.append(
            Paragraph(
                f"Effective number of independent points in the likelihood: "
                f"{fmt(eff.get('n_eff_total'), 3)} (residuals are autocorrelated, so "
                f"this is far fewer than the resampled points; {_n_eff_source(eff)})."
            )
        )
    warns = [str(w) for w in post.get("warnings") or []]
    if warns:
        blocks.append(Bullets(tuple(warns), tone="warning"))
    notes = [str(n) for n in post.get("proposal_notes") or []]
    if notes:
        blocks.append(Paragraph("The emcee chains that started the importance sampling, whose settled "
                                "weights the numbers above come from, say:"))
        blocks.append(Bullets(tuple(notes)))
    return blocks


def _spread_paragraph(spread: dict[str, Any]) -> Paragraph | None:
    """How far GP sample functions move the posterior, and whether they widen it."""
    if not spread:
        return None
    pooled = ""
    if spread.get("pooled"):
        by = pooled_words(spread)
        pooled = (" Their posteriors are pooled with the emulator's own in the table above, so the "
                  f"emulator's uncertainty widens it{', ' + by if by else ''}.")
    return Paragraph(
        f"Emulator spread: {spread_words(spread)}; "
        f"above {SPREAD_MAX} the simulator runs spent on the emulator do not yet determine the "
        f"posterior.{pooled}"
    )


def _method_words(post: dict[str, Any]) -> str:
    """What emulated the likelihood and what sampled it."""
    s = post.get("settings") or {}
    seed, seconds = fmt(s.get("seed")), fmt(post.get("seconds"), 3)
    if (post.get("active_learning") or {}).get("kind") == "curves":
        spread = post.get("emulator_spread") or {}
        pooled = (f", pooled with {fmt(spread.get('functions'))} GP sample functions' posteriors"
                  if spread.get("pooled") else "")
        return (f"A Gaussian process emulates the force curves{_active_words(post)}; the likelihood of their "
                "expected loss is sampled by importance on the emulator "
                f"(no forward run{pooled}, seed {seed}; "
                f"{seconds} s).")
    return (f"The calibration's Gaussian process emulates the likelihood{_active_words(post)}; "
            f"emcee samples it ({fmt(s.get('walkers'))} walkers, up to {fmt(s.get('steps'))} steps, "
            f"{_sampled_words(post)}, seed {seed}; {seconds} s).")


def _sampled_words(post: dict[str, Any]) -> str:
    """What emcee sampled: the GP mean, a mixture of sample functions, or both pooled."""
    functions = (post.get("settings") or {}).get("functions") or 0
    spread = post.get("emulator_spread") or {}
    if spread.get("pooled"):
        return f"the GP mean and {fmt(spread.get('functions'))} GP sample functions, pooled"
    return f"{fmt(functions)} GP sample functions" if functions else "the GP mean"


def _active_words(post: dict[str, Any]) -> str:
    """What the emulator started from and how it was trained further by active learning,
    in a clause."""
    active = post.get("active_learning") or {}
    start = active.get("start_points") or {}
    searched = start.get("local_search") or 0
    begun = (f", starting from its {fmt(start.get('calibration_gp'))} points and {fmt(searched)} "
             "evaluations of the calibration's local search" if searched else "")
    if not active.get("enabled"):
        return begun
    done = ("validated: out-of-sample error below 1 nat, stable quantiles and a small spread"
            if active.get("converged") else "stopped by its budget before it was validated")
    return (f"{begun}, trained further by active learning with "
            f"{fmt(active.get('evaluations'))} forward runs in "
            f"{fmt(active.get('rounds'))} rounds ({done})")


def _verdict(post: dict[str, Any]) -> list[Block]:
    """The stage's own verdict (``reliability``) first: unreliable with its reasons, and the
    notes on the posterior's shape (a bound, separate modes, a ridge) or on what its checks
    cannot see, with what to do."""
    rel = post.get("reliability") or {}
    if not rel:
        return []
    reasons = [str(r) for r in rel.get("reasons") or []]
    if rel.get("reliable"):
        blocks: list[Block] = [Paragraph("Verdict: the posterior's own diagnostics pass; its numbers "
                                         "can be used.")]
    else:
        blocks = [Paragraph("Verdict: the posterior is unreliable; treat its numbers as "
                            "indicative. Reasons:", tone="warning"),
                  Bullets(tuple(reasons), tone="warning")]
    notes = [str(n) for n in rel.get("notes") or []]
    if notes:
        blocks += [Paragraph("How to read it:"), Bullets(tuple(notes), tone="warning")]
    return blocks


def _pair_words(pair: dict[str, Any]) -> str:
    r = _num(pair.get("r"))
    strength = "strongly" if abs(r) >= 0.7 else "moderately" if abs(r) >= 0.4 else "weakly"
    sense = (
        "a larger value of one goes with a larger value of the other"
        if r > 0
        else "a larger value of one goes with a smaller value of the other"
    )
    return (
        f"{pair.get('a')} and {pair.get('b')}: r = {r:+.2f}, {strength} correlated; {sense}, "
        "so the data pin down their combination better than each alone."
    )


def interval_share(p: dict[str, Any], ranges: dict[str, tuple[float, float, bool]]) -> float:
    """Width of the 5-95 % interval as a share of the search range (log10 for log parameters)."""
    lo, hi, log = ranges.get(str(p.get("name")), (float("nan"), float("nan"), False))
    q05, q95 = _num(p.get("q05")), _num(p.get("q95"))
    if log:
        if min(lo, hi, q05, q95) <= 0:
            return float("nan")
        return (np.log10(q95) - np.log10(q05)) / (np.log10(hi) - np.log10(lo))
    return (q95 - q05) / (hi - lo) if hi > lo else float("nan")


def _identification(
    params: list[dict[str, Any]], ranges: dict[str, tuple[float, float, bool]]
) -> Paragraph | None:
    shares = {str(p.get("name")): interval_share(p, ranges) for p in params}
    known = {k: v for k, v in shares.items() if v == v}
    if not known:
        return None
    loose = [k for k, v in known.items() if v > 0.6]
    if not loose:
        return Paragraph(
            "Every parameter's 90 % interval is narrower than 60 % of its search range: "
            "the data identify the parameters."
        )
    if len(known) == len(shares) and all(v > PRIOR_SHARE for v in known.values()):
        return Paragraph(
            f"The posterior is essentially the prior: every parameter's 90 % interval spans "
            f"more than {pct(PRIOR_SHARE)} of its search range, so the data constrain none of "
            "them in this model. A misfit that no parameter value can remove, such as an "
            "unmodelled effect, has this signature; see the diagnosis.",
            tone="warning",
        )
    return Paragraph(
        f"The 90 % interval of {', '.join(loose)} spans more than 60 % of the search range: "
        "the data hardly constrain these parameters (the posterior is close to the "
        "prior). A misfit that no parameter value can remove, such as an unmodelled "
        "effect, has this signature; see the diagnosis.",
        tone="warning",
    )


def _largest_correlation(corr: dict[str, Any]) -> str:
    """The largest off-diagonal |r| of the correlation matrix, in words."""
    m = np.asarray(corr.get("matrix") or [[1.0]], dtype=float)
    labels = list(corr.get("labels") or [])
    if m.ndim != 2 or m.shape[0] < 2 or len(labels) != m.shape[0]:
        return "There is only one free parameter, so there are no correlations."
    off = np.abs(m - np.diag(np.diag(m)))
    i, j = np.unravel_index(int(np.nanargmax(off)), off.shape)
    return (
        f"No pair of parameters is noticeably correlated in the posterior: the largest is "
        f"{labels[i]} - {labels[j]}, r = {m[i, j]:+.2f}."
    )


POSTERIOR_HEADER = (
    "parameter",
    "unit",
    "mean",
    "sd",
    "5 %",
    "50 %",
    "95 %",
    "90 % interval / range",
    "R-hat",
    "ESS",
    "true value",
)


def _posterior_table(
    params: list[dict[str, Any]],
    truth: dict[str, Any],
    ranges: dict[str, tuple[float, float, bool]],
) -> Table:
    rows = tuple(
        (
            str(p.get("name")),
            str(p.get("unit", "-")),
            *(fmt(p.get(k)) for k in ("mean", "sd", "q05", "q50", "q95")),
            pct(interval_share(p, ranges)),
            fmt(p.get("r_hat"), 3),
            fmt(p.get("ess"), 3),
            fmt(truth.get(p.get("name"))),
        )
        for p in params
    )
    return Table(POSTERIOR_HEADER, rows, caption="posterior summary", numeric=tuple(range(2, 11)))


def _correlation_blocks(run: RunFiles, corr: dict[str, Any]) -> list[Block]:
    pairs = corr.get("strongest") or []
    blocks: list[Block] = [Heading("Correlations")]
    if pairs:
        blocks.append(Bullets(tuple(_pair_words(p) for p in pairs)))
    else:
        blocks.append(Paragraph(_largest_correlation(corr)))
    if (fig := run.figure("posterior", "figures", "correlations")) is not None:
        blocks.append(Figure(fig, "Posterior correlation matrix (sampled coordinates)."))
    return blocks


def posterior_section(
    run: RunFiles, ranges: dict[str, tuple[float, float, bool]] | None = None
) -> Section | None:
    """Summary table, diagnostics in plain words, corner plot, correlations named.

    Args:
        run: the run's files.
        ranges: search bounds ``(lower, upper, log)`` per free parameter, for the width of
            the 90 % interval relative to the search range (omitted if empty).
    """
    post = run.posterior
    if post is None:
        return None
    ranges = ranges or {}
    truth = (run.truth or {}).get("parameters") or post.get("truth") or {}
    params = post.get("parameters") or []
    sec = Section("posterior", "Posterior")
    sec.add(
        Paragraph(_method_words(post)),
        _posterior_table(params, truth, ranges),
        Heading("Diagnostics"),
        *_verdict(post),
    )
    if (ident := _identification(params, ranges)) is not None:
        sec.add(ident)
    sec.add(*_diagnostics(post))
    if (fig := run.figure("posterior", "figures", "learning")) is not None:
        sec.add(Figure(fig, "Active learning round by round: the emulator's error at fresh posterior "
                            "draws, the posterior's move and drift, and the spread of GP sample "
                            "functions' posteriors, each beside the bound the stop asks of the last "
                            "rounds; stars mark the reported posterior's spread at each confirmation."))
    if (fig := run.figure("posterior", "figures", "corner")) is not None:
        caption = "Corner plot of the posterior draws (log10 for log-scaled parameters); "
        caption += "5/50/95 % quantiles dashed" + ("; true values in red." if truth else ".")
        sec.add(Figure(fig, caption))
    sec.add(*_correlation_blocks(run, post.get("correlation") or {}))
    return sec


def bands_section(run: RunFiles) -> Section | None:
    """Predictive bands: their coverage of the measured curves beside their sharpness, and
    the error model they add to the posterior draws."""
    post = run.posterior
    if post is None or not post.get("bands"):
        return None
    bands = post["bands"]
    roles = {str(b.get("role", "-")) for b in bands.values()}
    sec = Section("bands", "Predictive bands")
    kind = (
        "validation configurations, not used in the calibration"
        if roles == {"validation"}
        else "training configurations (the project has no validation configuration with data)"
    )
    sec.add(Paragraph(_bands_text(kind, post.get("discrepancy"))))
    rows = tuple(
        (
            cid,
            str(b.get("role", "-")),
            pct(b.get("coverage50")),
            pct(b.get("coverage90")),
            fmt(b.get("width90_kN"), 3),
            fmt(b.get("crps_kN"), 3),
            fmt(b.get("interval_score90_kN"), 3),
            fmt(b.get("rmse_median_kN"), 3),
            fmt(b.get("rmse_mean_kN"), 3),
            fmt(b.get("draws")),
        )
        for cid, b in bands.items()
    )
    sec.add(
        Table(
            ("configuration", "role", "inside 50 % band", "inside 90 % band", "90 % width (kN)",
             "CRPS (kN)", "interval score 90 % (kN)", "median RMSE (kN)", "predictive mean RMSE (kN)",
             "draws"),
            rows,
            caption="coverage and sharpness of the predictive force bands; the predictive mean is the "
                    "point prediction",
            numeric=(2, 3, 4, 5, 6, 7, 8, 9),
        )
    )
    disc = post.get("discrepancy")
    if disc and disc.get("bins"):
        sec.add(_error_table(disc["bins"], "error model: measured minus simulated force of the training "
                             "configurations (see above for the parameter points), by remaining ram travel "
                             "to the simulated end of closing"))
        for extra in disc.get("extrapolation") or []:
            sec.add(_error_table(extra.get("bins") or [], "error model of "
                                 f"{', '.join(extra.get('configurations') or [])}, outside the training set: "
                                 f"residuals of {extra.get('residuals', '')}"))
    if (fig := run.figure("posterior", "figures", "bands")) is not None:
        sec.add(
            Figure(
                fig,
                "Predicted force bands (colour), the predictive mean (dashed; the point "
                "prediction) and the measured force (black) per configuration.",
            )
        )
    return sec


def _error_table(bins: list[dict], caption: str) -> Table:
    """One error model's bins: remaining travel, counts and the 5/50/95 % errors."""
    return Table(
        ("remaining travel (mm)", "points", "configurations", "error 5 % (kN)", "median (kN)",
         "error 95 % (kN)"),
        tuple((_travel_range(b), fmt(b.get("points")), fmt(b.get("configurations")),
               fmt(b.get("q05_kN"), 3), fmt(b.get("q50_kN"), 3), fmt(b.get("q95_kN"), 3)) for b in bins),
        caption=caption, numeric=(1, 2, 3, 4, 5))


def _bands_text(kind: str, discrepancy: dict | None) -> str:
    """The paragraph above the bands table."""
    source = (discrepancy or {}).get("residuals", "calibrated point")
    where = ("each left out of a refit on the others" if source.startswith("leave")
             else "at the calibrated point")
    error = (
        f"plus an error drawn from the training configurations' residuals ({where}) at the same "
        "stage of the closing (remaining ram travel to the simulated end of closing; table "
        "below), so the bands widen where the model misses the press, such as the end of "
        "closing; a configuration at a speed outside the fitted range or with a charge no "
        "training configuration has takes the residuals of training configurations left out "
        "as a group across the same kind of gap"
        if discrepancy
        else "plus white noise with each configuration's residual standard deviation"
    )
    return (
        f"Posterior draws pushed through the forward model on the {kind}, {error}; the bands "
        "are clipped to 0 kN and the press's force limit. Coverage is the share of measured "
        "points inside the band: a calibrated model covers about 50 % and 90 % of the points "
        "with its 50 % and 90 % bands; much lower means the model misses the measurements by "
        "more than its uncertainty, much higher that the bands are wider than needed. Read it "
        "beside the sharpness: the mean width of the 90 % band, the CRPS (mean distance of "
        "the predictive distribution from the measured points, in kN; smaller is better) and "
        "the interval score (width plus 20 times the distance of the points outside the 90 % "
        "band; smaller is better). The point prediction is the predictive mean (dashed in the "
        "figure): under squared error it is the best single curve, since it averages over the "
        "parameters, the contact scatter and the error model's lean."
    )


def _travel_range(b: dict) -> str:
    """A bin of the error model as text, e.g. ``0.5 to 1.2`` or ``below 0``."""
    lo, hi = b.get("from_mm"), b.get("to_mm")
    if lo is None:
        return f"below {fmt(hi, 3)}"
    if hi is None:
        return f"above {fmt(lo, 3)}"
    return f"{fmt(lo, 3)} to {fmt(hi, 3)}"


def _n_eff_source(eff: dict) -> str:
    """How the effective number of points was estimated, in words."""
    if "n_eff_sandwich" not in eff or eff.get("n_eff_residual") is None:
        return "from the residuals' autocorrelation"
    sandwich, residual = eff["n_eff_sandwich"], eff["n_eff_residual"]
    # a failed sandwich estimate is NaN in the stage and null in summary.json
    if sandwich is None or not np.isfinite(float(sandwich)):
        return "from the residuals' autocorrelation (the sandwich estimate was unavailable)"
    return ("the smaller of two estimates at the best point: from the curvature of the likelihood "
            f"against the scatter of its score, {fmt(sandwich, 3)}, and from the residuals' "
            f"autocorrelation, {fmt(residual, 3)}")
