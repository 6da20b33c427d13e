"""Measured curves of a project's configurations, read and pre-processed once.

``load_dataset(project)`` reads every configuration's data files (CSV, press export or
Moldflow XML, see :mod:`smcbayes.data.readers`), checks them against the configuration
(units by orders of magnitude against the force limit), applies the optional
pre-processing of ``[preprocess]`` and records each step with the measurement.  Files are
only read, never written.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import ConfigurationSpec, DataSpec, ProjectConfig
from smcbayes.config.specs import PreprocessSpec
from smcbayes.data import preprocess as pp
from smcbayes.data.curve import Curve
from smcbayes.data.readers.csv import read_csv
from smcbayes.data.readers.moldflow import read_moldflow
from smcbayes.data.readers.press import read_press
from smcbayes.errors import DataError
from smcbayes.forward.case import Case
from smcbayes.units import MM

Array = NDArray[np.float64]

UNIT_FACTOR_LIMIT = 20.0
"""A closing force above this multiple of the force limit is taken as a unit mistake."""

HOLD_MIN_S = 1.0
"""A force curve running this long past the limit contains the hold and is split there."""

END_NEAR_LIMIT = 0.95
"""A force curve that stops at this share of the limit or above without reaching it is
taken to stop where the press switched (sampled or digitised curves end a little short of
the limit, and a curve through the hold is cut at the hold's threshold)."""


@dataclass(frozen=True)
class Measurement:
    """The measured curves of one configuration.

    Attributes:
        config_id: configuration id.
        role: ``train`` or ``validation``.
        force: closing force (kN) from first contact to the force limit, or None.
        hold: ram displacement (mm) during the force-controlled hold vs time since the
            hold began (s), relative to the hold start, negative = closing; or None.
        steps: what was read and done, one line per step, in order.
        force_limit_kN: the configuration's force limit (kN).
        flow_stop_s: time (s) from contact at which the ram reaches the incompressible
            flow-stop gap (thesis eq. 4.1) at the set speed.
        speed_mm_s: the set closing speed (mm/s), which turns a contact offset into a delay.
        end_stack_mm: the stack height (mm) at first contact that the trial's end state
            implies were the frame rigid (:func:`end_stack_height_mm`); None without a
            measured part or a force curve that reaches the limit.
    """

    config_id: str
    role: str
    force: Curve | None
    hold: Curve | None
    steps: list[str] = field(default_factory=list)
    force_limit_kN: float = 1400.0
    flow_stop_s: float | None = None
    speed_mm_s: float | None = None
    end_stack_mm: float | None = None


@dataclass(frozen=True)
class Dataset:
    """Measurements of a project, by configuration id (configurations with data only).

    Attributes:
        project: the project the data belong to.
        measurements: id -> measurement, in the project's order.
        preprocess: the pre-processing options applied.
    """

    project: ProjectConfig
    measurements: dict[str, Measurement]
    preprocess: PreprocessSpec = PreprocessSpec()

    def ids(self, role: str | None = None) -> list[str]:
        """Ids of configurations with measurements, optionally of one role."""
        return [k for k, m in self.measurements.items() if role is None or m.role == role]

    def __getitem__(self, config_id: str) -> Measurement:
        if config_id not in self.measurements:
            raise DataError(f"configuration '{config_id}' has no measured data; configurations with "
                            f"data: {', '.join(self.measurements) or 'none'}")
        return self.measurements[config_id]


def flow_stop_time_s(spec: ConfigurationSpec, base_dir: Path) -> float:
    """Time (s) after contact at which the ram reaches h_flow = A_cov / A_mould * h_init."""
    case = Case.from_spec(spec, base_dir)
    travel = case.gap0 - case.gap_full
    if case.profile is not None:
        return float(np.interp(travel, case.profile.position, case.profile.time))
    return pp.flow_stop_time(case.gap0 / MM, case.area0 / case.area_mould, case.speed / MM)


def _check_units(m: Measurement, stack_mm: float) -> None:
    """Reject values off by orders of magnitude (a unit mistake) with the fix."""
    if m.force is not None:
        peak = float(np.max(m.force.values))
        if peak > UNIT_FACTOR_LIMIT * m.force_limit_kN:
            raise DataError(
                f"{m.force.source}: force up to {peak:.4g} kN is {peak / m.force_limit_kN:.0f}x the "
                f"{m.force_limit_kN:g} kN force limit; the file is probably in N: set "
                "data.force_unit = 'N' (or name the column force_N)")
    if m.hold is not None:
        travel = float(np.max(np.abs(m.hold.values)))
        if travel > 10.0 * stack_mm:
            raise DataError(
                f"{m.hold.source}: hold displacement up to {travel:.4g} mm exceeds 10x the "
                f"{stack_mm:g} mm stack; the file is probably in um: set data.displacement_unit")


def end_stack_height_mm(spec: ConfigurationSpec, force: Curve | None, hold: Curve | None,
                        steps: list[str]) -> float | None:
    """The stack height (mm) at first contact that a pressed trial's end state implies.

    Under speed control the ram travels v t_end from first contact to the force limit; the
    gap there is the part's thickness plus what the force-controlled hold closed after it
    (the hold curve's last value, negative = closing).  Their sum is the charge's height at
    contact, were the frame rigid: a compliant frame has travelled F / k further, which
    the loss takes from the simulation (:func:`smcbayes.data.loss.end_state_offsets_mm`).
    The closing ends where the force first reaches the limit (where the simulation
    switches), or at the end of a curve that stops short of it at :data:`END_NEAR_LIMIT`
    of it or above.  A note on what was used is
    appended to ``steps``; None (with the reason) when the trial has no measured part, no
    force curve reaching the limit, or a ram profile instead of a set speed.
    """
    part = None if spec.part is None else spec.part.thickness(spec.mould)
    if part is None:
        return None
    limit = spec.press.force_limit_kN
    t_end = None if force is None else pp.crossing_time(force, limit)
    if t_end is None and force is not None and force.values[-1] >= END_NEAR_LIMIT * limit:
        t_end = float(force.time_s[-1])
    if t_end is None or spec.press.profile is not None:
        why = ("its closing follows a ram profile, not a set speed" if spec.press.profile is not None
               else "its force curve does not reach the force limit")
        steps.append(f"no end state: {why}")
        return None
    closed = 0.0 if hold is None else float(-hold.values[-1])
    travel = spec.press.speed_mm_s * t_end
    height = part + closed + travel
    held = (f"+ {closed:.3f} mm closed in the hold" if hold is not None
            else "(no hold curve: nothing closed in the hold)")
    steps.append(f"end state: part {part:.3f} mm {held} + ram travel {travel:.3f} mm to the force "
                 f"limit = stack height {height:.3f} mm at contact "
                 f"(nominal {spec.charge.stack_height_mm:g} mm)")
    return height


def _path(root: Path | None, name: str, cid: str, key: str) -> Path:
    if root is None:
        raise DataError(f"configuration '{cid}': data.{key} = '{name}' but the project has no "
                        "data_dir; set data_dir in the config or pass --data-dir")
    path = root / name
    if not path.is_file():
        raise DataError(f"{path}: data file of configuration '{cid}' (data.{key}) not found; "
                        "fix the path in the config or pass --data-dir")
    return path


def _read(path: Path, data: DataSpec, quantity: str) -> Curve:
    unit = data.force_unit if quantity == "force" else data.displacement_unit
    if data.format == "moldflow":
        return read_moldflow(path, quantity, unit=unit)
    default = "force_kN" if quantity == "force" else "displacement_mm"
    column = (data.force_column if quantity == "force" else data.displacement_column) or default
    return read_csv(path, column, quantity, time_column=data.time_column or "time_s", unit=unit)


def _from_press(path: Path, data: DataSpec, pre: PreprocessSpec, limit_kN: float,
                steps: list[str]) -> tuple[Curve, Curve]:
    """Closing force and hold from one press recording (contact and split always applied)."""
    rec = read_press(path, data.force_column, data.displacement_column, data.force_unit,
                     data.displacement_unit)
    steps.append(f"read {path} (press export, {rec.force.size} rows)")
    force, travel = rec.force, rec.position
    if pre.trim_idle:
        start, end, text = pp.trim_idle(force, pre.contact_threshold_kN)
        force, travel = pp.cut(force, start, end), pp.cut(travel, start, end)
        steps.append(text)
    force, tc, text = pp.zero_at_contact(force, pre.contact_threshold_kN)
    travel = pp.shift(travel, tc)
    steps.append(text)
    ts, text = pp.split_at_limit(force, limit_kN)
    steps.append(text)
    hold, text = pp.hold_from_travel(travel, ts)
    steps.append(text)
    return pp.cut(force, end_s=ts), hold


def _from_files(root: Path | None, spec: ConfigurationSpec, pre: PreprocessSpec,
                steps: list[str]) -> tuple[Curve | None, Curve | None]:
    """Closing force and hold from separate CSV / Moldflow files."""
    data, cid, limit = spec.data, spec.id, spec.press.force_limit_kN
    force = hold = travel = None
    if data.force:
        force = _read(_path(root, data.force, cid, "force"), data, "force")
        steps.append(f"read {force.source} ({data.format}, {force.name}, {force.size} rows)")
    if data.hold:
        hold = _read(_path(root, data.hold, cid, "hold"), data, "displacement")
        steps.append(f"read {hold.source} ({data.format}, hold {hold.name}, {hold.size} rows)")
    elif data.displacement:
        travel = _read(_path(root, data.displacement, cid, "displacement"), data, "displacement")
        steps.append(f"read {travel.source} ({data.format}, ram travel, {travel.size} rows)")
    if force is None:
        return None, hold
    peak = float(np.max(force.values))
    if peak > UNIT_FACTOR_LIMIT * limit:
        return force, hold  # reported by the unit check, before any step that uses levels
    if pre.trim_idle:
        start, end, text = pp.trim_idle(force, pre.contact_threshold_kN)
        force = pp.cut(force, start, end)
        steps.append(text)
    tc = 0.0
    if pre.zero_at_contact:
        force, tc, text = pp.zero_at_contact(force, pre.contact_threshold_kN)
        steps.append(text)
    ts = pp.crossing_time(force, pp.LIMIT_FRACTION * limit)
    if ts is not None and force.end_s - ts > HOLD_MIN_S:
        steps.append(pp.split_at_limit(force, limit)[1])
        if travel is not None and hold is None:
            hold, text = pp.hold_from_travel(pp.shift(travel, tc), ts)
            steps.append(text)
        force = pp.cut(force, end_s=ts)
    elif travel is not None:
        raise DataError(f"{travel.source}: cannot place the hold: the force curve of '{cid}' does not "
                        "run past the force limit; give data.hold instead of data.displacement")
    return force, hold


def _optional_steps(m_force: Curve | None, m_hold: Curve | None, pre: PreprocessSpec,
                    limit: float, flow_stop: float | None,
                    steps: list[str]) -> tuple[Curve | None, Curve | None]:
    curves = [m_force, m_hold]
    for i, c in enumerate(curves):
        if c is None:
            continue
        if pre.smooth_window_s is not None:
            c, text = pp.savgol(c, pre.smooth_window_s, pre.smooth_order)
            steps.append(text)
        if pre.resample_dt_s is not None:
            c, text = pp.resample(c, pre.resample_dt_s)
            steps.append(text)
        curves[i] = c
    force = curves[0]
    if force is not None and pre.clip == "flow_stop" and flow_stop is not None:
        force, text = pp.clip_flow_stop(force, flow_stop)
        steps.append(text)
    elif force is not None and pre.clip == "force_limit":
        force, text = pp.clip_force_limit(force, limit)
        steps.append(text)
    return force, curves[1]


def load_measurement(spec: ConfigurationSpec, root: Path | None, pre: PreprocessSpec,
                     base_dir: Path) -> Measurement:
    """Read and pre-process the data files of one configuration (which must have some)."""
    steps: list[str] = []
    limit = spec.press.force_limit_kN
    if spec.data.format == "press":
        if not spec.data.force:
            raise DataError(f"configuration '{spec.id}': a press export is given as data.force")
        force, hold = _from_press(_path(root, spec.data.force, spec.id, "force"), spec.data, pre,
                                  limit, steps)
    else:
        force, hold = _from_files(root, spec, pre, steps)
    flow_stop = flow_stop_time_s(spec, base_dir)
    speed = spec.press.speed_mm_s
    m = Measurement(spec.id, spec.role, force, hold, steps, limit, flow_stop, speed)
    _check_units(m, spec.charge.stack_height_mm)
    end_stack = end_stack_height_mm(spec, force, hold, steps)
    force, hold = _optional_steps(force, hold, pre, limit, flow_stop, steps)
    return Measurement(spec.id, spec.role, force, hold, steps, limit, flow_stop, speed, end_stack)


def load_dataset(project: ProjectConfig, ids: Sequence[str] | None = None,
                 preprocess: PreprocessSpec | None = None) -> Dataset:
    """Read the measured curves of a project.

    Args:
        project: the validated project (its ``data_dir`` locates the files).
        ids: configurations to read (default: all that list data files).
        preprocess: pre-processing options (default: the project's ``[preprocess]``).

    Returns:
        The dataset; configurations without data files have no measurement.

    Raises:
        DataError: a listed file is missing or bad (one line: file, row/column, fix).
    """
    pre = project.preprocess if preprocess is None else preprocess
    root = project.data_path()
    wanted = [c.id for c in project.configuration] if ids is None else list(ids)
    out: dict[str, Measurement] = {}
    for cid in wanted:
        spec = project.get(cid)
        d = spec.data
        if d is None or not (d.force or d.hold or d.displacement):
            continue
        out[cid] = load_measurement(spec, root, pre, Path(project.base_dir))
    return Dataset(project, out, pre)


def measured_force(project: ProjectConfig, ids: Sequence[str]) -> dict[str, tuple[Array, Array]]:
    """Measured force curves ``(time_s, force_kN)`` of those of ``ids`` that have them.

    Read through :func:`load_dataset` (formats, units, the project's pre-processing);
    empty when the project's data folder does not exist.
    """
    root = project.data_path()
    if root is None or not root.is_dir():
        return {}
    dataset = load_dataset(project, ids)
    return {cid: (m.force.time_s, m.force.values) for cid, m in dataset.measurements.items()
            if m.force is not None}
