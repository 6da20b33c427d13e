"""Where the calibrated model misses: per configuration, phase and normalised time.

The residual is measured minus simulated force on the loss's comparison window, the
closing from first contact to the force limit; normalised time is the position in that
window (0 = contact, 1 = its end).  The verdict is computed from these numbers:

1. the configurations carrying the misfit: the smallest set holding >= ``share`` of the
   squared error, described by what they have in common (coverage, charge shape, speed);
2. the time window: the shortest run of normalised-time bins holding >= ``share`` of their
   squared error, named as the first / last x % of the closing or a span;
3. the sign of the residual there, the phase that dominates it, the mean lag of the
   simulated force limit (simulated minus measured time at which the limit is reached),
   and the timing / amplitude / shape split of the error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.data.breakdown import force_breakdown
from smcbayes.data.loss import force_pair
from smcbayes.diagnose.fit import DiagnosisContext
from smcbayes.forward.result import PHASE_NAMES

Array = NDArray[np.float64]

PHASE_WORDS = {"contact": "contact", "flow": "flow", "full": "mould-full compaction",
               "force_control": "force-control"}


@dataclass(frozen=True)
class WhereReport:
    """Residual analysis of one model on some configurations.

    Attributes:
        ids: configurations (rows of ``heat_kN``).
        bins: bin centres of normalised time, shape ``(B,)``.
        heat_kN: mean residual (measured - simulated) per bin, shape ``(K, B)``.
        heat_sq_kN2: mean squared residual per bin, shape ``(K, B)``.
        mse_kN2: force MSE per configuration, ``(K,)``.
        phase_rmse_kN: RMS error per phase, ``(K, 4)`` (NaN where a phase is absent).
        phase_share: share of each configuration's squared error per phase, ``(K, 4)``.
        lag_s: best-fit time lag of the simulated curve (positive: late), ``(K,)``.
        limit_lag_s: simulated minus measured time of reaching the force limit, ``(K,)``.
        split_kN2: timing shift, amplitude and shape parts of the MSE, ``(K, 3)``.
        verdict: the computed text verdict.
        focus: configurations and normalised-time window named in the verdict.
    """

    ids: list[str]
    bins: Array
    heat_kN: Array
    heat_sq_kN2: Array
    mse_kN2: Array
    phase_rmse_kN: Array
    phase_share: Array
    lag_s: Array
    limit_lag_s: Array
    split_kN2: Array
    verdict: str
    focus: dict

    def to_json(self) -> dict:
        """JSON-ready dictionary (per configuration entries keyed by id)."""
        per = {}
        for k, cid in enumerate(self.ids):
            per[cid] = {"mse_kN2": float(self.mse_kN2[k]),
                        "rmse_kN": float(np.sqrt(self.mse_kN2[k])),
                        "phase_rmse_kN": {p: _num(self.phase_rmse_kN[k, i])
                                          for i, p in enumerate(PHASE_NAMES)},
                        "phase_share": {p: _num(self.phase_share[k, i])
                                        for i, p in enumerate(PHASE_NAMES)},
                        "lag_s": float(self.lag_s[k]), "limit_lag_s": _num(self.limit_lag_s[k]),
                        "split_kN2": dict(zip(("timing", "amplitude", "shape"),
                                              map(float, self.split_kN2[k]), strict=True))}
        return {"verdict": self.verdict, "focus": self.focus, "per_config": per,
                "bins": self.bins.tolist(), "heat_kN": self.heat_kN.tolist()}


def _kn(x: float) -> str:
    """A force for text: whole kN from 100 kN up, three significant digits below."""
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.3g}"


def _num(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)


def analyse(ctx: DiagnosisContext, extra: Sequence[str], theta: Array, ids: Sequence[str],
            bins: int = 40, share: float = 0.6) -> WhereReport:
    """Residuals of the model ``extra`` at ``theta`` ``(1, d)`` on ``ids`` and the verdict."""
    ids = list(ids)
    results = ctx.simulate(extra, theta, ids)
    spec = ctx.project.loss
    edges = np.linspace(0.0, 1.0, bins + 1)
    heat, heat_sq = np.zeros((len(ids), bins)), np.zeros((len(ids), bins))
    limit_lag = np.full(len(ids), np.nan)
    for k, cid in enumerate(ids):
        pair = force_pair(results[cid], ctx.dataset[cid], spec)
        r = pair.meas_kN[0] - pair.sim_kN[0]
        tn = np.linspace(0.0, 1.0, r.size)
        idx = np.clip(np.searchsorted(edges, tn, side="right") - 1, 0, bins - 1)
        count = np.maximum(np.bincount(idx, minlength=bins), 1)
        heat[k] = np.bincount(idx, r, minlength=bins) / count
        heat_sq[k] = np.bincount(idx, r * r, minlength=bins) / count
        ts = results[cid].switch_time_s[0]
        if np.isfinite(ts) and ts > 0:
            limit_lag[k] = ts - ctx.dataset[cid].force.time_s[-1]
    bd = force_breakdown(results, ctx.dataset, spec, ids)
    mse = bd.shift_kN2[0] + bd.amplitude_kN2[0] + bd.shape_kN2[0]
    split = np.column_stack([bd.shift_kN2[0], bd.amplitude_kN2[0], bd.shape_kN2[0]])
    report = WhereReport(ids, 0.5 * (edges[:-1] + edges[1:]), heat, heat_sq, mse,
                         np.sqrt(bd.phase_mse_kN2[0]), bd.phase_share[0], bd.shift_s[0],
                         limit_lag, split, "", {})
    verdict, focus = make_verdict(ctx, report, share)
    return WhereReport(**{**report.__dict__, "verdict": verdict, "focus": focus})


def describe_group(ctx: DiagnosisContext, ids: Sequence[str], all_ids: Sequence[str]) -> str:
    """Words for a set of configurations: what they share that the others do not."""
    if len(ids) == len(all_ids):
        return "all configurations"
    specs = [ctx.project.get(cid) for cid in ids]
    words = []
    cover = {s.charge.coverage_pct for s in specs}
    if len(cover) == 1 and None not in cover:
        words.append(f"{next(iter(cover)):g} %")
    shapes = {s.charge.shape for s in specs}
    if len(shapes) == 1:
        words.append(next(iter(shapes)))
    speeds = {s.press.speed_mm_s for s in specs}
    if len(speeds) == 1:
        words.append(f"{next(iter(speeds)):g} mm/s")
    if not words or (len(ids) <= 2 and len(words) < 3):
        return "configuration" + ("s " if len(ids) > 1 else " ") + ", ".join(ids)
    return "the " + " ".join(words) + " configuration" + ("s" if len(ids) > 1 else "")


def time_window(profile: Array, share: float) -> tuple[int, int]:
    """Shortest run of bins ``[i, j)`` holding >= ``share`` of ``profile``'s sum (``(B,)``)."""
    total = profile.sum()
    if total <= 0:
        return 0, profile.size
    c = np.concatenate(([0.0], np.cumsum(profile)))
    best = (0, profile.size)
    for i in range(profile.size):
        j = int(np.searchsorted(c, c[i] + share * total - 1e-12 * total))
        if j <= profile.size and j - i < best[1] - best[0]:
            best = (i, max(j, i + 1))
    return best


