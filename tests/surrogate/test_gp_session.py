"""The GP session: torch and the BLAS libraries on the asked number of threads, restored after."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import pytest
import torch
from threadpoolctl import threadpool_limits

from smcbayes.surrogate import gp


def test_the_gp_session_limits_torch_and_blas_threads_and_restores_torch(
        monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[dict[str, Any]] = []

    def recording(**kwargs: Any) -> threadpool_limits:
        asked.append(kwargs)
        return threadpool_limits(**kwargs)

    monkeypatch.setattr(gp, "threadpool_limits", recording)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with gp.gp_session():
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    assert asked == [{"limits": 1, "user_api": "blas"}]


def test_the_posteriors_threaded_kernels_leave_torch_on_the_sessions_thread() -> None:
    # a fresh process: numba's threads start at its first threaded call, and there they
    # would reset the OpenMP runtime torch shares to every core
    code = (
        "import numpy as np, torch\n"
        "from smcbayes.surrogate.gp import gp_session\n"
        "from smcbayes.posterior.curves import matern52\n"
        "with gp_session():\n"
        "    matern52(np.random.default_rng(0).random((600, 3)), np.ones((50, 3)), np.ones(3))\n"
        "    print(torch.get_num_threads())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=300)
    assert done.stdout.strip() == "1"
