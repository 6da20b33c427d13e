"""Twin of ``benchmarks/failure_capture.py``: the measurement runs, and the default meets it."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "failure_capture.py"


def bench():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("failure_capture", PATH)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def test_default_retries_meet_the_target_in_expectation_and_in_a_run(tmp_path: Path) -> None:
    b = bench()
    assert b.expected_lost(0.2, 2) > b.TARGET >= b.expected_lost(0.2, 3)
    assert b.expected_lost(0.2, 0) == pytest.approx(1 - 0.8**9)
    row = b.calibrate(budget=8, seed=0, share=0.2, retries=None, folder=tmp_path)
    assert row["retries"] == 3 and row["evaluations"] == 8 and row["lost"] == 0
