"""The emulators' arithmetic on several threads, with results that do not depend on their
number.

The stage's samplers spend most of its time in numpy's and numba's arithmetic on the
emulators, one batch at a time, and numpy releases the interpreter's lock inside its
products and ufuncs.  Independent tasks of a fixed shape (the log-likelihoods of the GP
sample functions on a support, the fixed-size batches of an importance sample) therefore
run side by side on a few threads, each exactly as it would alone: a task's rows are never
split anew, so every value is the same to the last bit whatever the number of threads, and
the random path with it.  Splitting a batch differently would change the products' rounding
and hence the path.

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

_POOL: contextvars.ContextVar[ThreadPoolExecutor | None] = contextvars.ContextVar("emulator_threads",
                                                                                    default=None)


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
    if count > 1 and not _kernels_thread_safe():
        logger.info("numba's threading layer is 'workqueue', whose compiled kernels must not run on "
                    "two threads at once: the emulator's arithmetic runs on one thread (install tbb "
                    "for more)")
        count = 1
    if count == 1:
        token = _POOL.set(None)
        try:
            yield 1
        finally:
            _POOL.reset(token)
        return
    with ThreadPoolExecutor(count, thread_name_prefix="smcbayes-emulator", initializer=_mark_worker) as pool:
        token = _POOL.set(pool)
        logger.debug("emulator arithmetic on %d threads", count)
        try:
            yield count
        finally:
            _POOL.reset(token)


def _mark_worker() -> None:
    _LOCAL.worker = True


def in_worker() -> bool:
    """Whether this thread is one of :func:`emulator_threads`'s: its tasks already share the
    cores, so the compiled kernels run serially there (numba's threads on top of them would
    only contend; a kernel's values do not depend on its threads)."""
    return bool(getattr(_LOCAL, "worker", False))


def _kernels_thread_safe() -> bool:
    """Whether numba's threading layer lets its parallel kernels run from several threads at
    once: 'tbb' and 'omp' do, 'workqueue' (numba's fallback) aborts the process."""
    import numba

    numba.get_num_threads()  # starts the layer, whose name is known only then
    return str(numba.threading_layer()) != "workqueue"


def thread_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(item) for item in items]``, the calls shared out over the threads of the
    enclosing :func:`emulator_threads` (in order on this thread outside one, or when called
    from one of its threads, which would otherwise wait on themselves).  ``fn`` must not
    draw random numbers or change shared state: the tasks' order of completion varies."""
    pool = _POOL.get()
    work = list(items)
    if pool is None or len(work) < 2:
        return [fn(item) for item in work]
    return list(pool.map(fn, work))
