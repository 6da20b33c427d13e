"""``smcbayes evaluate``: per-configuration RMSE table and global loss."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from smcbayes.cli import main
from smcbayes.config import load_project
from smcbayes.data.dataset import load_dataset
from smcbayes.data.loss import evaluate_loss
from smcbayes.forward.model import ForwardModel

REPO = Path(__file__).resolve().parents[2]
REAL_DATA = REPO / ".." / "shared" / "data" / "thesis-press"
THESIS_TOML = REPO / "configs" / "thesis.toml"


def _rows(out: str) -> dict[str, list[str]]:
    return {line.split()[0]: line.split()[1:] for line in out.splitlines()
            if re.match(r"^\d\d-(bar|center)-\d\d ", line)}


def _global(out: str) -> tuple[float, float]:
    """Full and clipped global loss (kN^2) of the last line."""
    m = re.search(r"full (\S+) kN\^2 .*clipped at flow stop \(thesis\) (\S+) kN\^2", out)
    assert m is not None, out
    return float(m.group(1)), float(m.group(2))


def _force_mse(t: np.ndarray, f: np.ndarray, t_switch: float, tm: np.ndarray, fm: np.ndarray,
               end: float, points: int) -> float:
    """e^F written out from its definition: both curves on a uniform grid of [0, end], the
    simulation held at its value at the switch, the measurement at its last sample."""
    grid = np.linspace(0.0, end, points)
    sim = np.interp(np.minimum(grid, t_switch), t, f)
    return float(np.mean((sim - np.interp(grid, tm, fm)) ** 2))


def test_evaluate_real_data_at_the_default_point(capsys: pytest.CaptureFixture[str]) -> None:
    """Every printed RMSE (full and clipped at flow stop) and both global losses are those of
    the loss module on the same simulations."""
    if not REAL_DATA.is_dir():
        pytest.skip("thesis-press data folder not present")
    assert main(["evaluate", str(THESIS_TOML)]) == 0
    out = capsys.readouterr().out
    rows = _rows(out)
    assert len(rows) == 9 and "80-center-03" not in rows
    assert "global loss L" in out and "clipped at flow stop" in out

    project = load_project(THESIS_TOML)
    dataset = load_dataset(project)
    ids = dataset.ids("train")
    results = ForwardModel(project).simulate(None, ids)
    full = evaluate_loss(results, dataset, project.loss, ids)
    clipped = evaluate_loss(results, dataset, project.loss.model_copy(update={"clip": "flow_stop"}), ids)
    assert sorted(rows) == sorted(ids)
    for k, cid in enumerate(full.ids):
        assert float(rows[cid][0]) == pytest.approx(np.sqrt(full.force_mse_kN2[0, k]), abs=0.006)
        assert float(rows[cid][1]) == pytest.approx(np.sqrt(clipped.force_mse_kN2[0, k]), abs=0.006)
        assert float(rows[cid][2]) == pytest.approx(np.sqrt(full.displacement_mse_mm2[0, k]), abs=0.006)
    # the flow-stop window is shorter and leaves out the force-limit jump, so it differs
    assert np.all(clipped.force_mse_kN2 < full.force_mse_kN2)
    total, total_clipped = _global(out)
    assert total == pytest.approx(full.total[0], rel=1e-5)
    assert total_clipped == pytest.approx(clipped.total[0], rel=1e-5)


def test_evaluate_is_zero_on_the_model_own_curves_and_matches_the_definition(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Measured curves that are the simulation itself (up to its switch to force control)
    give a zero loss at that point; at another point the printed RMSE and losses are those
    of the loss definition written out here."""
    ids = ["60-bar-03", "80-center-07"]
    assert main(["synth", str(THESIS_TOML), "--truth", "n=0.3", "--noise-kN", "0", "--seed", "2",
                 "--only", *ids, "--out", str(tmp_path)]) == 0
    toml = tmp_path / "project.toml"
    # the definition written out below is the nominal contact's (no offset of a trial's own)
    text = re.sub(r'contact = "[a-z_]+"', 'contact = "nominal"', toml.read_text(encoding="utf-8"))
    text = re.sub(r"contact_offset_mm = [0-9.]+", "contact_offset_mm = 0.0", text)
    toml.write_text(text, encoding="utf-8")
    project = load_project(toml)
    assert project.loss.contact_mode == "nominal"
    truth = ForwardModel(project, overrides={"n": 0.3}).simulate(None, ids)
    for cid, res in truth.items():
        keep = res.time_s[0] <= res.switch_time_s[0]
        np.savetxt(tmp_path / "force" / f"{cid}.csv",
                   np.column_stack([res.time_s[0, keep], res.force_kN[0, keep]]),
                   delimiter=",", header="time_s,force_kN", comments="")
    capsys.readouterr()
    assert main(["evaluate", str(toml), "--set", "n=0.3", "--role", "all"]) == 0
    out = capsys.readouterr().out
    rows = _rows(out)
    assert sorted(rows) == sorted(ids)
    for cells in rows.values():
        assert float(cells[0]) == 0.0 and float(cells[1]) == 0.0 and float(cells[2]) == 0.0
    assert max(_global(out)) < 1e-20

    assert main(["evaluate", str(toml), "--set", "n=0.35", "--role", "all"]) == 0
    out = capsys.readouterr().out
    rows = _rows(out)
    dataset = load_dataset(project)
    other = ForwardModel(project, overrides={"n": 0.35}).simulate(None, ids)
    points = project.loss.grid_points
    full, clipped = [], []
    for cid in ids:
        r, m = other[cid], dataset[cid]
        t, f, ts = r.time_s[0], r.force_kN[0], float(r.switch_time_s[0])
        tm, fm = m.force.time_s, m.force.values
        full.append(_force_mse(t, f, ts, tm, fm, max(ts, tm[-1]), points))
        clipped.append(_force_mse(t, f, ts, tm, fm, m.flow_stop_s, points))
        assert float(rows[cid][0]) == pytest.approx(np.sqrt(full[-1]), abs=0.006)
        assert float(rows[cid][1]) == pytest.approx(np.sqrt(clipped[-1]), abs=0.006)
        assert float(rows[cid][0]) > 1.0  # a real difference, not the zero of the first call
    total, total_clipped = _global(out)
    assert total == pytest.approx(np.mean(full), rel=1e-5)
    assert total_clipped == pytest.approx(np.mean(clipped), rel=1e-5)


