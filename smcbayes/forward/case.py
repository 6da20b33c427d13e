"""A press configuration turned into SI numbers for the solvers (geometry + protocol).

The physics (model and effects) holds no numbers; a :class:`Case` holds the numbers of one
trial: mould and charge geometry, stack height and mass, temperatures and the press
programme.  Build once per configuration, solve for many parameter vectors.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from smcbayes.config import ConfigurationSpec
from smcbayes.errors import ConfigError
from smcbayes.forward.layout import square_charge_factor, union_area
from smcbayes.units import KN, MM, G, celsius_to_kelvin

Array = NDArray[np.float64]


AT_REST = "the measured ram profile ends at rest before the force limit"
"""Why a run whose ram log is over, with the ram at rest short of the limit, fails."""


@dataclass(frozen=True)
class SpeedProfile:
    """Measured ram position vs time, used instead of a constant set speed.

    Attributes:
        time: sample times (s), strictly increasing, shape ``(K,)``.
        position: ram travel from first contact (m, positive closing), shape ``(K,)``.
    """

    time: Array
    position: Array

    @cached_property
    def closed(self) -> Array:
        """The ram's closing up to each sample (m), ``(K,)``: the sum of its positive
        increments, as :meth:`speed` moves it (an opening is a pause)."""
        return np.concatenate([[0.0], np.cumsum(np.maximum(np.diff(self.position), 0.0))])

    def speed(self, t: Array) -> Array:
        """Closing speed (m/s) at times ``t`` (s): slope of the segment holding ``t`` (past
        the last sample, the last segment's; 0 where the ram opens)."""
        slopes = np.diff(self.position) / np.diff(self.time)
        idx = np.clip(np.searchsorted(self.time, t, side="right") - 1, 0, slopes.size - 1)
        return np.maximum(slopes[idx], 0.0)

    def ends_at_rest(self, t: ArrayLike) -> NDArray[np.bool_]:
        """Where the log is over at ``t`` (s) and the ram no longer closes: it can never
        reach more travel than it has.  Same shape as ``t``."""
        t = np.asarray(t, dtype=float)
        return (t >= self.time[-1]) & (self.speed(t) <= 0.0)

    def time_after(self, t0: float, travel: float) -> float:
        """Time (s) at which the ram has closed ``travel`` (m) more than at ``t0`` (s), counted
        as :meth:`speed` moves it (past the last sample at the last segment's speed); inf
        where the log ends at rest first."""
        if not (np.isfinite(t0) and travel > 0.0):  # none left, or none known (NaN)
            return t0 if travel <= 0.0 else np.nan
        closed = self.closed
        last = float(self.speed(np.array([self.time[-1]]))[0])
        start = (float(np.interp(t0, self.time, closed)) if t0 <= self.time[-1]
                 else float(closed[-1]) + last * (t0 - float(self.time[-1])))
        target = start + travel
        if target > closed[-1]:
            return float(self.time[-1]) + (target - float(closed[-1])) / last if last > 0.0 else np.inf
        i = max(int(np.searchsorted(closed, target, side="left")), 1)  # first sample at it
        frac = (target - closed[i - 1]) / (closed[i] - closed[i - 1])
        return max(float(self.time[i - 1] + frac * (self.time[i] - self.time[i - 1])), t0)

    def pace(self, travel: float) -> float:
        """Mean closing speed (m/s) over the first ``travel`` (m) of the ram's closing, or over
        all the closing the log holds if that is less: the speed that sets a solver's step.
        The closing is counted as :meth:`speed` moves the ram (an opening is a pause), and
        a log that runs on into the hold does not dilute it."""
        closed = self.closed
        if not closed[-1] > 0.0:
            raise ConfigError("the measured ram profile never closes (closing is positive)")
        travel = min(travel, float(closed[-1])) if travel > 0.0 else float(closed[-1])
        i = max(int(np.searchsorted(closed, travel, side="left")), 1)  # first sample at it
        frac = (travel - closed[i - 1]) / (closed[i] - closed[i - 1])
        return travel / float(self.time[i - 1] + frac * (self.time[i] - self.time[i - 1]))

    @classmethod
    def read(cls, path: Path) -> SpeedProfile:
        """Read a CSV with columns ``time_s`` and ``position_mm`` (closing positive)."""
        try:
            data = np.genfromtxt(path, delimiter=",", names=True)
            t, x = np.asarray(data["time_s"], float), np.asarray(data["position_mm"], float) * MM
        except (OSError, ValueError) as err:
            raise ConfigError(f"{path}: cannot read ram profile "
                              f"(need columns time_s, position_mm): {err}") from None
        if t.size < 2 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(x)):
            raise ConfigError(f"{path}: ram profile needs >= 2 rows with strictly increasing time_s")
        if not np.max(x - x[0]) > 0.0:
            raise ConfigError(f"{path}: the ram profile never closes (position_mm never rises above "
                              "its first value; closing is positive)")
        # time and travel from the first sample: the first contact
        return cls(t - t[0], x - x[0])


