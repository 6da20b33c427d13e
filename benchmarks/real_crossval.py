"""Cross-validation of the whole workflow on the 9 real training trials of the thesis.

Six folds: leave one closing speed out (all 0.3, all 0.7, all 1.1 mm/s trials) and leave one
charge group out (60 % bar, 60 % centre, 80 % bar).  Per fold, a derived project file (the
held-out trials with ``role = "validation"``, the three 80 % centre configurations without
data left out) is written into the work directory and the documented workflow runs on it
through the library's API (the same code as the commands):

1. ``calibrate`` the base model (``smcbayes calibrate``);
2. ``diagnose_gap`` on that run (``smcbayes diagnose RUN``), whose decision names the
   effect(s) to add; a selected effect set in the diagnosis summary is preferred when the
   diagnosis records one, else its decision, else its top-ranked effect;
3. ``calibrate`` with those effects (``smcbayes calibrate --effect X``);
4. ``sample_posterior`` (``smcbayes posterior RUN``), whose predictive bands are drawn on the
   validation configurations, i.e. the held-out trials.

Per held-out trial: force RMSE (kN) over the whole closing at the calibrated point and of
the posterior median curve, coverage of the 50 % and 90 % predictive bands, mean width of the
90 % band (kN), CRPS (kN) and the 90 % interval score (kN); where the project profiles
contact offsets or measures them from each trial's end state, also the RMSE at the trial's
own offset (``rmse_own_contact_kN``, ``own_contact_offset_mm``; its best within the profile's
range, or the one its own end state implies): the error a known contact (a measured stack height) would
leave, i.e. the model's share of the held-out error; and over each band's whole grid, the
measured closing held at the force limit past its end (``horizon_scores``), the predictive
mean's RMSE and the 90 % band's coverage and width (``rmse_mean_horizon_kN``,
``coverage90_horizon``, ``band_width90_horizon_kN``).  Per fold: the effects, the wall
time of each step, and the thesis's clipped loss (force compared up to the incompressible
flow-stop time, summed over the 9 configurations; the thesis's best is 18,384 kN^2) at the
fold's calibrated point.

    python benchmarks/real_crossval.py [--fold K] [--jobs N] [--effects a,b] [--workdir DIR] [--reuse]
        [--project FILE] [--name real_crossval]
        [--budget 60 --init 20] [--population 64 --generations 50 --restarts 2]
        [--walkers 32 --steps 10000 --refine 800 --round-runs N --correct-draws 0 --draws 100]
        [--emulator curves]

The budgets default to the workflow's defaults (``[calibration]``, ``[diagnose]``,
``[posterior]`` of settings.py).  Writes ``benchmarks/results/NAME.json`` (``--name``,
default ``real_crossval``; merged with an existing file when ``--fold`` is given), copies
each fold's band figure to ``benchmarks/results/NAME/fold-K.png`` and keeps the folds'
work in ``NAME/work`` unless ``--workdir`` says otherwise.  Needs
../shared/data/thesis-press next to the repository (``--data-dir``); without it, prints
why and exits 0.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
import time
import tomllib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATA = ROOT / ".." / "shared" / "data" / "thesis-press"
PROJECT = ROOT / "configs" / "thesis.toml"
RESULTS = ROOT / "benchmarks" / "results"
THESIS_BEST_CLIPPED_KN2 = 18384.70
TRAIN = ("60-bar-03", "60-bar-07", "60-bar-11", "60-center-03", "60-center-07", "60-center-11",
         "80-bar-03", "80-bar-07", "80-bar-11")
FOLDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("speed 0.3 mm/s", tuple(c for c in TRAIN if c.endswith("-03"))),
    ("speed 0.7 mm/s", tuple(c for c in TRAIN if c.endswith("-07"))),
    ("speed 1.1 mm/s", tuple(c for c in TRAIN if c.endswith("-11"))),
    ("60 % bar", tuple(c for c in TRAIN if c.startswith("60-bar"))),
    ("60 % centre", tuple(c for c in TRAIN if c.startswith("60-center"))),
    ("80 % bar", tuple(c for c in TRAIN if c.startswith("80-bar"))),
)
def toml_value(v: Any) -> str:
    """One TOML value (the subset thesis.toml uses: strings, numbers, lists, inline tables)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"no TOML form for {type(v).__name__}")