def test_evaluate_synthetic_data_at_the_truth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["synth", str(THESIS_TOML), "--truth", "n=0.3", "--noise-kN", "10", "--seed", "2",
                 "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "project.toml"), "--set", "n=0.3"]) == 0
    rows = _rows(capsys.readouterr().out)
    assert len(rows) == 9
    for cells in rows.values():
        assert 5.0 < float(cells[0]) < 15.0  # about the 10 kN noise (interpolated, plus a floor)


def test_evaluate_without_data_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", str(THESIS_TOML), "--data-dir", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "not found" in err


def test_evaluate_with_the_contact_from_the_end_state(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """The thesis project takes each trial's contact from its end state; synthetic trials
    carry their own simulated parts, so at the truth their offsets are 0, and a trial
    without its part is averaged over the training trials' offsets instead of failing."""
    ids = ["60-bar-03", "60-center-07", "80-center-03"]
    assert main(["synth", str(THESIS_TOML), "--truth", "n=0.3", "--noise-kN", "0", "--seed", "2",
                 "--only", *ids, "--out", str(tmp_path)]) == 0
    toml = tmp_path / "project.toml"
    text = toml.read_text(encoding="utf-8")
    assert 'contact = "end_state"' in text
    head, sep, rest = text.partition('id = "80-center-03"')
    toml.write_text(head + sep + re.sub(r"\npart = \{[^}]*\}", "", rest, count=1), encoding="utf-8")
    capsys.readouterr()
    assert main(["evaluate", str(toml), "--set", "n=0.3", "--role", "all"]) == 0
    out = capsys.readouterr().out
    assert "the contact offset its end state implies ([loss] contact), within +-1 mm" in out
    assert re.search(r"60-bar-03 [+-]0\.00 mm", out) and re.search(r"60-center-07 [+-]0\.00 mm", out)
    assert re.search(r"without an end state, averaged over the training trials' offsets \(mean "
                     r"80-center-03 [+-]0\.00 mm\)", out)
    assert sorted(_rows(out)) == sorted(ids)


def test_evaluate_shows_the_offset_a_trial_beyond_the_bound_implies(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Pressed with a ram that lags by a 1 s speed ramp, evaluated without it under a
    0.05 mm bound: the trial is compared at the bound, and the line says what its end
    state implied."""
    assert main(["synth", str(THESIS_TOML), "--effect", "speed_ramp", "--truth", "ramp_time_s=1.0",
                 "--seed", "1", "--only", "60-bar-03", "--out", str(tmp_path)]) == 0
    toml = tmp_path / "project.toml"
    toml.write_text(re.sub(r"contact_offset_mm = [0-9.]+", "contact_offset_mm = 0.05",
                           toml.read_text(encoding="utf-8")), encoding="utf-8")
    capsys.readouterr()
    assert main(["evaluate", str(toml)]) == 0
    out = capsys.readouterr().out
    found = re.search(r"60-bar-03 ([+-]0\.05) mm \(on the bound; its end state implies ([+-]\d\.\d\d) mm\)",
                      out)
    assert found and abs(float(found.group(2))) > 0.05