@dataclass(frozen=True)
class Case:
    """One press trial in SI units.

    Attributes:
        id: configuration id.
        planar: True for a full-width bar (1-D planar flow), False for a centre charge
            (axisymmetric flow of the equal-area disc).
        width: mould width across the bar's flow (m).
        mould_length: mould length along the bar's flow (m).
        area0: initial charge area (m^2).
        area_mould: cavity area (m^2).
        gap0: initial stack height H0 (m).
        mass: charge mass (kg) or None.
        T_mould, T_charge: temperatures (K).
        speed: set closing speed (m/s).
        force_limit: force limit (N).
        hold: force-controlled hold time (s).
        profile: measured ram profile replacing ``speed``, or None.
        pieces: charge layout as rectangles ``(x, y, length, width)`` (m), centres relative
            to the mould centre (x along the mould length); one rectangle for ``center``
            and ``bar`` charges.
    """

    id: str
    planar: bool
    width: float
    mould_length: float
    area0: float
    area_mould: float
    gap0: float
    mass: float | None
    T_mould: float
    T_charge: float
    speed: float
    force_limit: float
    hold: float
    profile: SpeedProfile | None = None
    pieces: tuple[tuple[float, float, float, float], ...] = ()

    @property
    def gap_full(self) -> float:
        """Gap at which an incompressible charge fills the cavity (thesis eq. 4.1) (m)."""
        return self.gap0 * self.area0 / self.area_mould

    def front(self, area: Array) -> Array:
        """Flow length from the charge area: half-length (planar) or radius (m)."""
        return area / (2.0 * self.width) if self.planar else np.sqrt(area / np.pi)

    def set_speed(self, t: Array) -> Array:
        """Commanded closing speed (m/s) at times ``t`` (s)."""
        if self.profile is None:
            return np.full_like(np.asarray(t, dtype=float), self.speed)
        return self.profile.speed(np.asarray(t, dtype=float))

    @classmethod
    def from_spec(cls, spec: ConfigurationSpec, base_dir: Path | None = None) -> Case:
        """Build from a validated configuration; raises :class:`ConfigError` on bad geometry."""
        mould, charge, press = spec.mould, spec.charge, spec.press
        L, W = mould.length_mm * MM, mould.width_mm * MM
        area_mould = L * W
        where = f"configuration '{spec.id}'"
        if charge.shape == "bar":
            if charge.width_mm is not None and abs(charge.width_mm - mould.width_mm) > 1e-9:
                raise ConfigError(f"{where}: charge.width_mm of a bar must equal mould.width_mm "
                                  f"({mould.width_mm:g}); use the 2-D solver for a partial-width strip")
            length = charge.length_mm * MM if charge.length_mm else charge.coverage_pct / 100 * L
            if length > L:
                raise ConfigError(f"{where}: charge.length_mm {length / MM:g} "
                                  f"exceeds mould.length_mm {L / MM:g}")
            area0 = length * W
            pieces = ((0.0, 0.0, length, W),)
        elif charge.shape == "layout":
            pieces = _layout_pieces(spec)
            area0 = union_area(pieces)
        else:
            if charge.length_mm is not None:
                lx = charge.length_mm * MM
                ly = (charge.width_mm or charge.length_mm) * MM
                if lx > L or ly > W:
                    raise ConfigError(f"{where}: centre charge {lx / MM:g} x {ly / MM:g} mm "
                                      "does not fit the mould")
                area0 = lx * ly
            else:
                area0 = charge.coverage_pct / 100 * area_mould
                # a coverage-only centre charge is the mould scaled down about its centre
                lx, ly = L * (charge.coverage_pct / 100) ** 0.5, W * (charge.coverage_pct / 100) ** 0.5
            pieces = ((0.0, 0.0, lx, ly),)
        profile = None
        if press.profile is not None:
            p = Path(press.profile)
            profile = SpeedProfile.read(p if p.is_absolute() or base_dir is None else base_dir / p)
        T_mould = celsius_to_kelvin(mould.temperature_C)
        T_charge = celsius_to_kelvin(charge.temperature_C) if charge.temperature_C is not None else T_mould
        return cls(id=spec.id, planar=charge.shape == "bar", width=W, mould_length=L,
                   area0=area0, area_mould=area_mould, gap0=charge.stack_height_mm * MM,
                   mass=charge.mass_g * G if charge.mass_g else None, T_mould=T_mould,
                   T_charge=T_charge, speed=press.speed_mm_s * MM,
                   force_limit=press.force_limit_kN * KN, hold=press.hold_s, profile=profile,
                   pieces=pieces)


def _layout_pieces(spec: ConfigurationSpec) -> tuple[tuple[float, float, float, float], ...]:
    """Rectangles (m) of a ``layout`` charge; raises :class:`ConfigError` if one leaves the mould."""
    L, W = spec.mould.length_mm * MM, spec.mould.width_mm * MM
    out = []
    for k, piece in enumerate(spec.charge.pieces or []):
        x, y, lx, ly = piece.x_mm * MM, piece.y_mm * MM, piece.length_mm * MM, piece.width_mm * MM
        if abs(x) + lx / 2 > L / 2 * (1 + 1e-9) or abs(y) + ly / 2 > W / 2 * (1 + 1e-9):
            raise ConfigError(f"configuration '{spec.id}': charge.pieces[{k}] "
                              f"({piece.length_mm:g} x {piece.width_mm:g} mm at x_mm={piece.x_mm:g}, "
                              f"y_mm={piece.y_mm:g}) leaves the {spec.mould.length_mm:g} x "
                              f"{spec.mould.width_mm:g} mm mould; centres are relative to the mould centre")
        out.append((x, y, lx, ly))
    return tuple(out)


def shape_factor(case: Case, area: Array) -> Array | None:
    """Force factor of the equal-area disc of a centred square charge, or None.

    Applies to a single centred piece in a square mould (see
    :func:`~smcbayes.forward.layout.square_charge_factor`; measured against the 2-D solver).
    """
    pieces = getattr(case, "pieces", ())
    if case.planar or abs(case.mould_length - case.width) > 1e-12 or len(pieces) != 1:
        return None
    piece = pieces[0]
    if abs(piece[0]) > 1e-12 or abs(piece[1]) > 1e-12 or abs(piece[2] - piece[3]) > 1e-12:
        return None
    return square_charge_factor(area / case.area_mould, case.area0 / case.area_mould)
