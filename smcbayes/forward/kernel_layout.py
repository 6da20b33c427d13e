"""Named layouts of the flat arrays the compiled marching kernel works on.

The kernel (:mod:`smcbayes.forward._march_kernel`) takes its inputs as flat float arrays;
the slots of those arrays are generated here from the effect classes it implements
(:data:`KERNEL_EFFECTS`, each declaring :attr:`~smcbayes.forward.effects.base.Effect.kernel_slots`
and :attr:`~smcbayes.forward.effects.base.Effect.kernel_state`), so the packing in
:mod:`smcbayes.forward.march_compiled` and the reading in the kernel use the same names.

* :data:`ROW`, per parameter set ``(P, len(ROW))``: initial solid fraction ``solid0``,
  frame compliance ``inv_k`` (m/N), an on-flag ``on:NAME`` per kernel effect, each
  effect's parameters by symbol (SI) and the initial value ``NAME0`` of each state variable;
* :data:`STATE`, the state of one row ``(len(STATE),)``: time (s), gap (m), charge area
  (m^2), frame deflection (m), phase, switch time (s) and the effects' state variables;
* :data:`GEO`, the configuration and press programme ``(len(GEO),)`` (SI).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from smcbayes.errors import SolverError
from smcbayes.forward.effects.base import Effect
from smcbayes.forward.effects.registry import BUILT_IN

Array = NDArray[np.float64]

KERNEL_EFFECTS: tuple[type[Effect], ...] = BUILT_IN
"""Effect classes whose hooks the compiled kernel implements: the built-in ones,
recognised by class, so a subclass that changes a hook runs on the NumPy path."""


class Slots:
    """Names of the slots of a flat array, in order."""

    def __init__(self, names: Iterable[str]) -> None:
        self.names = tuple(names)
        self._index = {n: i for i, n in enumerate(self.names)}
        if len(self._index) != len(self.names):
            raise SolverError(f"duplicate slot names in {self.names}")

    def __len__(self) -> int:
        return len(self.names)

    def __getitem__(self, name: str) -> int:
        return self._index[name]

    def pack(self, values: Mapping[str, ArrayLike], rows: int) -> Array:
        """``(rows, len(self))`` array of ``values`` (scalars or ``(rows,)``); others 0."""
        out = np.zeros((rows, len(self)))
        for name, value in values.items():
            out[:, self._index[name]] = value
        return out


def _effect_state() -> tuple[str, ...]:
    return tuple(s for cls in KERNEL_EFFECTS for s in cls.kernel_state)


ROW = Slots(("solid0", "inv_k")
            + tuple(f"on:{cls.name}" for cls in KERNEL_EFFECTS)
            + tuple(s for cls in KERNEL_EFFECTS for s in cls.kernel_slots or ())
            + tuple(f"{s}0" for s in _effect_state()))
STATE = Slots(("t", "gap", "area", "delta", "phase", "switch") + _effect_state())
GEO = Slots(("planar", "width", "area0", "area_mould", "gap0", "gap_full", "force_limit", "hold",
             "speed", "jump_time", "shape_weight", "fill0", "T_mould"))

INTERPOLATED = tuple(i for i, n in enumerate(STATE.names) if n not in ("area", "phase", "switch"))
"""State slots moved linearly back to the crossing of the force limit (the area moves
geometrically; phase and switch time are set)."""