def toml_dump(doc: dict[str, Any]) -> str:
    """TOML text of a project document: top-level keys, nested tables, array of configurations."""
    lines: list[str] = []

    def table(prefix: str, body: dict[str, Any]) -> None:
        plain = {k: v for k, v in body.items()
                 if not isinstance(v, dict) or not v or prefix == "configuration"}
        nested = {k: v for k, v in body.items() if k not in plain}
        if prefix and plain:
            lines.append(f"\n[{prefix}]")
        lines.extend(f"{k} = {toml_value(v)}" for k, v in plain.items())
        for k, v in nested.items():
            table(f"{prefix}.{k}" if prefix else k, v)

    top = {k: v for k, v in doc.items() if k != "configuration"}
    table("", top)
    for conf in doc.get("configuration", []):
        lines.append("\n[[configuration]]")
        lines.extend(f"{k} = {toml_value(v)}" for k, v in conf.items())
    return "\n".join(lines) + "\n"


def fold_project(project: Path, held_out: tuple[str, ...], data_dir: Path, path: Path) -> Path:
    """Write the fold's project from ``project``: held-out trials as validation,
    configurations without data dropped."""
    doc = tomllib.loads(project.read_text(encoding="utf-8"))
    doc["data_dir"] = str(data_dir.resolve())
    confs = []
    for conf in doc["configuration"]:
        if "data" not in conf:
            continue
        conf["role"] = "validation" if conf["id"] in held_out else "train"
        confs.append(conf)
    doc["configuration"] = confs
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(toml_dump(doc), encoding="utf-8")
    return path


def selected_effects(summary: dict[str, Any]) -> list[str]:
    """The effects a diagnosis selects: its selected set if recorded, else its decision, else its
    top-ranked single effect."""
    for key in ("selected_effects", "selection", "selected"):
        sel = summary.get(key)
        if isinstance(sel, dict):
            sel = sel.get("effects")
        if isinstance(sel, list) and sel:
            return [str(e) for e in sel]
    best = (summary.get("decision") or {}).get("best")
    if best:
        return [e.strip() for e in str(best).split("+")]
    singles = [r["effect"] for r in summary.get("ranking") or [] if "+" not in r["effect"]]
    return singles[:1]


def rmse_at(project: Any, run_dir: Path, ids: list[str], theta_by_name: dict[str, float],
            effects: list[str], fixed: dict[str, float],
            train_ids: list[str]) -> tuple[dict[str, float], dict[str, float], dict[str, dict[str, float]]]:
    """Force RMSE (kN, whole closing) and the thesis's clipped MSE (kN^2) of ``ids`` at one
    point, and each held-out trial's RMSE at its own contact.

    Where each trial has a contact offset (profiled by the loss or measured from its end
    state), a training trial is compared at its own offset (as the calibration saw it) and
    a held-out trial by its curve averaged over the training trials' offsets
    (:func:`smcbayes.data.loss.mixed_force_pair`): its own is unknown until it is pressed.
    The third result gives, per held-out trial, the RMSE at its own offset
    (the best within the loss's range, or the one its end state implies; ``rmse_kN``,
    ``offset_mm``): the error left if the trial's contact were known (e.g.
    its stack height measured), which separates the model's error from the trials' scatter.
    """
    from smcbayes.data.loss import contact_offsets_mm, force_pair, given_force_pair
    from smcbayes.simulation.problem import build_problem

    problem = build_problem(project, run_dir, effects, fixed)
    space = problem.model.space
    theta = np.array([[theta_by_name[n] for n in space.free_names]])
    results = problem.model.simulate(theta, ids)
    full_spec = project.loss.model_copy(update={"clip": "none"})
    own = contact_offsets_mm(results, problem.dataset, project.loss, [c for c in ids if c in train_ids])
    unseen = tuple(own.values())
    held_out = [c for c in ids if c not in train_ids]
    known = contact_offsets_mm(results, problem.dataset, project.loss, held_out)
    rmse, clipped, at_own = {}, {}, {}
    for cid in ids:
        m = problem.dataset.measurements[cid]
        offset = own.get(cid, unseen)
        full = given_force_pair(results[cid], m, full_spec, offset)
        rmse[cid] = float(np.sqrt(np.mean((full.sim_kN[0] - full.meas_kN[0]) ** 2)))
        if m.flow_stop_s is not None:
            thesis = project.loss.model_copy(update={"clip": "flow_stop"})
            cl = given_force_pair(results[cid], m, thesis, offset)
            clipped[cid] = float(np.mean((cl.sim_kN[0] - cl.meas_kN[0]) ** 2))
        if cid in known:
            pair = force_pair(results[cid], m, full_spec, offset_mm=known[cid])
            at_own[cid] = {"rmse_kN": float(np.sqrt(np.mean((pair.sim_kN[0] - pair.meas_kN[0]) ** 2))),
                           "offset_mm": float(known[cid])}
    return rmse, clipped, at_own


