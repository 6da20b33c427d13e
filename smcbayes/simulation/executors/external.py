"""External-simulator adapter: run the user's own solver (e.g. Moldflow) by command line.

For each parameter vector and configuration the adapter makes a work folder, writes
``params.json`` there::

    {"config_id": "60-bar-07", "parameters": {"n": 0.4, "tau_star_Pa": 1e4, ...},
     "units": {"n": "-", "tau_star_Pa": "Pa", ...}, "configuration": {...the config table...}}

runs the command template with ``{params}``, ``{output}``, ``{config}`` and ``{workdir}``
replaced (e.g. ``python run_moldflow.py {params} --out {output}``), with a timeout, and
reads the curve the command wrote to ``{output}``: CSV with ``time_s,force_kN`` (and
optionally ``displacement_mm``), or a Moldflow XML result file.  A non-zero exit, a
timeout or an unreadable output fails that evaluation with the reason; the run goes on.
Work folders are named after a hash of the parameters, so a rerun finds the same folder.

Each command runs in a process group of its own: on a timeout, on an interruption
(Ctrl-C, a kill of the calling process) and after it exits, the whole group is ended
(SIGTERM, then SIGKILL after a short grace), so a wrapper's children (the solver it
started) never outlive it.
"""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import signal
import subprocess
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import ProjectConfig
from smcbayes.data.readers.csv import read_csv
from smcbayes.data.readers.moldflow import read_moldflow
from smcbayes.errors import ConfigError, DataError, SolverError
from smcbayes.forward.parameters import ParameterSpace
from smcbayes.forward.result import STATUS_OK, SimulationResult

Array = NDArray[np.float64]
FORMATS = ("csv", "moldflow")
FIELDS = ("params", "output", "config", "workdir")
GRACE_S = 2.0
"""Seconds between SIGTERM and SIGKILL when a command's process group is ended."""


def _end_group(proc: subprocess.Popen[bytes], grace_s: float) -> None:
    """End every process of ``proc``'s group: SIGTERM, then SIGKILL after ``grace_s``.

    The group outlives its leader when a wrapper's children still run, so SIGKILL goes to
    the group even when the leader has already exited.
    """
    if not hasattr(os, "killpg"):  # no process groups (Windows): the direct child only
        proc.kill()
        proc.wait()
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except ProcessLookupError:  # nothing of the group left
        proc.wait()
        return
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def run_command(argv: Sequence[str], cwd: Path, timeout_s: float, grace_s: float = GRACE_S) -> int:
    """Run ``argv`` in ``cwd`` in a new session, its output in ``cwd/stdout.txt`` and
    ``cwd/stderr.txt``; returns the exit code.

    The command's whole process group is ended on a timeout, on an interruption while
    waiting (``KeyboardInterrupt``, ``SystemExit``: re-raised once the group is gone) and
    after the command exits (children it left behind).

    Raises:
        SolverError: the command could not start or ran longer than ``timeout_s`` (s).
    """
    with open(cwd / "stdout.txt", "wb") as out, open(cwd / "stderr.txt", "wb") as err:
        try:
            proc = subprocess.Popen(list(argv), cwd=cwd, stdout=out, stderr=err,
                                    stdin=subprocess.DEVNULL, start_new_session=True)
        except OSError as error:
            raise SolverError(f"external command could not start: {error}") from None
        try:
            code = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            _end_group(proc, grace_s)
            raise SolverError(f"external command timed out after {timeout_s:g} s; raise "
                              "--external-timeout if the solver needs longer") from None
        except (KeyboardInterrupt, SystemExit):  # no orphan, then go on unwinding
            _end_group(proc, grace_s)
            raise
        _end_group(proc, grace_s)
        return code


