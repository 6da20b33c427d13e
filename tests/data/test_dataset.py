"""Datasets: every format through load_dataset, pre-processing steps recorded, real data."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import load_project
from smcbayes.config.specs import PreprocessSpec
from smcbayes.data import preprocess as pp
from smcbayes.data.curve import Curve
from smcbayes.data.dataset import load_dataset
from smcbayes.data.readers.csv import write_csv
from smcbayes.data.readers.moldflow import write_moldflow
from smcbayes.data.readers.press import write_press

LIMIT = 300.0


def _recording() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A whole press cycle: idle, closing at 1 mm/s, 20 s hold at the limit, opening."""
    t = np.arange(0.0, 32.0, 0.05)
    closing = np.clip(t - 2.0, 0.0, 6.0) / 6.0
    force = np.where(t < 2.0, 0.2, 0.2 + (LIMIT - 0.2) * closing**3)
    force = np.where(t > 28.0, 0.1, force)
    pos = 100.0 - np.clip(t - 2.0, 0.0, 6.0) - 0.005 * np.clip(t - 8.0, 0.0, 20.0)
    return t, force, pos


def test_press_export_dataset_splits_closing_and_hold(tmp_path: Path, dh) -> None:
    t, f, x = _recording()
    write_press(tmp_path / "run1.csv", datetime(2024, 2, 2, 8), t, f, x)
    proj = dh.project(tmp_path, [dh.config(data={"force": "run1.csv", "format": "press"},
                                           force_limit_kN=LIMIT)],
                      preprocess={"trim_idle": True})
    m = load_dataset(proj)["c1"]
    contact = 2.0 + 6.0 * ((2.0 - 0.2) / (LIMIT - 0.2)) ** (1 / 3)
    assert m.force.time_s[0] == 0.0 and m.force.values[0] == pytest.approx(2.0)
    t_split = 2.0 + 6.0 * ((0.98 * LIMIT - 0.2) / (LIMIT - 0.2)) ** (1 / 3)
    assert m.force.end_s == pytest.approx(t_split - contact, abs=0.01)
    assert m.force.values[-1] == pytest.approx(0.98 * LIMIT, rel=0.01)
    assert m.hold.values[0] == 0.0 and m.hold.time_s[0] == 0.0
    assert m.hold.end_s == pytest.approx(28.0 - t_split, abs=0.06)
    assert m.hold.values[-1] == pytest.approx(-0.1 - (8.0 - t_split), abs=0.01)  # closing negative
    assert len(m.steps) == 5 and "trim idle" in m.steps[1] and "first contact" in m.steps[2]


def test_csv_and_moldflow_datasets_agree(tmp_path: Path, dh) -> None:
    t = np.linspace(0.0, 6.0, 121)
    f = LIMIT * (t / 6.0) ** 2
    write_csv(tmp_path / "f.csv", t, f, "force_kN", digits=12)
    write_csv(tmp_path / "h.csv", t + 1.0, -0.01 * t, "displacement_mm", digits=12)
    write_moldflow(tmp_path / "f.xml", "Press force", t, f * 1e3, "N", "Press force")
    write_moldflow(tmp_path / "h.xml", "Press displacement", t + 1.0, -1e-5 * t, "m", "Press displacement")
    proj = dh.project(tmp_path, [
        dh.config("a", {"force": "f.csv", "hold": "h.csv"}, force_limit_kN=LIMIT),
        dh.config("b", {"force": "f.xml", "hold": "h.xml", "format": "moldflow"}, force_limit_kN=LIMIT),
        dh.config("v", role="validation")])
    ds = load_dataset(proj)
    assert ds.ids() == ["a", "b"] and ds.ids("validation") == [] and ds.ids("train") == ["a", "b"]
    for name in ("force", "hold"):
        ca, cb = getattr(ds["a"], name), getattr(ds["b"], name)
        np.testing.assert_allclose(cb.time_s, ca.time_s, atol=1e-9)
        np.testing.assert_allclose(cb.values, ca.values, rtol=1e-8, atol=1e-12)