def small_copy(src: Path, dest: Path, width_px: int = 1100) -> None:
    """Copy a PNG, scaled down to ``width_px`` wide when it is wider (kept small for docs)."""
    from PIL import Image

    with Image.open(src) as im:
        if im.width > width_px:
            im = im.resize((width_px, round(im.height * width_px / im.width)), Image.LANCZOS)
        im.convert("RGB").quantize(colors=64).save(dest, optimize=True)


REUSE_KEYS = ("data_dir", "seed", "budget", "init", "population", "generations", "restarts", "candidates",
              "effects")
"""Settings that shape a fold's calibrations and diagnosis: ``--reuse`` keeps a fold's
work only when they and the project file are unchanged."""


def fold_workdir(k: int, args: argparse.Namespace) -> Path:
    """Fold ``k``'s work directory: emptied unless ``--reuse`` finds it made with the same
    settings (:data:`REUSE_KEYS`, recorded in ``settings.json``)."""
    work = Path(args.workdir or RESULTS / args.name / "work") / f"fold-{k}"
    settings = {key: getattr(args, key) for key in REUSE_KEYS}
    # the same data reached through another checkout's relative path is the same data
    settings["data_dir"] = str(Path(args.data_dir).resolve())
    settings["project_sha256"] = hashlib.sha256(Path(args.project).read_bytes()).hexdigest()
    record = work / "settings.json"
    same = args.reuse and record.exists() and json.loads(record.read_text()) == settings
    if work.exists() and not same:
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps(settings, indent=2) + "\n")
    return work


def choose_effects(base: Any, work: Path, args: argparse.Namespace,
                   times: dict[str, float]) -> tuple[list[str], dict[str, Any] | None]:
    """The effects to add (``--effects``, a reused choice or the diagnosis's) and the
    diagnosis's record; the diagnosis's wall time goes into ``times``."""
    import smcbayes

    if args.effects is not None:
        return list(args.effects), None
    chosen = work / "effects.json"
    if chosen.exists():  # only left by fold_workdir under --reuse with the same settings
        kept = json.loads(chosen.read_text())
        return kept["effects"], kept["diagnosis"]
    t = time.perf_counter()
    diag = smcbayes.diagnose_gap(base.run_dir, figures=False, population=args.population,
                                 generations=args.generations, restarts=args.restarts, seed=args.seed,
                                 effects=args.candidates)
    times["diagnose_s"] = time.perf_counter() - t
    effects = selected_effects(diag.summary)
    diagnosis = {"statement": diag.statement, "holdout": diag.summary.get("holdout"),
                 "ranking": [{k2: r.get(k2) for k2 in ("effect", "score",
                                                       "holdout_shrink_pct", "significant")}
                             for r in diag.summary.get("ranking") or []]}
    chosen.write_text(json.dumps({"effects": effects, "diagnosis": diagnosis}, indent=2) + "\n")
    return effects, diagnosis