class ExternalSimulator:
    """Simulate by running an external command per parameter vector and configuration.

    Args:
        project: the validated project (configuration tables go into ``params.json``).
        space: parameter space (names, units, fixed values).
        command: template, e.g. ``"python sim.py {params} {output}"``.
        work_dir: folder for the per-evaluation work folders.
        timeout_s: wall-time limit of one command (s).
        output_format: ``csv`` or ``moldflow``.
    """

    def __init__(self, project: ProjectConfig, space: ParameterSpace, command: str,
                 work_dir: Path, timeout_s: float = 3600.0, output_format: str = "csv") -> None:
        if output_format not in FORMATS:
            raise ConfigError(f"--external-format {output_format!r}; accepted: {', '.join(FORMATS)}")
        self.args = shlex.split(command)
        if not self.args:
            raise ConfigError("--external: the command template is empty")
        for token in self.args:
            try:
                token.format(**{f: "" for f in FIELDS})
            except (KeyError, IndexError, ValueError):
                raise ConfigError(f"--external: placeholder in {token!r} not understood; "
                                  f"accepted: {', '.join('{' + f + '}' for f in FIELDS)}") from None
        self.project = project
        self.space = space
        self.work_dir = Path(work_dir).resolve()
        self.timeout_s = timeout_s
        self.output_format = output_format

    def _folder(self, values: dict[str, float], config_id: str) -> Path:
        key = json.dumps({"config": config_id, "params": values}, sort_keys=True)
        digest = hashlib.sha1(key.encode()).hexdigest()[:12]
        return self.work_dir / f"{config_id}-{digest}"

    def run_one(self, values: dict[str, float], config_id: str) -> tuple[Array, Array, Array | None]:
        """Run the command for one parameter set; returns time (s), force (kN), displacement (mm) or None.

        Raises:
            SolverError: the command failed or timed out.
            DataError: it wrote no readable curve.
        """
        folder = self._folder(values, config_id)
        folder.mkdir(parents=True, exist_ok=True)
        params = folder / "params.json"
        output = folder / ("curves.csv" if self.output_format == "csv" else "curves.xml")
        units = {p.name: p.unit for p in self.space.parameters}
        params.write_text(json.dumps({
            "config_id": config_id, "parameters": values, "units": units,
            "configuration": self.project.get(config_id).model_dump(mode="json"),
        }, indent=2), encoding="utf-8")
        fields = {"params": str(params), "output": str(output), "config": config_id,
                  "workdir": str(folder)}
        argv = [token.format(**fields) for token in self.args]
        output.unlink(missing_ok=True)  # a retry must not read the curve of an earlier attempt
        code = run_command(argv, folder, self.timeout_s)
        if code != 0:
            stderr = (folder / "stderr.txt").read_text(encoding="utf-8", errors="replace")
            tail = stderr.strip().splitlines()[-1:] or ["(no stderr)"]
            raise SolverError(f"external command exited with {code}: {tail[0]}")
        return self._read(output)

    def _read(self, output: Path) -> tuple[Array, Array, Array | None]:
        if self.output_format == "moldflow":
            force = read_moldflow(output, "force")
            return force.time_s, force.values, None
        force = read_csv(output, "force_kN", "force")
        header = output.read_text(encoding="utf-8").splitlines()[0].split(",")
        disp = None
        if "displacement_mm" in [h.strip() for h in header]:
            disp = np.interp(force.time_s, *_xy(read_csv(output, "displacement_mm", "displacement")))
        return force.time_s, force.values, disp

    def simulate(self, theta: Array, config_ids: Sequence[str]) -> dict[str, SimulationResult]:
        """Curves of every row of ``theta`` ``(P, d)`` on each configuration (NaN rows on failure)."""
        batch = self.space.batch(theta)
        rows = np.atleast_2d(theta).shape[0]
        out: dict[str, SimulationResult] = {}
        for cid in config_ids:
            curves: list[tuple[Array, Array, Array | None] | None] = []
            status: list[str] = []
            for i in range(rows):
                values = {k: float(v[i]) for k, v in batch.items()}
                try:
                    curves.append(self.run_one(values, cid))
                    status.append(STATUS_OK)
                except (SolverError, DataError) as err:  # that run failed; the batch goes on
                    curves.append(None)
                    status.append(f"failed: {err}")
            out[cid] = _stack(cid, curves, status, self.project.get(cid).press.force_limit_kN)
        return out


def _xy(curve: object) -> tuple[Array, Array]:
    return curve.time_s, curve.values  # type: ignore[attr-defined]


def _stack(cid: str, curves: list[tuple[Array, Array, Array | None] | None], status: list[str],
           limit_kN: float) -> SimulationResult:
    """Pad the rows' curves to a common length (holding end values) into one result."""
    length = max((c[0].size for c in curves if c is not None), default=2)
    shape = (len(curves), length)
    t, f, d = np.full(shape, np.nan), np.full(shape, np.nan), np.full(shape, np.nan)
    switch = np.full(len(curves), np.nan)
    for i, c in enumerate(curves):
        if c is None:
            continue
        n = c[0].size
        t[i, :n] = c[0]
        t[i, n:] = c[0][-1] + np.arange(1, length - n + 1) * 1e-9
        f[i] = np.concatenate([c[1], np.full(length - n, c[1][-1])])
        if c[2] is not None:
            d[i] = np.concatenate([c[2], np.full(length - n, c[2][-1])])
        hit = np.nonzero(c[1] >= limit_kN)[0]
        switch[i] = c[0][hit[0]] if hit.size else c[0][-1]
    nan = np.full(shape, np.nan)
    return SimulationResult(cid, t, nan.copy(), d, f, nan.copy(), nan.copy(),
                            np.zeros(shape, dtype=np.int8), switch, status)
