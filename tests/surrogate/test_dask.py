"""Dask executor: same evaluations as the local run; a worker killed mid-run is survived."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from smcbayes.errors import SolverError
from smcbayes.forward.parameters import BASE_PARAMETERS, ParameterSpace
from smcbayes.run.runlog import RunLog
from smcbayes.simulation.executors.dask import DaskExecutor
from smcbayes.simulation.executors.local import LocalExecutor
from smcbayes.simulation.objective import QuadraticObjective
from smcbayes.surrogate.loop import BayesOpt, BOSettings

distributed = pytest.importorskip("distributed")

SETTINGS = BOSettings(budget=8, init=4, batch=2, restarts=4, raw_samples=64, seed=5)


def objective(delay_s: float = 0.0) -> QuadraticObjective:
    space = ParameterSpace(BASE_PARAMETERS).with_fixed({"n": 0.4, "tau_star_Pa": 1e4, "B_Pa_s": 1e4})
    return QuadraticObjective(space, [0.02, 1.3], ["a", "b"], seed=2, delay_s=delay_s)


def records(bo: BayesOpt) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "seconds"} for _, r in sorted(bo.state.evaluations.items())]


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


def test_dask_equals_local(client, tmp_path: Path) -> None:
    local = BayesOpt(objective(), SETTINGS, RunLog(tmp_path / "local.jsonl"), LocalExecutor(1)).run()
    # by address, as `--scheduler tcp://...` does
    executor = DaskExecutor(client.scheduler.address)
    dask = BayesOpt(objective(), SETTINGS, RunLog(tmp_path / "dask.jsonl"), executor).run()
    assert records(dask) == records(local)
    assert len(records(dask)) == 8


def test_worker_killed_mid_run(client, tmp_path: Path) -> None:
    log = RunLog(tmp_path / "kill.jsonl")
    killed: list[int] = []

    def killer() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if log.path.exists() and '"evaluation"' in log.path.read_text():
                pid = sorted(client.run(os.getpid).values())[0]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
            time.sleep(0.05)

    thread = threading.Thread(target=killer)
    thread.start()
    bo = BayesOpt(objective(delay_s=0.4), SETTINGS, log, DaskExecutor(client)).run()
    thread.join()
    assert killed, "a worker must have been killed during the run"
    assert len(bo.state.evaluations) == 8
    assert bo.failures() == 0
    reference = BayesOpt(objective(), SETTINGS, RunLog(tmp_path / "ref.jsonl"), LocalExecutor(1)).run()
    assert records(bo) == records(reference)


@pytest.mark.timeout(60)  # before the fix the run waited for a worker forever
def test_no_worker_left_stops_with_a_solver_error_and_resumes(tmp_path: Path) -> None:
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                       dashboard_address=None)
    own = distributed.Client(cluster)
    log = RunLog(tmp_path / "alone.jsonl")
    settings = SETTINGS.model_copy(update={"worker_timeout_s": 1.0})

    def close_workers() -> None:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if log.path.exists() and '"evaluation"' in log.path.read_text():
                cluster.scale(0)
                return
            time.sleep(0.05)

    thread = threading.Thread(target=close_workers)
    try:
        thread.start()
        start = time.monotonic()
        with pytest.raises(SolverError, match=r"no Dask worker left at \S+ for 1 s; start workers "
                                              r"with `dask worker \S+` and resume with --resume"):
            BayesOpt(objective(delay_s=0.3), settings, log, DaskExecutor(own.scheduler.address)).run()
        assert time.monotonic() - start < 10
        thread.join()
        logged = len(log.read().evaluations)
        assert 1 <= logged < 8
        # workers back: the run resumes to the uninterrupted result
        cluster.scale(1)
        own.wait_for_workers(1, timeout=10)
        bo = BayesOpt(objective(), settings, log, DaskExecutor(own)).run()
        reference = BayesOpt(objective(), SETTINGS, RunLog(tmp_path / "ref.jsonl"), LocalExecutor(1)).run()
        assert records(bo) == records(reference)
    finally:
        own.close()
        cluster.close()
