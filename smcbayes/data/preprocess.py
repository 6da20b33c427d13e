"""Pre-processing of measured curves; every function returns the new curve and a one-line
description of what it did, which the dataset keeps with the measurement.

Times in s, forces in kN, lengths in mm.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from smcbayes.data.curve import Curve
from smcbayes.errors import DataError

Array = NDArray[np.float64]

LIMIT_FRACTION = 0.98
"""The force-controlled hold starts where the force first reaches this share of the limit
(the controller settles onto the limit from slightly below)."""


def crossing_time(curve: Curve, level: float) -> float | None:
    """First time (s) the curve reaches ``level``, linearly interpolated; None if never."""
    hit = np.nonzero(curve.values >= level)[0]
    if hit.size == 0:
        return None
    i = int(hit[0])
    if i == 0:
        return float(curve.time_s[0])
    t0, t1, v0, v1 = curve.time_s[i - 1], curve.time_s[i], curve.values[i - 1], curve.values[i]
    return float(t0 + (level - v0) / (v1 - v0) * (t1 - t0))


def cut(curve: Curve, start_s: float | None = None, end_s: float | None = None) -> Curve:
    """The part of ``curve`` in [start_s, end_s], with interpolated end points."""
    t, v = curve.time_s, curve.values
    lo = t[0] if start_s is None else max(start_s, t[0])
    hi = t[-1] if end_s is None else min(end_s, t[-1])
    inside = (t > lo) & (t < hi)
    tt = np.concatenate(([lo], t[inside], [hi]))
    return curve.with_data(tt, np.interp(tt, t, v))


def shift(curve: Curve, t0_s: float) -> Curve:
    """Curve with ``t0_s`` subtracted from its times."""
    return curve.with_data(curve.time_s - t0_s, curve.values)


def contact_time(force: Curve, threshold_kN: float) -> float:
    """Time (s) the force first reaches ``threshold_kN`` (first contact)."""
    t = crossing_time(force, threshold_kN)
    if t is None:
        raise DataError(f"{force.source}: force never reaches the contact threshold "
                        f"{threshold_kN:g} kN; lower preprocess.contact_threshold_kN or check units")
    return t


def trim_idle(force: Curve, threshold_kN: float) -> tuple[float, float, str]:
    """Start and end (s) of the pressing: idle states before contact and after opening.

    Returns:
        ``(start_s, end_s, description)``: start is the last sample below the threshold
        before first contact, end the first sample below it after the force peak.
    """
    t, v = force.time_s, force.values
    contact = np.nonzero(v >= threshold_kN)[0]
    if contact.size == 0:
        raise DataError(f"{force.source}: force never reaches {threshold_kN:g} kN, nothing but "
                        "idle states; check the file or preprocess.contact_threshold_kN")
    start = t[max(int(contact[0]) - 1, 0)]
    peak = int(np.argmax(v))
    after = np.nonzero(v[peak:] < threshold_kN)[0]
    end = t[peak + int(after[0])] if after.size else t[-1]
    return float(start), float(end), (f"trim idle states: kept {start:.3f}-{end:.3f} s of "
                                      f"{t[0]:.3f}-{t[-1]:.3f} s (force < {threshold_kN:g} kN is idle)")


def zero_at_contact(force: Curve, threshold_kN: float) -> tuple[Curve, float, str]:
    """Shift time so that t = 0 at first contact and drop earlier samples."""
    tc = contact_time(force, threshold_kN)
    out = shift(cut(force, start_s=tc), tc)
    text = f"t = 0 at first contact: force reaches {threshold_kN:g} kN at {tc:.4f} s of the file"
    return out, tc, text


def split_at_limit(force: Curve, limit_kN: float) -> tuple[float, str]:
    """Time (s) the closing ends and the force-controlled hold begins."""
    ts = crossing_time(force, LIMIT_FRACTION * limit_kN)
    if ts is None:
        raise DataError(f"{force.source}: force never reaches the force limit {limit_kN:g} kN "
                        f"(maximum {force.values.max():.4g} kN); check press.force_limit_kN and units")
    return ts, (f"split closing / hold at {ts:.4f} s where the force first reaches "
                f"{LIMIT_FRACTION:.0%} of the {limit_kN:g} kN limit")


def hold_from_travel(travel: Curve, start_s: float) -> tuple[Curve, str]:
    """Hold curve from a ram travel/position curve: relative to the hold start, closing negative.

    The closing direction is the direction the ram moved before ``start_s``.
    """
    before = travel.at(np.array([travel.time_s[0], start_s]))
    sign = -1.0 if before[1] >= before[0] else 1.0
    hold = shift(cut(travel, start_s=start_s), start_s)
    values = sign * (hold.values - hold.values[0])
    out = Curve(hold.time_s, values, "displacement", "mm", travel.source)
    return out, f"hold: ram travel after {start_s:.4f} s, relative to its start, closing negative"


def savgol(curve: Curve, window_s: float, order: int) -> tuple[Curve, str]:
    """Savitzky-Golay smoothing; uneven samples are first resampled at their median spacing."""
    from scipy.signal import savgol_filter

    dt = float(np.median(np.diff(curve.time_s)))
    t = np.arange(curve.time_s[0], curve.time_s[-1] + 0.5 * dt, dt)
    t = t[t <= curve.time_s[-1]]
    n = int(round(window_s / dt)) | 1
    if n <= order or n > t.size:
        raise DataError(f"{curve.source}: smoothing window {window_s:g} s is {n} samples; needs "
                        f"more than smooth_order {order} and at most {t.size}; change smooth_window_s")
    v = savgol_filter(np.interp(t, curve.time_s, curve.values), n, order)
    return curve.with_data(t, v), (f"Savitzky-Golay smoothing of {curve.name}: window {n} samples "
                                   f"({n * dt:.3g} s), order {order}, on a {dt:.3g} s grid")


def resample(curve: Curve, dt_s: float) -> tuple[Curve, str]:
    """Linear resampling to a uniform grid starting at the first sample."""
    t = np.arange(curve.time_s[0], curve.time_s[-1] + 1e-9 * dt_s, dt_s)
    if t.size < 2:
        raise DataError(f"{curve.source}: resample_dt_s {dt_s:g} s leaves fewer than 2 samples")
    return curve.with_data(t, curve.at(t)), f"resampled {curve.name} to {t.size} points every {dt_s:g} s"


def flow_stop_time(gap0_mm: float, area_ratio: float, speed_mm_s: float) -> float:
    """Time (s) the ram has travelled from h_init to the flow-stop gap at the set speed.

    Thesis eq. 4.1: ``h_flow = A_cov / A_mould * h_init``.
    """
    return gap0_mm * (1.0 - area_ratio) / speed_mm_s


def clip_flow_stop(force: Curve, t_clip_s: float) -> tuple[Curve, str]:
    """Cut the closing force at the incompressible flow-stop time."""
    return cut(force, end_s=t_clip_s), f"clipped force at the flow-stop time {t_clip_s:.4f} s (eq. 4.1)"


def clip_force_limit(force: Curve, limit_kN: float) -> tuple[Curve, str]:
    """Cut the closing force where it first reaches the force limit."""
    t = crossing_time(force, limit_kN)
    if t is None:
        return force, f"force limit {limit_kN:g} kN not reached; nothing clipped"
    return cut(force, end_s=t), f"clipped force at {t:.4f} s where it reaches the {limit_kN:g} kN limit"
