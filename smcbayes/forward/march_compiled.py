"""Compiled time-marching backend for the built-in effects.

The NumPy marching path (:mod:`smcbayes.forward.march`) is general: any effect plugs in
through its hooks.  Its cost is ~0.3 ms of interpreter and NumPy call overhead per step,
whatever the batch size, so a single run takes ~300 steps x 0.3 ms.  This module is the
same algorithm (same balance, same events, same step control; see the docstring of
:mod:`~smcbayes.forward.march`) compiled with numba, with the hooks of the built-in
effects (:data:`SUPPORTED`) written into the kernel.  It loops over rows and steps in
machine code, so one run costs about a millisecond.  Its results agree with the NumPy path
to round-off (tests/forward/test_march_compiled.py).  The NumPy path remains the
reference and serves what the kernel does not know: effects registered by users and
measured ram profiles.

numba compiles the kernel on first use (about 10 s) and caches it on disk.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.case import Case
from smcbayes.forward.effects.base import EffectStack
from smcbayes.forward.flux import MaterialTable
from smcbayes.forward.nodes import Nodes
from smcbayes.forward.result import STATUS_OK
from smcbayes.units import ZERO_C_K

Array = NDArray[np.float64]

SUPPORTED = frozenset({"compressibility", "heating", "curing", "press_compliance", "speed_ramp"})
"""Effects whose hooks the compiled kernel implements."""

_FAILED = ("failed: the press programme did not finish within the step limit "
           "(press stalled before the force limit?)")
_KERNEL: Any = None


def supports(effects: EffectStack, case: Case) -> bool:
    """True when the compiled kernel can run ``effects`` on ``case`` (constant set speed)."""
    return case.profile is None and set(effects.names) <= SUPPORTED


def _kernel() -> Any:
    global _KERNEL
    if _KERNEL is None:
        from smcbayes.forward import _march_kernel

        _KERNEL = _march_kernel.march_rows
    return _KERNEL


def _row_params(case: Case, p: dict[str, Array], effects: EffectStack, P: int) -> Array:
    """Per-row effect parameters, ``(P, 17)``, SI (column order: see ``_march_kernel``)."""
    out = np.zeros((P, 17))
    s0 = effects.solid_fraction0(case, p, P)
    out[:, 0] = 1.0 if s0 is None else np.minimum(np.asarray(s0, float), 1.0)
    if "compressibility" in effects.names:
        out[:, 1] = p["compaction_modulus"]
        out[:, 2] = p["compaction_exponent"]
        out[:, 3] = p["bulk_viscosity"]
    out[:, 4] = effects.compliance(case, p, P)
    if "speed_ramp" in effects.names:
        out[:, 5] = p["ramp_time"]
        out[:, 6] = p["load_slowdown"]
    if "heating" in effects.names:
        out[:, 7] = 1.0
        out[:, 8] = p["T_start_C"] + ZERO_C_K
        out[:, 9] = p["diffusivity"]
        out[:, 10] = p["T_b"]
    if "curing" in effects.names:
        out[:, 11] = 1.0
        for col, name in zip(range(12, 17), ("k1", "k2", "c1", "c2", "alpha_g"), strict=True):
            out[:, col] = p[name]
    return out


def _shape_table(case: Case, enabled: bool) -> tuple[Array, Array, Array, float, float]:
    """Square-charge correction tables (x nodes, two ratio rows, weight, fill0); empty when off."""
    from smcbayes.forward.layout import square_charge_tables
    from smcbayes.forward.squeeze1d import shape_factor

    if not enabled or shape_factor(case, np.array([case.area0])) is None:
        empty = np.zeros(0)
        return empty, empty, empty, 0.0, 0.0
    x, low, high, w = square_charge_tables(case.area0 / case.area_mould)
    return x, low, high, w, case.area0 / case.area_mould


def march_compiled(case: Case, p: dict[str, Array], effects: EffectStack, table: MaterialTable,
                   options: object) -> Nodes:
    """Same contract as :func:`smcbayes.forward.march.march`, for :func:`supports` cases."""
    steps, hold_steps = options.closing_steps, options.hold_steps
    P = p["n"].shape[0]
    x, low, high, w, fill0 = _shape_table(case, getattr(options, "shape_correction", True))
    geometry = np.array([float(case.planar), case.width, case.area0, case.area_mould, case.gap0,
                         case.gap_full, case.force_limit, case.hold, case.speed,
                         options.jump_time_s, w, fill0, case.T_mould])
    max_iter = 12 * (steps + hold_steps) + 20
    shear = np.ascontiguousarray(np.broadcast_to(table.shear, (P, table.tau.size)))
    slip = np.ascontiguousarray(np.broadcast_to(table.slip, (P, table.tau.size)))
    rec, count, switch, done = _kernel()(
        table.tau, slip, shear, np.ascontiguousarray(p["B"], dtype=float),
        _row_params(case, p, effects, P), geometry, x, low, high, steps, hold_steps, max_iter)
    width = max(int(count.max()), 1)
    rec = rec[:, :, :width]
    status = [STATUS_OK if d else _FAILED for d in done]
    return Nodes(time=rec[0], gap=rec[1], area=rec[2], force=rec[3], deflection=rec[4],
                 solid=rec[5], count=count.astype(np.int64), switch=switch, status=status)
