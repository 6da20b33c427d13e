"""The report's words on how the posterior was sampled: the emcee chains, and the importance
sample that is the reported posterior on the default path and under the forward model's
correction.
"""

from __future__ import annotations

from typing import Any

from smcbayes.posterior.correct import K_HAT_WARN as K_HAT_LIMIT
from smcbayes.posterior.reliability import R_HAT_MAX as R_HAT_LIMIT
from smcbayes.posterior.reliability import chains_r_hat
from smcbayes.report.document import Block, Paragraph, fmt


def num(x: Any) -> float:
    """``x`` as a float; NaN for anything but a number (None, NaN, text)."""
    return float(x) if isinstance(x, (int, float)) and x == x else float("nan")


def _correction_paragraph(corr: dict[str, Any], r_hat: float) -> Paragraph:
    """Plain words on the importance correction of the emulated posterior.

    Args:
        corr: the ``correction`` block of the posterior summary.
        r_hat: the largest R-hat of the emulator chains (the correction's proposal).
    """
    k_hat = num(corr.get("k_hat"))
    weights_ok = bool(corr.get("reliable") and corr.get("settled")) and k_hat <= K_HAT_LIMIT
    if weights_ok and r_hat <= R_HAT_LIMIT:
        verdict = "the weights are reliable and the corrected posterior can be trusted"
    elif weights_ok:
        # the proposal came from chains that disagree; only the weights vouch for the result
        verdict = (f"the corrected posterior rests on the importance weights (k-hat "
                   f"{fmt(k_hat, 2)}), the emulator chains did not converge (R-hat "
                   f"{fmt(r_hat, 3)}), so a part of the posterior the proposal never reached "
                   "would go unseen")
    elif k_hat > K_HAT_LIMIT:
        verdict = ("the weights are unreliable (k-hat above 0.7): the proposal misses part of "
                   "the posterior, so treat the numbers as indicative")
    else:
        verdict = ("the correction did not settle within its draws: treat the numbers as "
                   "indicative")
    return Paragraph(
        f"The emulated posterior was corrected by importance sampling with the forward model: "
        f"{fmt(corr.get('evaluations'))} forward runs, Pareto k-hat {fmt(k_hat, 2)}, importance "
        f"effective sample size {fmt(corr.get('ess'), 3)}; {verdict}. The table and figures "
        "show the corrected posterior.",
        tone="normal" if weights_ok else "warning",
    )


def _emulator_sample_paragraph(corr: dict[str, Any]) -> Paragraph:
    """Plain words on the importance sample of the emulated posterior (no forward run).

    Args:
        corr: the ``correction`` block of the posterior summary (``target`` "emulator").
    """
    k_hat = num(corr.get("k_hat"))
    weights_ok = bool(corr.get("reliable") and corr.get("settled")) and k_hat <= K_HAT_LIMIT
    if weights_ok:
        verdict = "the weights are reliable"
    elif k_hat > K_HAT_LIMIT:
        verdict = ("the weights are unreliable (k-hat above 0.7): the proposal misses part of "
                   "the emulated posterior, so treat the numbers as indicative")
    else:
        verdict = "the sampling did not settle within its draws: treat the numbers as indicative"
    return Paragraph(
        f"The emulated posterior was sampled by importance on the emulator, with no forward run: "
        f"{fmt(corr.get('draws'))} emulator evaluations, Pareto k-hat {fmt(k_hat, 2)}, importance "
        f"effective sample size {fmt(corr.get('ess'), 3)}; {verdict}. The table and figures "
        "show this weighted sample.",
        tone="normal" if weights_ok else "warning",
    )


def sampler_paragraphs(post: dict[str, Any]) -> list[Block]:
    """The chains' stopping rule and largest R-hat, with their smallest effective sample
    size; with an importance sample (of the emulated posterior, or corrected by the forward
    model), the weights' paragraph instead of that size.

    The R-hat is read from the chains' own table (``emulator_parameters``), as an
    importance-weighted ``parameters`` table has none; a summary without that table has
    the chains' R-hat in ``parameters``."""
    params = post.get("parameters") or []
    sampler = post.get("sampler") or []
    r_hat = chains_r_hat(post)
    ess = min((num(p.get("ess")) for p in params), default=float("nan"))
    converged = bool(sampler) and all(s.get("converged") for s in sampler)
    steps = ", ".join(str(s.get("steps", "-")) for s in sampler) or "-"
    words = (
        "The chains met the autocorrelation stopping rule"
        if converged
        else "The chains stopped at the step limit before the autocorrelation stopping rule was met"
    )
    quality = (
        "the walkers agree"
        if r_hat <= R_HAT_LIMIT
        else "the walkers do not yet agree, so treat the numbers as indicative"
    )
    corr = post.get("correction") or {}
    if corr.get("enabled") and corr.get("target") == "emulator":
        # the chains only started the importance sample of the emulated posterior, which its
        # weights judge (as the stage's verdict does)
        return [
            Paragraph(
                f"{words} on the emulator (steps per chain: {steps}); the largest R-hat of its "
                f"chains is {fmt(r_hat, 3)}. They only started the importance sampling, whose "
                "weights judge the reported posterior."
            ),
            _emulator_sample_paragraph(corr),
        ]
    if corr.get("enabled"):
        # R-hat belongs to the emulator chains, the effective sample size to the weights
        chains = ("the emulator chains agree" if r_hat <= R_HAT_LIMIT
                  else "the emulator chains did not converge")
        return [
            Paragraph(
                f"{words} on the emulator (steps per chain: {steps}); the largest R-hat of its "
                f"chains is {fmt(r_hat, 3)}: {chains}."
            ),
            _correction_paragraph(corr, r_hat),
        ]
    return [
        Paragraph(
            f"{words} (steps per chain: {steps}); the largest R-hat is {fmt(r_hat, 3)} "
            f"and the smallest effective sample size {fmt(ess, 3)}: {quality}."
        )
    ]
