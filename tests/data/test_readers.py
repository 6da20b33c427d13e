"""Readers: each format round-trips its fixture, and all agree on the same data."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from smcbayes.data.readers.csv import read_csv, write_csv
from smcbayes.data.readers.moldflow import read_moldflow, write_moldflow
from smcbayes.data.readers.press import read_press, write_press

TONNE_FORCE_KN = 9.80665


def _curve() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.round(np.linspace(0.0, 6.0, 61), 6)
    f = np.round(1400.0 * (t / 6.0) ** 3, 6)
    x = np.round(120.0 - 0.7 * t, 6)
    return t, f, x


def test_csv_round_trip_and_units(tmp_path: Path) -> None:
    t, f, _ = _curve()
    write_csv(tmp_path / "a.csv", t, f, "force_kN", digits=12)
    c = read_csv(tmp_path / "a.csv", "force_kN", "force")
    np.testing.assert_allclose(c.time_s, t)
    np.testing.assert_allclose(c.values, f)
    assert (c.quantity, c.unit, c.name, c.source) == ("force", "kN", "force_kN", tmp_path / "a.csv")
    write_csv(tmp_path / "n.csv", t * 1000, f * 1000, "press_force_N", digits=12)
    text = (tmp_path / "n.csv").read_text().replace("time_s", "t_ms")
    (tmp_path / "n.csv").write_text(text)
    c = read_csv(tmp_path / "n.csv", "press_force_N", "force", time_column="t_ms")
    np.testing.assert_allclose(c.time_s, t)
    np.testing.assert_allclose(c.values, f)


def test_csv_named_columns_semicolons_and_explicit_unit(tmp_path: Path) -> None:
    p = tmp_path / "d.csv"
    p.write_text("# ram travel\nzeit;weg\n0;0\n1;0.001\n2;0.0025\n", encoding="utf-8")
    c = read_csv(p, "weg", "displacement", time_column="zeit", unit="m")
    np.testing.assert_allclose(c.values, [0.0, 1.0, 2.5])
    assert c.unit == "mm"


def test_press_export_round_trip(tmp_path: Path) -> None:
    t, f, x = _curve()
    p = tmp_path / "press.csv"
    write_press(p, datetime(2024, 5, 17, 9, 59, 59, 900000), t, f, x)
    raw = p.read_bytes()
    assert raw[:2] != b"\xff\xfe" and b";\x00" in raw  # UTF-16-LE, no BOM, ';' separated
    assert "," in raw.decode("utf-16-le").splitlines()[3]  # decimal commas
    rec = read_press(p)
    np.testing.assert_allclose(rec.force.time_s, t, atol=1e-6)
    np.testing.assert_allclose(rec.force.values, f, atol=1e-6)
    np.testing.assert_allclose(rec.position.values, x, atol=1e-6)


def test_press_export_with_bom_and_force_in_N(tmp_path: Path) -> None:
    rows = ["Zeit;dbPr\\diIstPos;dbPr\\diIstKraftGes;dbPr\\diSollPos", ";[mm];[N];mm"]
    rows += ["31.12.2023 23:59:59.500000;10,5;1000,0;0", "01.01.2024 00:00:00.250000;10,0;2500,5;0"]
    p = tmp_path / "bom.csv"
    p.write_bytes("\r\n".join(rows).encode("utf-16"))
    rec = read_press(p)
    np.testing.assert_allclose(rec.force.time_s, [0.0, 0.75])
    np.testing.assert_allclose(rec.force.values, [1.0, 2.5005])
    np.testing.assert_allclose(rec.position.values, [10.5, 10.0])


def test_moldflow_round_trip_in_N_and_tonne_force(tmp_path: Path) -> None:
    t, f, x = _curve()
    write_moldflow(tmp_path / "f.xml", "Press force:XY Plot", t, f * 1000.0, "N", "Press force")
    c = read_moldflow(tmp_path / "f.xml", "force")
    np.testing.assert_allclose(c.time_s, t)
    np.testing.assert_allclose(c.values, f, rtol=1e-9)
    write_moldflow(tmp_path / "t.xml", "Clamp force:XY Plot", t, f / TONNE_FORCE_KN, "tonne", "Clamp force")
    np.testing.assert_allclose(read_moldflow(tmp_path / "t.xml", "force").values, f, rtol=1e-9)
    write_moldflow(tmp_path / "d.xml", "Press displacement:XY Plot", t, x / 1000.0, "m", "Press displacement")
    np.testing.assert_allclose(read_moldflow(tmp_path / "d.xml", "displacement").values, x, rtol=1e-9)


def test_moldflow_picks_dataset_by_quantity(tmp_path: Path) -> None:
    t, f, x = _curve()
    write_moldflow(tmp_path / "f.xml", "Press force:XY Plot", t, f, "kN", "Press force")
    write_moldflow(tmp_path / "d.xml", "Press displacement:XY Plot", t, x, "mm", "Press displacement")
    body_f = (tmp_path / "f.xml").read_text().split("<Dataset>")[1].split("</Dataset>")[0]
    both = (tmp_path / "d.xml").read_text().replace("</Dataset>",
                                                    f"</Dataset>\n  <Dataset>{body_f}</Dataset>")
    (tmp_path / "both.xml").write_text(both)
    np.testing.assert_allclose(read_moldflow(tmp_path / "both.xml", "force").values, f)
    np.testing.assert_allclose(read_moldflow(tmp_path / "both.xml", "displacement").values, x)


def test_all_readers_give_the_same_curve(tmp_path: Path) -> None:
    t, f, x = _curve()
    write_csv(tmp_path / "f.csv", t, f, "force_kN", digits=12)
    write_press(tmp_path / "p.csv", datetime(2024, 1, 1, 12), t, f, x)
    write_moldflow(tmp_path / "m.xml", "Press force", t, f / TONNE_FORCE_KN, "tonne-force", "Press force")
    a = read_csv(tmp_path / "f.csv", "force_kN", "force")
    b = read_press(tmp_path / "p.csv").force
    c = read_moldflow(tmp_path / "m.xml", "force")
    for other in (b, c):
        np.testing.assert_allclose(other.time_s, a.time_s, atol=1e-6)
        np.testing.assert_allclose(other.values, a.values, atol=1e-5)
        assert (other.quantity, other.unit) == (a.quantity, a.unit)


@pytest.mark.parametrize("unit,factor", [("kN", 1.0), ("MN", 1000.0), ("lbf", 4.4482216152605e-3)])
def test_force_unit_table(tmp_path: Path, unit: str, factor: float) -> None:
    write_csv(tmp_path / "u.csv", np.array([0.0, 1.0]), np.array([1.0, 2.0]), f"force_{unit}")
    c = read_csv(tmp_path / "u.csv", f"force_{unit}", "force")
    np.testing.assert_allclose(c.values, np.array([1.0, 2.0]) * factor)
