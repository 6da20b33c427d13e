"""The emulator's threads: tasks in order, the same values whatever their number."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from smcbayes.posterior.threads import emulator_threads, in_worker, thread_map


def test_outside_the_threads_tasks_run_in_order_on_the_calling_thread() -> None:
    seen: list[tuple[int, str]] = []

    def task(k: int) -> int:
        seen.append((k, threading.current_thread().name))
        return k * k

    assert thread_map(task, range(5)) == [0, 1, 4, 9, 16]
    assert seen == [(k, threading.current_thread().name) for k in range(5)]
    assert not in_worker()


def test_inside_the_threads_results_keep_their_order_and_nested_maps_run_inline() -> None:
    def task(k: int) -> tuple[int, bool, list[tuple[int, str]], str]:
        # a map inside a task runs on the task's own thread (no worker waits on itself)
        inner = thread_map(lambda j: (j + k, threading.current_thread().name), range(3))
        return k, in_worker(), inner, threading.current_thread().name

    with emulator_threads(2) as count:
        assert count == 2
        out = thread_map(task, range(6))
    assert [o[0] for o in out] == list(range(6)) and all(o[1] for o in out)
    assert [[v for v, _ in o[2]] for o in out] == [[k, k + 1, k + 2] for k in range(6)]
    assert all(name == o[3] for o in out for _, name in o[2])
    assert not in_worker()


def test_numpy_tasks_give_the_same_bits_on_one_thread_and_on_several() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((6, 300, 60)), rng.standard_normal((60, 500))

    def task(x: np.ndarray) -> np.ndarray:
        return np.exp(np.tanh(x @ b)).sum(axis=1)

    with emulator_threads(1):
        one = thread_map(task, list(a))
    with emulator_threads(3):
        three = thread_map(task, list(a))
    for p, q in zip(one, three, strict=True):
        np.testing.assert_array_equal(p, q)


def test_a_count_below_one_is_refused() -> None:
    with pytest.raises(ValueError, match="at least 1"), emulator_threads(0):
        pass


def test_fewer_calls_than_threads_run_on_the_calling_thread() -> None:
    """There the calls' compiled kernels may share every core out themselves."""
    with emulator_threads(3):
        assert thread_map(lambda k: in_worker(), range(2)) == [False, False]
        assert all(thread_map(lambda k: in_worker(), range(3)))


def test_an_error_in_a_call_reaches_the_caller_and_the_threads_close() -> None:
    def task(k: int) -> int:
        if k == 3:
            raise ArithmeticError("row 3")
        return k

    with pytest.raises(ArithmeticError, match="row 3"), emulator_threads(2):
        thread_map(task, range(6))
    assert thread_map(lambda k: in_worker(), range(4)) == [False] * 4