def window_words(i: int, j: int, bins: int) -> str:
    """'the last 30 % of the closing' / 'the first 20 %' / 'between 40 % and 70 %'."""
    lo, hi = round(100 * i / bins), round(100 * j / bins)
    if lo == 0 and hi == 100:
        return "the whole closing"
    if hi == 100:
        return f"the last {100 - lo} % of the closing"
    if lo == 0:
        return f"the first {hi} % of the closing"
    return f"the closing between {lo} % and {hi} % of its duration"


def make_verdict(ctx: DiagnosisContext, rep: WhereReport, share: float) -> tuple[str, dict]:
    """The text verdict and the focus it names (configurations, window, numbers)."""
    sse = rep.heat_sq_kN2.sum(axis=1)
    order = np.argsort(-sse)
    cum = np.cumsum(sse[order]) / max(sse.sum(), 1e-300)
    n_focus = int(np.searchsorted(cum, share - 1e-12) + 1)
    focus_idx = sorted(order[:n_focus].tolist())
    focus_ids = [rep.ids[k] for k in focus_idx]
    i, j = time_window(rep.heat_sq_kN2[focus_idx].sum(axis=0), share)
    in_window = rep.heat_sq_kN2[focus_idx, i:j].sum() / max(sse.sum(), 1e-300)
    mean_r = float(np.mean(rep.heat_kN[focus_idx, i:j]))
    sign = "above" if mean_r > 0 else "below"
    phase_sse = np.nansum(rep.phase_share[focus_idx] * sse[focus_idx, None], axis=0)
    phase = PHASE_NAMES[int(np.argmax(phase_sse))]
    split = rep.split_kN2[focus_idx].sum(axis=0)
    split = split / max(split.sum(), 1e-300)
    lag = rep.limit_lag_s[focus_idx]
    lag_txt = ""
    if np.any(np.isfinite(lag)):
        mean_lag = float(np.nanmean(lag))
        when = (f"{abs(mean_lag):.2g} s {'late' if mean_lag > 0 else 'early'}"
                if abs(mean_lag) >= 0.05 else "on time (within 0.05 s)")
        lag_txt = f": the simulation reaches the force limit {when}"
    rmse = float(np.sqrt(np.mean(rep.mse_kN2)))
    verdict = (f"the misfit is concentrated in {window_words(i, j, rep.bins.size)} in "
               f"{describe_group(ctx, focus_ids, rep.ids)} ({100 * in_window:.0f} % of the squared "
               f"error, mostly in the {PHASE_WORDS[phase]} phase){lag_txt}; there the measured "
               f"force lies {sign} the simulated one by {_kn(abs(mean_r))} kN on average; "
               f"timing shift {100 * split[0]:.0f} %, amplitude {100 * split[1]:.0f} %, "
               f"shape {100 * split[2]:.0f} % of the error (overall RMSE {_kn(rmse)} kN)")
    focus = {"configurations": focus_ids, "window": [i / rep.bins.size, j / rep.bins.size],
             "share_in_focus": float(in_window), "phase": phase, "mean_residual_kN": mean_r,
             "limit_lag_s": None if not np.any(np.isfinite(lag)) else float(np.nanmean(lag)),
             "split_share": dict(zip(("timing", "amplitude", "shape"), map(float, split),
                                     strict=True))}
    return verdict, focus
