"""Moldflow XML result files (``<MoldflowXMLDocument>``), e.g. an exported XY plot.

A document holds one or more ``<Dataset>`` elements.  Each has a description (``Name``,
the independent variable ``IndpVar`` and dependent variable ``DeptVar`` with their
``Unit``) and ``<Block>`` elements, one per time step: ``<IndpVar Value="t"/>`` and the
value(s) in ``<DeptValues>`` (the first number is taken).  Units are read from the
description (``Unit`` child or attribute) unless given explicitly.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from smcbayes.data.curve import Curve, check_samples, unit_factor
from smcbayes.errors import DataError

_KEYWORDS = {"force": ("force", "clamp"), "displacement": ("displacement", "position", "stroke")}


def _unit(desc: ET.Element | None, tag: str) -> str | None:
    if desc is None:
        return None
    for el in desc.iter(tag):
        if el.get("Value") is not None:
            continue
        unit = el.get("Unit") or el.findtext("Unit")
        if unit:
            return unit.strip()
    return None


def _datasets(root: ET.Element) -> list[ET.Element]:
    sets = list(root.iter("Dataset"))
    return sets or [root]


def _pick(path: Path, sets: list[ET.Element], quantity: str, name: str | None) -> ET.Element:
    names = [(s.findtext(".//Name") or "").strip() for s in sets]
    if name is not None:
        hits = [s for s, n in zip(sets, names, strict=False) if name.lower() in n.lower()]
    elif len(sets) == 1:
        return sets[0]
    else:
        hits = [s for s, n in zip(sets, names, strict=False)
                if any(k in n.lower() for k in _KEYWORDS[quantity])]
    if len(hits) != 1:
        raise DataError(f"{path}: {len(hits)} datasets match {quantity} {name or ''}; datasets: "
                        f"{', '.join(repr(n) for n in names)}; give the dataset name in the config")
    return hits[0]


def read_moldflow(path: str | Path, quantity: str, unit: str | None = None,
                  time_unit: str | None = None, dataset: str | None = None) -> Curve:
    """Read one curve of a Moldflow XML result file.

    Args:
        path: the XML file.
        quantity: ``force`` or ``displacement`` (decides the edge unit, kN or mm).
        unit: unit of the values (e.g. ``N``, ``tonne``, ``m``); default: the file's.
        time_unit: unit of ``IndpVar``; default: the file's, else s.
        dataset: part of the dataset name to pick when the file holds several.

    Raises:
        DataError: one line naming the file, the block or element, and the fix.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file not found; check the path, data_dir or --data-dir")
    if path.stat().st_size == 0:
        raise DataError(f"{path}: file is empty; expected a Moldflow XML result file")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as err:
        raise DataError(f"{path}: not well-formed XML ({err}); export the result again") from None
    if root.tag != "MoldflowXMLDocument":
        raise DataError(f"{path}: root element is <{root.tag}>, expected <MoldflowXMLDocument>")
    ds = _pick(path, _datasets(root), quantity, dataset)
    blocks = list(ds.iter("Block"))
    t, v = np.empty(len(blocks)), np.empty(len(blocks))
    for i, block in enumerate(blocks):
        where = f"{path}: block {i + 1}"
        indp = block.find("IndpVar")
        dept = block.find(".//DeptValues")
        if indp is None or indp.get("Value") is None:
            raise DataError(f"{where}: missing <IndpVar Value=...> (time); the export is incomplete")
        if dept is None or not (dept.text or "").split():
            raise DataError(f"{where}: missing <DeptValues>; the export is incomplete")
        cells = ((indp.get("Value"), "IndpVar"), (dept.text.split()[0], "DeptValues"))
        for j, (text, label) in enumerate(cells):
            try:
                (t, v)[j][i] = float(text)
            except ValueError:
                raise DataError(f"{where}, <{label}>: {text!r} is not a number") from None
    check_samples(path, t, v, [i + 1 for i in range(len(blocks))], "block IndpVar", "block DeptValues")
    desc = ds.find("DataDescription")
    desc = ds if desc is None else desc
    vunit = unit or _unit(desc, "DeptVar")
    if vunit is None:
        raise DataError(f"{path}: no unit of the values (<DeptVar><Unit>); set data.force_unit "
                        "or data.displacement_unit")
    tunit = time_unit or _unit(desc, "IndpVar") or "s"
    vf = unit_factor(vunit, quantity, f"{path}: <DeptVar>")
    tf = unit_factor(tunit, "time", f"{path}: <IndpVar>")
    return Curve(t * tf, v * vf, quantity, "kN" if quantity == "force" else "mm", path)


def write_moldflow(path: str | Path, name: str, time_s: np.ndarray, values: np.ndarray,
                   unit: str, dept_name: str) -> None:
    """Write a one-dataset Moldflow XML result file (for tests and examples)."""
    blocks = "\n".join(
        f'      <Block><IndpVar Value="{t:.9E}"/><Data><NodeData ID="1">'
        f"<DeptValues>{v:.9E}</DeptValues></NodeData></Data></Block>"
        for t, v in zip(time_s, values, strict=False))
    text = (f'<?xml version="1.0" encoding="UTF-8"?>\n<MoldflowXMLDocument version="1.0">\n'
            f"  <Dataset>\n    <DataDescription>\n      <Name>{name}</Name>\n"
            f"      <IndpVar><Name>Time</Name><Unit>s</Unit></IndpVar>\n"
            f"      <DeptVar><Name>{dept_name}</Name><Unit>{unit}</Unit></DeptVar>\n"
            f"    </DataDescription>\n    <Blocks>\n{blocks}\n    </Blocks>\n  </Dataset>\n"
            f"</MoldflowXMLDocument>\n")
    Path(path).write_text(text, encoding="utf-8")