def run_fold(k: int, args: argparse.Namespace) -> dict[str, Any]:
    """The whole workflow on fold ``k``; returns its record."""
    import smcbayes
    from smcbayes.config import load_project
    from smcbayes.data.dataset import load_dataset

    name, held_out = FOLDS[k]
    work = fold_workdir(k, args)
    path = fold_project(Path(args.project), held_out, Path(args.data_dir), work / "project.toml")
    project = load_project(path)
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    reused = (work / "base" / "config.json").exists()
    cal_settings = {"budget": args.budget, "init": args.init, "seed": args.seed}
    base = smcbayes.calibrate(project, work / "base", figures=False,
                              resume=reused, **cal_settings)
    times["calibrate_base_s"] = time.perf_counter() - t0
    effects, diagnosis = choose_effects(base, work, args, times)
    final_run = base
    # the solid density and the bulk viscosity are fixed by the project file when on
    fixed: dict[str, float] = {}
    if effects:
        t = time.perf_counter()
        final_run = smcbayes.calibrate(project, work / "final", effects=effects, figures=False,
                                       resume=(work / "final" / "config.json").exists(), **cal_settings)
        times["calibrate_effects_s"] = time.perf_counter() - t
    t = time.perf_counter()
    post = smcbayes.sample_posterior(final_run.run_dir, walkers=args.walkers, steps=args.steps,
                                     correct_draws=args.correct_draws, draws=args.draws, seed=args.seed,
                                     functions=args.functions, refine=args.refine, emulator=args.emulator,
                                     round_runs=args.round_runs)
    times["posterior_s"] = time.perf_counter() - t
    times["workflow_s"] = time.perf_counter() - t0
    best = final_run.best_params
    # RMSE at the calibrated point on every trial, and the thesis's clipped loss over all 9
    all_project = load_project(Path(args.project), Path(args.data_dir))
    rmse, clipped, at_own = rmse_at(all_project, work / "check", list(TRAIN), best, effects, fixed,
                                    [c for c in TRAIN if c not in held_out])
    shutil.rmtree(work / "check", ignore_errors=True)
    bands = post.summary.get("bands") or {}
    measured = load_dataset(all_project, list(held_out)).measurements
    rows = []
    for cid in held_out:
        b = bands.get(cid, {})
        band_csv = final_run.run_dir.root / "posterior" / "bands" / f"{cid}.csv"
        m = measured.get(cid)
        horizon = (horizon_scores(band_csv, m.force.time_s, m.force.values, m.force_limit_kN)
                   if band_csv.is_file() and m is not None and m.force is not None else {})
        rows.append({"config_id": cid, "rmse_kN": rmse[cid], "rmse_median_kN": b.get("rmse_median_kN"),
                     "rmse_mean_kN": b.get("rmse_mean_kN"), "coverage50": b.get("coverage50"),
                     "coverage90": b.get("coverage90"),
                     "band_width90_kN": b.get("width90_kN"), "crps_kN": b.get("crps_kN"),
                     "interval_score90_kN": b.get("interval_score90_kN"),
                     "rmse_own_contact_kN": at_own.get(cid, {}).get("rmse_kN"),
                     "own_contact_offset_mm": at_own.get(cid, {}).get("offset_mm"), **horizon})
    fig = final_run.run_dir.root / "posterior" / "figures" / "bands.png"
    figure = None
    if fig.exists():
        dest = RESULTS / args.name / f"fold-{k}.png"
        dest.parent.mkdir(parents=True, exist_ok=True)
        small_copy(fig, dest)
        figure = str(dest.relative_to(ROOT))
    return {"fold": k, "name": name, "held_out": list(held_out), "effects": effects, "fixed": fixed,
            "diagnosis": diagnosis, "best_params": best, "rows": rows,
            "train_rmse_kN": {c: v for c, v in rmse.items() if c not in held_out},
            "clipped_loss_sum_kN2": float(sum(clipped.values())), "clipped_errors_kN2": clipped,
            "discrepancy": post.summary.get("discrepancy"), "posterior_warnings": post.warnings,
            "wall_s": times, "reused": reused, "figure": figure}


