"""Compiled time-marching backend for the built-in effects.

The NumPy marching path (:mod:`smcbayes.forward.march`) is general: any effect plugs in
through its hooks.  Its cost is ~0.3 ms of interpreter and NumPy call overhead per step,
whatever the batch size, so a single run takes ~300 steps x 0.3 ms.  This module is the
same algorithm (same balance, same events, same step control; see the docstring of
:mod:`~smcbayes.forward.march`) compiled with numba for the effects of
:data:`~smcbayes.forward.kernel_layout.KERNEL_EFFECTS`: their laws
(:mod:`smcbayes.forward.laws`) and the press programme (:mod:`smcbayes.forward.programme`)
are compiled from the same functions the NumPy path calls, and their parameters are
packed by the named layout of :mod:`smcbayes.forward.kernel_layout`.  It loops over rows
and steps in machine code, so one run costs about a millisecond.  Its results agree with
the NumPy path to round-off (tests/forward/test_march_compiled.py).  The NumPy path
remains the reference and serves what the kernel does not know: effects registered by
users and measured ram profiles.

numba compiles the kernel on first use (about 10 s) and caches it on disk.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward import kernel_layout, laws, programme
from smcbayes.forward.case import Case, shape_factor
from smcbayes.forward.effects.base import EffectStack
from smcbayes.forward.flux import MaterialTable
from smcbayes.forward.kernel_layout import GEO, KERNEL_EFFECTS, ROW
from smcbayes.forward.layout import square_charge_tables
from smcbayes.forward.nodes import Nodes
from smcbayes.forward.programme import MarchOptions, PressProgramme
from smcbayes.forward.result import STATUS_OK

Array = NDArray[np.float64]

_FAILED = ("failed: the press programme did not finish within the step limit "
           "(press stalled before the force limit?)")
_KERNEL: Any = None
RUNS = {"compiled": 0}
"""Number of batches the compiled kernel has run in this process (tests check the path)."""


def unsupported(effects: EffectStack, case: Case) -> list[str]:
    """What keeps ``effects`` on ``case`` off the compiled kernel (empty: nothing)."""
    out = [f"effect '{e.name}'" for e in effects.effects if type(e) not in KERNEL_EFFECTS]
    if case.profile is not None:
        out.append(f"the measured ram profile of configuration '{case.id}'")
    return out


def supports(effects: EffectStack, case: Case) -> bool:
    """True when the compiled kernel can run ``effects`` on ``case`` (constant set speed)."""
    return not unsupported(effects, case)


def _fingerprint() -> str:
    """Hash of the sources compiled into the kernel besides its own file."""
    digest = hashlib.sha256()
    for module in (laws, programme, kernel_layout):
        digest.update(Path(module.__file__ or "").read_bytes())
    return digest.hexdigest()


def _kernel() -> Any:
    """The compiled kernel, imported on first use: importing numba and loading the
    compiled code takes about half a second, which runs that never march should not pay."""
    global _KERNEL
    if _KERNEL is None:
        # lazy on purpose: numba and the compiled code load only when a run marches
        from smcbayes.forward import _march_kernel as module

        # numba keys its disk cache on the kernel's own file only; drop cached machine
        # code compiled from other versions of the shared laws, programme or layout
        stamp = Path(module.__file__ or "").with_name("__pycache__") / "_march_kernel.deps"
        current = _fingerprint()
        if not stamp.exists() or stamp.read_text() != current:
            for dispatcher in (*module.DISPATCHERS, *_kernel_functions(module)):
                dispatcher._cache.flush()
            try:
                stamp.parent.mkdir(exist_ok=True)
                stamp.write_text(current)
            except OSError:  # a read-only install: numba caches elsewhere or not at all
                pass
        _KERNEL = module.march_rows
    return _KERNEL


def _kernel_functions(module: Any) -> list[Any]:
    """The kernel module's own compiled functions."""
    return [f for f in vars(module).values() if hasattr(f, "_cache") and hasattr(f, "py_func")
            and f.py_func.__module__ == module.__name__]


def row_params(case: Case, p: dict[str, Array], effects: EffectStack, P: int) -> Array:
    """Per-row values of :data:`~smcbayes.forward.kernel_layout.ROW`, ``(P, len(ROW))``, SI."""
    s0 = effects.solid_fraction0(case, p, P)
    values: dict[str, Any] = {
        "solid0": 1.0 if s0 is None else np.minimum(np.asarray(s0, float), 1.0),
        "inv_k": effects.compliance(case, p, P)}
    for e in effects.effects:
        values[f"on:{e.name}"] = 1.0
        values.update(e.kernel_values(case, p, P))
    values.update({f"{name}0": v for name, v in effects.initial_state(case, p, P).items()})
    return ROW.pack(values, P)


def _shape_table(case: Case, enabled: bool) -> tuple[Array, Array, Array, float, float]:
    """Square-charge correction tables (x nodes, two ratio rows, weight, fill0); empty when off."""
    if not enabled or shape_factor(case, np.array([case.area0])) is None:
        empty = np.zeros(0)
        return empty, empty, empty, 0.0, 0.0
    x, low, high, w = square_charge_tables(case.area0 / case.area_mould)
    return x, low, high, w, case.area0 / case.area_mould


def geometry(case: Case, press: PressProgramme, weight: float, fill0: float) -> Array:
    """Values of :data:`~smcbayes.forward.kernel_layout.GEO`, ``(len(GEO),)``, SI."""
    values = {"planar": float(case.planar), "width": case.width, "area0": case.area0,
              "area_mould": case.area_mould, "gap0": case.gap0, "gap_full": case.gap_full,
              "force_limit": press.force_limit, "hold": press.hold, "speed": press.speed,
              "jump_time": press.jump_time, "shape_weight": weight, "fill0": fill0,
              "T_mould": case.T_mould}
    return GEO.pack(values, 1)[0]


def march_compiled(case: Case, p: dict[str, Array], effects: EffectStack, table: MaterialTable,
                   options: MarchOptions) -> Nodes:
    """Same contract as :func:`smcbayes.forward.march.march`, for :func:`supports` cases."""
    steps, hold_steps = options.closing_steps, options.hold_steps
    P = p["n"].shape[0]
    x, low, high, w, fill0 = _shape_table(case, getattr(options, "shape_correction", True))
    geo = geometry(case, PressProgramme.of(case, options.jump_time_s), w, fill0)
    max_iter = 12 * (steps + hold_steps) + 20
    shear = np.ascontiguousarray(np.broadcast_to(table.shear, (P, table.tau.size)))
    slip = np.ascontiguousarray(np.broadcast_to(table.slip, (P, table.tau.size)))
    rec, count, switch, done = _kernel()(
        table.tau, slip, shear, np.ascontiguousarray(p["B"], dtype=float),
        row_params(case, p, effects, P), geo, x, low, high, steps, hold_steps, max_iter)
    RUNS["compiled"] += 1
    width = max(int(count.max()), 1)
    rec = rec[:, :, :width]
    status = [STATUS_OK if d else _FAILED for d in done]
    return Nodes(time=rec[0], gap=rec[1], area=rec[2], force=rec[3], deflection=rec[4],
                 solid=rec[5], count=count.astype(np.int64), switch=switch, status=status)
