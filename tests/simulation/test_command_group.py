"""External commands leave no process behind: timeout, interruption, early exit."""

from __future__ import annotations

import os
import signal
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from smcbayes.errors import SolverError
from smcbayes.simulation.executors.external import run_command

pytestmark = pytest.mark.skipif(not hasattr(os, "killpg"), reason="needs POSIX process groups")

# A wrapper that starts the "solver" (a child sleeping 30 s), records its PID, waits
# ``$1`` s and exits with ``$2``.
WRAPPER = textwrap.dedent('''
    sleep 30 &
    echo $! > child.pid.tmp && mv child.pid.tmp child.pid
    sleep "$1"
    exit "$2"
''')


def gone(pid: int, wait_s: float = 3.0) -> bool:
    """Whether ``pid`` has ended (a zombie waiting for its new parent to reap it counts)."""
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        try:
            if Path(f"/proc/{pid}/stat").read_text().split(") ")[1].startswith("Z"):
                return True
        except (FileNotFoundError, IndexError):
            return True
        time.sleep(0.05)
    return False


def child_pid(folder: Path) -> int:
    deadline = time.monotonic() + 5
    while not (folder / "child.pid").exists() or not (folder / "child.pid").read_text():
        assert time.monotonic() < deadline, "the wrapper did not start its child"
        time.sleep(0.02)
    return int((folder / "child.pid").read_text())


@pytest.fixture()
def wrapper(tmp_path: Path) -> Iterator[Path]:
    path = tmp_path / "wrapper.sh"
    path.write_text(WRAPPER)
    yield path
    pid_file = tmp_path / "child.pid"
    if pid_file.exists():  # never leave a sleeping child behind, whatever the outcome
        try:
            os.kill(int(pid_file.read_text()), signal.SIGKILL)
        except (ProcessLookupError, ValueError):
            pass


def test_timeout_ends_the_whole_process_group(tmp_path: Path, wrapper: Path) -> None:
    start = time.monotonic()
    with pytest.raises(SolverError, match="timed out after 1 s"):
        run_command(["sh", str(wrapper), "100", "0"], tmp_path, 1.0, grace_s=0.5)
    assert time.monotonic() - start < 5
    assert gone(child_pid(tmp_path))


def test_interruption_ends_the_group_and_is_reraised(tmp_path: Path, wrapper: Path) -> None:
    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, interrupt)
    try:
        signal.setitimer(signal.ITIMER_REAL, 1.0)
        with pytest.raises(KeyboardInterrupt):
            run_command(["sh", str(wrapper), "100", "0"], tmp_path, 60.0, grace_s=0.5)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert gone(child_pid(tmp_path))


def test_children_left_by_a_finished_command_are_ended(tmp_path: Path, wrapper: Path) -> None:
    assert run_command(["sh", str(wrapper), "0.2", "3"], tmp_path, 30.0, grace_s=0.5) == 3
    assert gone(child_pid(tmp_path))