def horizon_scores(band_csv: Path, time_s: np.ndarray, force_kN: np.ndarray,
                   limit_kN: float) -> dict[str, float]:
    """The predictive mean's RMSE (kN) and the 90 % band's coverage and mean width (kN) over
    the whole band grid of ``band_csv``, the measured closing ``(N,)`` continued at the force
    limit past its end, as the press holds it (``held_at_limit``); empty when the band has
    no predictive curves (every draw failed).

    The library scores a band on the measured closing alone, whose end is the outcome
    itself: past the simulated switch it scores only trials still closing.  This window
    runs to the end of the band's grid instead (1.1 times the latest simulated switch, or
    just past the measured end when that is later), so a band is also judged on predicting
    the limit once the closing has ended.
    """
    from smcbayes.posterior.discrepancy import held_at_limit

    rows = np.genfromtxt(band_csv, delimiter=",", skip_header=1, ndmin=2)
    head = band_csv.read_text(encoding="utf-8").splitlines()[0].split(",")
    col = {h: i for i, h in enumerate(head)}
    if not np.all(np.isfinite(rows[:, col["force_pred_mean_kN"]])):
        return {}
    grid = rows[:, 0]
    t, f = held_at_limit(np.asarray(time_s, float), np.asarray(force_kN, float), limit_kN, float(grid[-1]))
    t, f = t[t <= grid[-1]], f[t <= grid[-1]]
    mean, lo, hi = (np.interp(t, grid, rows[:, col[k]])
                    for k in ("force_pred_mean_kN", "force_pred_q05_kN", "force_pred_q95_kN"))
    return {"rmse_mean_horizon_kN": float(np.sqrt(np.mean((mean - f) ** 2))),
            "coverage90_horizon": float(np.mean((f >= lo) & (f <= hi))),
            "band_width90_horizon_kN": float(np.mean(hi - lo))}


def print_fold(f: dict[str, Any]) -> None:
    """The fold's table."""
    w = f["wall_s"]
    print(f"\nfold {f['fold']} ({f['name']}): effects {', '.join(f['effects']) or 'none'}; workflow "
          f"{w['workflow_s']:.0f} s (" + ", ".join(f"{k[:-2]} {v:.0f} s" for k, v in w.items()
                                                  if k != "workflow_s") + ")")
    print(f"  clipped loss at the calibrated point: {f['clipped_loss_sum_kN2']:.0f} kN^2 summed over 9 "
          f"(thesis best {THESIS_BEST_CLIPPED_KN2:.0f})")
    print(f"  {'held out':<14}{'RMSE kN':>9}{'median':>8}{'mean':>7}{'cov50':>7}{'cov90':>7}{'width90':>9}"
          f"{'CRPS':>7}{'IS90':>8}{'own contact':>13}")

    def g(v: Any, spec: str) -> str:
        width = int(spec.split(".")[0])
        return format(v, spec) if isinstance(v, (int, float)) and v == v else "-".rjust(width)

    for r in f["rows"]:
        print(f"  {r['config_id']:<14}{g(r['rmse_kN'], '9.1f')}{g(r['rmse_median_kN'], '8.1f')}"
              f"{g(r.get('rmse_mean_kN'), '7.1f')}"
              f"{g(r['coverage50'], '7.0%')}{g(r['coverage90'], '7.0%')}{g(r['band_width90_kN'], '9.0f')}"
              f"{g(r['crps_kN'], '7.1f')}{g(r['interval_score90_kN'], '8.0f')}"
              f"{g(r.get('rmse_own_contact_kN'), '7.1f')}{g(r.get('own_contact_offset_mm'), '+6.2f')}")


