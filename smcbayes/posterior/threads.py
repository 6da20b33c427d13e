"""The emulators' arithmetic on several threads, with results that do not depend on their
number.

The stage's samplers spend most of its time in numpy's and numba's arithmetic on the
emulators, one batch at a time, and numpy (in its products and ufuncs) and the compiled
kernels release the interpreter's lock.  Independent tasks of a fixed shape (the draws
and log-likelihoods of the GP sample functions on a support, the fixed-size batches of an
importance sample) therefore run side by side on a few threads, each exactly as it would
alone: a task's rows are never split anew, so every value is the same to the last bit
whatever the number of threads, and the random path with it.  Splitting a batch
differently would change the products' rounding and hence the path.

:func:`emulator_threads` opens the threads for a block of work (the posterior stage opens
them once); outside it :func:`thread_map` runs its tasks in order on the calling thread.
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

logger = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")

_LOCAL = threading.local()

_POOL: contextvars.ContextVar[tuple[ThreadPoolExecutor, int] | None] = contextvars.ContextVar(
    "emulator_threads", default=None)


def default_threads() -> int:
    """Threads of the emulators' arithmetic by default: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def emulator_threads(threads: int | None = None) -> Iterator[int]:
    """Run :func:`thread_map`'s tasks on ``threads`` threads (default
    :func:`default_threads`; 1: in order on the calling thread) within the block; yields
    the number in use.  The values computed are the same whatever the number."""
    count = default_threads() if threads is None else int(threads)
    if count < 1:
        raise ValueError(f"emulator threads must be at least 1, not {count}")
    if count == 1:
        token = _POOL.set(None)
        try:
            yield 1
        finally:
            _POOL.reset(token)
        return
    with ThreadPoolExecutor(count, thread_name_prefix="smcbayes-emulator", initializer=_mark_worker) as pool:
        token = _POOL.set((pool, count))
        logger.debug("emulator arithmetic on %d threads", count)
        try:
            yield count
        finally:
            _POOL.reset(token)


def _mark_worker() -> None:
    _LOCAL.worker = True


def in_worker() -> bool:
    """Whether this thread is one of :func:`emulator_threads`'s: its tasks already share the
    cores, so the compiled kernels run serially there (a kernel's values do not depend on
    its threads; numba's threads on top of the tasks would only contend, and its fallback
    threading layer, ``workqueue``, aborts when two threads start its parallel kernels)."""
    return bool(getattr(_LOCAL, "worker", False))


def thread_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(item) for item in items]``, the calls shared out over the threads of the
    enclosing :func:`emulator_threads` when there are at least as many calls as threads.
    Otherwise they run in order on this thread, whose compiled kernels may use every core:
    outside the threads, with fewer calls than threads, and in one of the threads (which
    would otherwise wait on itself).  ``fn`` must not draw random numbers or change shared
    state: the calls' order of completion varies."""
    open_pool = _POOL.get()
    work = list(items)
    if open_pool is None or in_worker() or len(work) < open_pool[1]:
        return [fn(item) for item in work]
    return list(open_pool[0].map(fn, work))
