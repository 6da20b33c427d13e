"""Progress estimates from a fake clock, and plain lines when stderr is not a terminal."""

from __future__ import annotations

import logging

import pytest

from smcbayes import progress
from smcbayes.progress import Progress


class Clock:
    """A clock that moves only when told (s)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_calibration_rate_includes_the_fits_between_rounds() -> None:
    # 6 initial evaluations in one batch (30 s, compilation included) reported within
    # microseconds, then one evaluation per round: 2 s of simulation + 8 s of GP fit
    clock = Clock()
    bar = Progress(30, "calibration", "eval", clock=clock)
    clock.t = 30.0
    for _ in range(6):
        bar.update(1)
        clock.t += 1e-5
    assert bar.remaining_s() != bar.remaining_s()  # unknown, not a rate of a burst
    for _ in range(3):
        clock.t += 10.0
        bar.update(1)
    assert bar.remaining_s() == pytest.approx(21 * 10.0, rel=1e-3)


def test_first_batch_with_start_up_is_left_out() -> None:
    # 500 draws per batch; the first also starts a pool (40 s), later ones take 5 s
    clock = Clock()
    bar = Progress(3000, "correction", "draw", clock=clock)
    clock.t = 45.0
    bar.update(500)
    clock.t += 5.0
    bar.update(500)
    assert bar.remaining_s() == pytest.approx(4 * 5.0)
    clock.t += 5.0
    bar.update(500)
    assert bar.remaining_s() == pytest.approx(3 * 5.0)


def test_plain_lines_at_most_every_interval(caplog: pytest.LogCaptureFixture,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    clock = Clock()
    progress.enable(True, interval_s=10.0)
    try:
        with caplog.at_level(logging.INFO, logger="smcbayes.progress"):
            with Progress(100, "work", "run", clock=clock) as bar:
                for _ in range(100):
                    clock.t += 1.0
                    bar.update(1, note="ok")
    finally:
        progress.enable(False)
    records = [r for r in caplog.records if r.name == "smcbayes.progress"]
    times = [float(r.getMessage().split(": ")[1].split("/")[0]) for r in records]
    # the first update, then one per 10 s (one unit a second), and the last
    assert times == [1.0, *[float(t) for t in range(11, 101, 10)], 100.0]
    assert all("\r" not in r.getMessage() and "\n" not in r.getMessage() for r in records)
    assert records[-1].getMessage().startswith("work: 100/100 run  ok")
    assert capsys.readouterr().err == ""
