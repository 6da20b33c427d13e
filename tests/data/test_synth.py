"""``smcbayes synth``: data at known truth read like real data; the loss gives the noise back."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from smcbayes.cli import main
from smcbayes.config import load_project
from smcbayes.data.dataset import Dataset, load_dataset
from smcbayes.data.loss import LossSpec, evaluate_loss
from smcbayes.data.synth import ou_noise
from smcbayes.forward.model import ForwardModel

TRUTH = {"n": 0.35, "tau_c_MPa": 0.08}


def _synth(dh, out: Path, *extra: str) -> Dataset:
    args = ["synth", str(dh.THESIS_TOML), "--truth", "n=0.35", "--truth", "tau_c_MPa=0.08",
            "--seed", "11", "--out", str(out), *extra]
    assert main(args) == 0
    return load_dataset(load_project(out / "project.toml"))


def _loss_at(ds: Dataset, values: dict[str, float]) -> float:
    model = ForwardModel(ds.project, overrides=values)
    return float(evaluate_loss(model.simulate(None, ds.ids("train")), ds).total[0])


def _interpolated_variance(ds: Dataset, white: float, corr: float, tau_s: float) -> float:
    """Expected mean square of the noise after linear interpolation onto the loss grid.

    A grid point between samples i, i+1 at weight w carries w x_i + (1 - w) x_{i+1}; its
    variance is white^2 (w^2 + (1-w)^2) + corr^2 (w^2 + (1-w)^2 + 2 w (1-w) phi_i).
    """
    spec = LossSpec()
    out = []
    for cid in ds.ids("train"):
        tm = ds[cid].force.time_s
        # at the truth the simulated switch time equals the last measured sample time
        grid = np.linspace(0.0, tm[-1], spec.grid_points)
        j = np.clip(np.searchsorted(tm, grid, side="right") - 1, 0, tm.size - 2)
        w = (tm[j + 1] - grid) / (tm[j + 1] - tm[j])
        phi = np.exp(-(tm[j + 1] - tm[j]) / tau_s)
        base = w**2 + (1 - w) ** 2
        out.append(np.mean(white**2 * base + corr**2 * (base + 2 * w * (1 - w) * phi)))
    return float(np.mean(out))


def test_synth_loss_at_truth_gives_the_noise_back(tmp_path: Path, dh) -> None:
    clean = _synth(dh, tmp_path / "clean")
    floor = _loss_at(clean, TRUTH)  # resolution floor: steep curve ends sampled at 0.02 s
    noisy = _synth(dh, tmp_path / "noisy", "--noise-kN", "20", "--correlated-kN", "10",
                   "--correlation-s", "0.2")
    expected = floor + _interpolated_variance(noisy, 20.0, 10.0, 0.2)
    at_truth = _loss_at(noisy, TRUTH)
    assert floor < 0.1 * expected
    assert at_truth == pytest.approx(expected, rel=0.1)
    # the flow force of this base model rises with the Cross stress tau* and B
    perturbed = _loss_at(noisy, {**TRUTH, "B_Pa_s": 3e4, "tau_star_Pa": 3e4})
    print(f"floor {floor:.1f}, expected {expected:.1f}, truth {at_truth:.1f}, perturbed {perturbed:.1f}")
    assert perturbed > 1.5 * at_truth
    info = json.loads((tmp_path / "noisy" / "truth.json").read_text())
    assert info["truth"] == TRUTH and info["seed"] == 11 and info["noise"]["white_kN"] == 20.0
    assert info["parameters"]["n"] == 0.35 and info["parameters"]["m"] == 1.5


def test_synth_is_reproducible_and_reads_like_real_data(tmp_path: Path, dh) -> None:
    a = _synth(dh, tmp_path / "a", "--noise-kN", "5", "--resolution-s", "0.018", "--resolution-kN", "3")
    _synth(dh, tmp_path / "b", "--noise-kN", "5", "--resolution-s", "0.018", "--resolution-kN", "3")
    for sub in ("force/60-bar-03.csv", "hold/80-center-11.csv", "project.toml"):
        assert (tmp_path / "a" / sub).read_bytes() == (tmp_path / "b" / sub).read_bytes()
    source = load_project(dh.THESIS_TOML)
    assert a.ids("train") == [c.id for c in source.configuration if c.role == "train"]
    assert len(a.ids("validation")) == 3
    f = a["60-bar-03"].force
    np.testing.assert_allclose(np.round(f.values / 3.0) * 3.0, f.values, atol=1e-6)
    steps = np.diff(f.time_s) / 0.018
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    assert (tmp_path / "a" / "project.toml").read_text().count("[[configuration]]") == 12


def test_effects_pass_through(tmp_path: Path, dh) -> None:
    ds = _synth(dh, tmp_path / "e", "--effect", "compressibility")
    info = json.loads((tmp_path / "e" / "truth.json").read_text())
    assert info["effects"] == ["compressibility"]
    base = _synth(dh, tmp_path / "b")
    # a compressible charge reaches the force limit later than the incompressible one
    assert ds["60-bar-03"].force.end_s > base["60-bar-03"].force.end_s + 1.0
    # each synthetic part is its own simulated end gap (the source's measured parts are
    # dropped), so its end state gives back the 8 mm stack
    text = (tmp_path / "e" / "project.toml").read_text()
    assert text.count("part = { thickness_mm") == 12 and "mass_g = 360" not in text
    for cid in ds.ids("train"):
        assert ds[cid].end_stack_mm == pytest.approx(8.0, abs=0.01)


def test_ou_noise_statistics() -> None:
    t = np.arange(0.0, 2000.0, 0.05)
    x = ou_noise(t, 3.0, 0.5, np.random.default_rng(5))
    assert np.std(x) == pytest.approx(3.0, rel=0.1)
    lag = int(0.5 / 0.05)
    r = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert r == pytest.approx(np.exp(-1.0), abs=0.05)


def test_bad_truth_exits_2(tmp_path: Path, dh, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["synth", str(dh.THESIS_TOML), "--truth", "nn=0.3", "--seed", "1", "--out", str(tmp_path)]
    assert main(args) == 2
    assert "nn" in capsys.readouterr().err
    args = ["synth", str(dh.THESIS_TOML), "--noise-kN", "-1", "--seed", "1", "--out", str(tmp_path)]
    assert main(args) == 2