def totals(folds: list[dict[str, Any]]) -> dict[str, Any]:
    """Means over held-out trials and the targets met."""
    rows = [r for f in folds for r in f["rows"]]
    timed = [f for f in folds if not f.get("reused")]  # a reused fold's steps were not all timed

    def mean(key: str) -> float:
        vals = [r[key] for r in rows if isinstance(r.get(key), (int, float)) and r[key] == r[key]]
        return float(np.mean(vals)) if vals else float("nan")

    ok_rmse = all(r["rmse_kN"] <= 70.0 for r in rows)
    ok_cov = all(r["coverage90"] is not None and 0.80 <= r["coverage90"] <= 0.97 for r in rows)
    ok_width = all(r["band_width90_kN"] is not None and r["band_width90_kN"] <= 4 * r["rmse_kN"]
                   for r in rows)
    return {"trials": len(rows), "mean_rmse_kN": mean("rmse_kN"),
            "max_rmse_kN": max(r["rmse_kN"] for r in rows),
            "mean_rmse_median_kN": mean("rmse_median_kN"),
            "mean_rmse_mean_kN": mean("rmse_mean_kN"), "mean_coverage50": mean("coverage50"),
            "mean_coverage90": mean("coverage90"), "mean_band_width90_kN": mean("band_width90_kN"),
            "mean_crps_kN": mean("crps_kN"), "mean_rmse_own_contact_kN": mean("rmse_own_contact_kN"),
            "mean_rmse_mean_horizon_kN": mean("rmse_mean_horizon_kN"),
            "mean_coverage90_horizon": mean("coverage90_horizon"),
            "mean_band_width90_horizon_kN": mean("band_width90_horizon_kN"),
            "own_contact_le_70kN": sum(1 for r in rows if (r.get("rmse_own_contact_kN") or np.inf) <= 70.0),
            "le_70kN": {key: sum(1 for r in rows if (r.get(key) or np.inf) <= 70.0)
                        for key in ("rmse_kN", "rmse_median_kN", "rmse_mean_kN", "rmse_mean_horizon_kN")},
            "wall_s_per_fold": [f["wall_s"]["workflow_s"] for f in folds],
            "targets": {"rmse_le_70kN_every_trial": ok_rmse, "coverage90_80_97_every_trial": ok_cov,
                        "width90_le_4rmse_every_trial": ok_width,
                        "workflow_le_15min_every_fold": all(f["wall_s"]["workflow_s"] <= 900 for f in timed)
                        if timed else None}}


def parse() -> argparse.Namespace:
    from smcbayes.config.settings import CalibrationSpec, DiagnoseSpec, PosteriorSpec, choices_of

    def d(spec: Any, name: str) -> Any:
        return spec.model_fields[name].default

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fold", type=int, action="append", choices=range(len(FOLDS)),
                    help="run this fold only (repeatable; default: all six)")
    ap.add_argument("--jobs", type=int, default=1, help="folds run in parallel processes")
    ap.add_argument("--effects", type=lambda s: [e for e in s.split(",") if e], default=None,
                    help="skip the diagnosis and add these effects (comma separated; '' for none)")
    ap.add_argument("--candidates", type=lambda s: s.split(","), default=None,
                    help="candidate effects of the diagnosis (default: all)")
    ap.add_argument("--workdir", default=None,
                    help="folds' work directories (default: benchmarks/results/NAME/work)")
    ap.add_argument("--reuse", action="store_true",
                    help="keep each fold's calibrations and diagnosis in --workdir when made with the same "
                         "settings, finish what is missing and rerun the posterior (whose stage cache "
                         "reuses its forward runs)")
    ap.add_argument("--data-dir", default=str(DATA))
    ap.add_argument("--project", default=str(PROJECT),
                    help="project file whose settings and trials the folds use "
                         "(default: configs/thesis.toml); "
                         "a variant of it tests another loss or parameter box")
    ap.add_argument("--name", default="real_crossval",
                    help="results file benchmarks/results/NAME.json, figures and work directories in "
                         "NAME/ (a variant's run keeps the default's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--budget", type=int, default=d(CalibrationSpec, "budget"))
    ap.add_argument("--init", type=int, default=d(CalibrationSpec, "init"))
    ap.add_argument("--population", type=int, default=d(DiagnoseSpec, "population"))
    ap.add_argument("--generations", type=int, default=d(DiagnoseSpec, "generations"))
    ap.add_argument("--restarts", type=int, default=d(DiagnoseSpec, "restarts"))
    ap.add_argument("--walkers", type=int, default=d(PosteriorSpec, "walkers"))
    ap.add_argument("--steps", type=int, default=d(PosteriorSpec, "steps"))
    ap.add_argument("--functions", type=int, default=d(PosteriorSpec, "functions"))
    ap.add_argument("--refine", type=int, default=d(PosteriorSpec, "refine"))
    ap.add_argument("--correct-draws", type=int, default=d(PosteriorSpec, "correct_draws"))
    ap.add_argument("--round-runs", type=int, default=d(PosteriorSpec, "round_runs"),
                    help="forward runs per active-learning round (smcbayes posterior --round-runs)")
    ap.add_argument("--draws", type=int, default=d(PosteriorSpec, "draws"))
    ap.add_argument("--emulator", choices=choices_of(PosteriorSpec, "emulator"),
                    default=d(PosteriorSpec, "emulator"),
                    help="the posterior's emulator (smcbayes posterior --emulator)")
    return ap.parse_args()


