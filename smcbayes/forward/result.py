"""Batched simulation output in engineering units."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

PHASE_CONTACT, PHASE_FLOW, PHASE_FULL, PHASE_FORCE = 0, 1, 2, 3
PHASE_NAMES: tuple[str, ...] = ("contact", "flow", "full", "force_control")

STATUS_OK = "ok"


@dataclass(frozen=True)
class SimulationResult:
    """Curves of one configuration for a batch of ``P`` parameter sets.

    Every curve has shape ``(P, T)``; a row whose ``status`` is not ``"ok"`` holds NaN.

    Attributes:
        config_id: configuration id.
        time_s: time from first contact (s), strictly increasing per row.
        gap_mm: cavity gap (mm).
        displacement_mm: ram travel from first contact (mm, positive closing); equals the
            gap change unless the press frame is compliant.
        force_kN: press force (kN).
        fill_fraction: charge area / cavity area (-).
        solid_fraction: consolidated volume fraction of the charge (-), 1 if incompressible.
        phase: phase code per sample, index into :data:`PHASE_NAMES`.
        switch_time_s: time the press switched to force control, shape ``(P,)``.
        status: ``"ok"`` or ``"failed: reason"`` per row, length ``P``.
        effects: names of the effects that were on.
    """

    config_id: str
    time_s: Array
    gap_mm: Array
    displacement_mm: Array
    force_kN: Array
    fill_fraction: Array
    solid_fraction: Array
    phase: NDArray[np.int8]
    switch_time_s: Array
    status: list[str]
    effects: tuple[str, ...] = field(default=())

    @property
    def rows(self) -> int:
        """Number of parameter sets ``P``."""
        return self.time_s.shape[0]

    @property
    def ok(self) -> NDArray[np.bool_]:
        """Rows that ran to completion, shape ``(P,)``."""
        return np.array([s == STATUS_OK for s in self.status])

    def row(self, i: int) -> dict[str, Array]:
        """Curves of row ``i`` as a dict of ``(T,)`` arrays (for CSV writing and plots)."""
        return {
            "time_s": self.time_s[i], "gap_mm": self.gap_mm[i],
            "displacement_mm": self.displacement_mm[i], "force_kN": self.force_kN[i],
            "fill_fraction": self.fill_fraction[i], "solid_fraction": self.solid_fraction[i],
            "phase": self.phase[i].astype(float),
        }
