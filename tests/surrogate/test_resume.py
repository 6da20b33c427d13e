"""End-to-end `smcbayes calibrate` on the 2-D slip check: outputs, SIGKILL + --resume, errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from smcbayes.cli import main
from smcbayes.surrogate.gp import load_surrogate

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "verify-slip-2d.toml"
ARGS = ["--budget", "10", "--init", "5", "--seed", "3", "--polish", "20"]
TOTAL = 30  # 10 of the optimisation, 20 of the local search


def cli(out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "smcbayes.cli", "calibrate", str(CONFIG), "--out", str(out), *ARGS, *extra]


def evaluations(run: Path) -> list[dict]:
    lines = (run / "evaluations.jsonl").read_text().splitlines()
    return [json.loads(x) for x in lines if '"evaluation"' in x]


def strip(recs: list[dict]) -> list[dict]:
    return sorted(({k: v for k, v in r.items() if k != "seconds"} for r in recs), key=lambda r: r["index"])


@pytest.fixture(scope="module")
def full_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("full") / "run"
    assert main(["calibrate", str(CONFIG), "--out", str(out), *ARGS]) == 0
    return out


def test_run_directory_contents(full_run: Path) -> None:
    summary = json.loads((full_run / "summary.json").read_text())
    assert summary["evaluations"] == TOTAL and summary["failures"] == 0
    assert summary["polish"]["evaluations"] == 20 and summary["settings"]["polish"] == 20
    assert summary["stop_reason"].startswith("budget")
    assert summary["free_parameters"] == ["tau_c_MPa", "m"]
    best = json.loads((full_run / "best_params.json").read_text())
    assert best["tau_c_MPa"]["unit"] == "MPa" and best["n"]["fixed"] is True
    assert summary["best_loss_kN2"] == min(r["loss"] for r in evaluations(full_run))
    for name in ("convergence", "best_curves", "landscape"):
        assert (full_run / "figures" / f"{name}.png").is_file()
        assert (full_run / "figures" / f"{name}.svg").is_file()
    assert len(list((full_run / "best_curves").glob("*.csv"))) == 5
    surrogate, meta = load_surrogate(full_run / "gp.pt")
    assert meta["free_parameters"] == ["tau_c_MPa", "m"]
    # the rebuilt GP carries the saved hyperparameters, not freshly initialised ones
    saved = torch.load(full_run / "gp.pt", weights_only=False)["state_dict"]
    rebuilt = surrogate.model.state_dict()
    for key, value in saved.items():
        assert torch.equal(rebuilt[key], value), key
    # with the small fixed noise it interpolates its training data (targets are log losses):
    # mean on the targets, standard deviation near zero there ...
    mean, std = surrogate.predict(surrogate.x_unit)
    y_sd = float(np.std(surrogate.log_loss, ddof=1))
    np.testing.assert_allclose(mean, surrogate.log_loss, atol=1e-3 * y_sd)
    assert np.all(std < 1e-2 * y_sd)
    # ... and away from them a standard deviation (not a variance) that grows with the
    # distance but never exceeds the prior's, the standardised targets' sd
    _, std_far = surrogate.predict(np.random.default_rng(0).random((200, 2)))
    assert np.median(std_far) > 10 * std.max()
    assert np.all(std_far <= y_sd * (1 + 1e-6))


def test_sigkill_then_resume_equals_uninterrupted(full_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cli(out, "--no-figures"), cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    log = out / "evaluations.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if log.exists() and log.read_text().count('"evaluation"') >= 6:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = len(evaluations(out))
    # killed in the optimisation (the local search's evaluations take milliseconds each, too
    # quick to aim a kill at; tests/surrogate/test_polish.py interrupts one in process)
    assert 6 <= done < TOTAL, "the run must be killed part-way"
    with log.open("a") as fh:  # a record cut short by the kill
        fh.write('{"type":"evaluation","index":99,"loss":1')
    res = subprocess.run(cli(out, "--no-figures", "--resume"), cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    recs = evaluations(out)
    indices = [r["index"] for r in recs]
    assert sorted(indices) == list(range(TOTAL)) and len(set(indices)) == TOTAL
    assert strip(recs) == strip(evaluations(full_run))
    a = json.loads((out / "summary.json").read_text())
    b = json.loads((full_run / "summary.json").read_text())
    assert a["best_params"] == b["best_params"] and a["best_loss_kN2"] == b["best_loss_kN2"]


def test_existing_run_needs_resume_and_same_settings(full_run: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["calibrate", str(CONFIG), "--out", str(full_run), *ARGS]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["calibrate", str(CONFIG), "--out", str(full_run), "--budget", "10", "--init", "5",
                 "--seed", "4", "--polish", "20", "--resume"]) == 2
    assert "--seed 4: the run" in capsys.readouterr().err