def test_full_ram_displacement_gives_the_hold(tmp_path: Path, dh) -> None:
    t, f, x = _recording()
    keep = t < 28.0
    write_csv(tmp_path / "f.csv", t[keep], f[keep], "force_kN", digits=12)
    write_csv(tmp_path / "x.csv", t[keep], x[keep], "position_mm", digits=12)
    data = {"force": "f.csv", "displacement": "x.csv", "displacement_column": "position_mm"}
    proj = dh.project(tmp_path, [dh.config(data=data, force_limit_kN=LIMIT)],
                      preprocess={"zero_at_contact": True})
    m = load_dataset(proj)["c1"]
    assert m.force.values[-1] == pytest.approx(0.98 * LIMIT, rel=0.01)
    t_split = 2.0 + 6.0 * ((0.98 * LIMIT - 0.2) / (LIMIT - 0.2)) ** (1 / 3)
    assert m.hold.values[-1] == pytest.approx(-0.1 - (8.0 - t_split), abs=0.005)
    assert m.hold.values[0] == 0.0
    assert any("split closing" in s for s in m.steps)


def test_preprocess_steps(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 10, 400))
    c = Curve(t, 100 * t + rng.normal(0, 5, t.size), "force", "kN", tmp_path / "x.csv")
    s, text = pp.savgol(c, 1.0, 2)
    assert "Savitzky-Golay" in text and np.std(s.values - 100 * s.time_s) < 2.5
    r, text = pp.resample(c, 0.5)
    np.testing.assert_allclose(np.diff(r.time_s), 0.5)
    clipped, text = pp.clip_flow_stop(c, 4.0)
    assert clipped.end_s == 4.0 and "4.0000 s" in text
    clipped, _ = pp.clip_force_limit(Curve(t, 100 * t, "force", "kN", c.source), 500.0)
    assert clipped.end_s == pytest.approx(5.0) and clipped.values[-1] == pytest.approx(500.0)
    assert pp.flow_stop_time(8.0, 0.6, 0.3) == pytest.approx(3.2 / 0.3)


def test_preprocess_options_are_recorded(tmp_path: Path, dh) -> None:
    t = np.linspace(0.0, 6.0, 301)
    write_csv(tmp_path / "f.csv", t, 0.5 + LIMIT * (t / 6.0) ** 2, "force_kN", digits=12)
    proj = dh.project(tmp_path, [dh.config(data={"force": "f.csv"}, force_limit_kN=LIMIT)])
    spec = PreprocessSpec(zero_at_contact=True, contact_threshold_kN=3.0, smooth_window_s=0.2,
                          resample_dt_s=0.05, clip="flow_stop")
    m = load_dataset(proj, preprocess=spec)["c1"]
    words = ["read", "first contact", "Savitzky-Golay", "resampled", "flow-stop"]
    assert [w in s for w, s in zip(words, m.steps, strict=False)] == [True] * 5
    assert m.force.end_s == pytest.approx(m.flow_stop_s) and m.flow_stop_s == pytest.approx(1.0)


def test_real_thesis_data_loads(dh) -> None:
    if not dh.REAL_DATA.is_dir():
        pytest.skip("thesis-press data folder not present")
    proj = load_project(dh.THESIS_TOML)
    ds = load_dataset(proj)
    assert len(ds.ids("train")) == 9 and ds.ids("validation") == []
    for m in ds.measurements.values():
        assert m.force.time_s[0] == 0.0 and 1300 < m.force.values[-1] < 1450
        assert m.hold.end_s > 370 and m.hold.values[-1] < -0.1
    # 60 % coverage, 8 mm stack: h_flow = 4.8 mm, 3.2 mm of travel at 0.3 mm/s
    assert ds["60-bar-03"].flow_stop_s == pytest.approx(3.2 / 0.3)