def main() -> int:
    """Run the folds, print their tables and totals, write the JSON."""
    args = parse()
    if not Path(args.data_dir).is_dir():
        print(f"skipped: no measured data at {args.data_dir} (pass --data-dir)")
        return 0
    ks = sorted(set(args.fold)) if args.fold else list(range(len(FOLDS)))
    start = time.perf_counter()
    if args.jobs > 1 and len(ks) > 1:
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            folds = list(pool.map(run_fold, ks, [args] * len(ks)))
    else:
        folds = [run_fold(k, args) for k in ks]
    for f in folds:
        print_fold(f)
    path = RESULTS / f"{args.name}.json"
    old = json.loads(path.read_text()) if args.fold and path.exists() else {}
    merged = {f["fold"]: f for f in old.get("folds", [])}
    merged.update({f["fold"]: f for f in folds})
    all_folds = [merged[k] for k in sorted(merged)]
    out = {"settings": {k: v for k, v in vars(args).items() if k not in ("fold",)},
           "thesis_best_clipped_kN2": THESIS_BEST_CLIPPED_KN2, "folds": all_folds,
           "totals": totals(all_folds), "wall_s_this_call": time.perf_counter() - start}
    tot = out["totals"]
    print(f"\n{tot['trials']} held-out trials: mean RMSE {tot['mean_rmse_kN']:.1f} kN (max "
          f"{tot['max_rmse_kN']:.1f}), median-curve RMSE {tot['mean_rmse_median_kN']:.1f} kN, "
          f"predictive-mean RMSE {tot['mean_rmse_mean_kN']:.1f} kN ({tot['le_70kN']['rmse_mean_kN']} "
          f"within 70 kN, {tot['le_70kN']['rmse_kN']} at the calibrated point), coverage "
          f"50 % {tot['mean_coverage50']:.0%}, 90 % {tot['mean_coverage90']:.0%}, 90 % width "
          f"{tot['mean_band_width90_kN']:.0f} kN, CRPS {tot['mean_crps_kN']:.1f} kN")
    if np.isfinite(tot["mean_rmse_own_contact_kN"]):
        print(f"at each held-out trial's own contact offset (known only after the trial): mean RMSE "
              f"{tot['mean_rmse_own_contact_kN']:.1f} kN, {tot['own_contact_le_70kN']} of {tot['trials']} "
              "within 70 kN")
    if np.isfinite(tot["mean_rmse_mean_horizon_kN"]):
        within = tot["le_70kN"]["rmse_mean_horizon_kN"]
        print(f"over each band's grid, the closing held at the force limit past its end: predictive-mean "
              f"RMSE {tot['mean_rmse_mean_horizon_kN']:.1f} kN ({within} within 70 kN), 90 % coverage "
              f"{tot['mean_coverage90_horizon']:.0%} at "
              f"{tot['mean_band_width90_horizon_kN']:.0f} kN")
    verdict = {True: "met", False: "MISSED", None: "not judged (reused folds are not timed)"}
    print("targets: " + ", ".join(f"{k} {verdict[v]}" for k, v in tot["targets"].items()))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2, default=float) + "\n", encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
