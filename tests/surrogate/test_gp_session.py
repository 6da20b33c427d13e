"""The GP session: torch and the BLAS libraries on the asked number of threads, restored after."""

from __future__ import annotations

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
