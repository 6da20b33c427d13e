"""Settings of the stages, each a validated table of the project file with its defaults.

``[calibration]``, ``[posterior]`` and ``[diagnose]`` in the project TOML fill these
models; command-line options override single fields (:func:`override`).  The defaults
written here are the only ones: the command line shows them in ``--help`` and the library
functions take these objects.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from smcbayes.errors import ConfigError


class Strict(BaseModel):
    """Base model: unknown keys are errors, objects are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class CodeBuilt(Strict):
    """Settings that library code and scripts build by keyword: a bad value raises
    :class:`ConfigError` naming the field (not pydantic's multi-line error)."""

    def __init__(self, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as err:
            e = err.errors()[0]
            where = ".".join(str(p) for p in e["loc"]) or type(self).__name__
            raise ConfigError(f"{type(self).__name__}.{where} = {e.get('input')!r}: "
                              f"{e['msg'].removeprefix('Value error, ')}") from None


POLISH_FAST = 600
"""Default budget of the calibration's local search with a fast simulator: about 5 s of the
1-D model on six press trials.  With 7-8 free parameters Powell's method may need a few
times more to meet its own tolerance, but the first few hundred evaluations make most of
its gain (README, "Calibration")."""


class CalibrationSpec(Strict):
    """Settings of ``smcbayes calibrate`` (Bayesian optimisation); CLI options override them."""

    budget: int = Field(60, ge=2, le=100000, description="total evaluations, initial design included")
    init: int = Field(20, ge=2, le=100000, description="Latin hypercube initial design size")
    batch: int = Field(1, ge=1, le=256, description="candidates per round (qLogEI when > 1)")
    kernel: Literal["rbf", "matern52"] = "matern52"
    tolerance: float = Field(0.0, ge=0.0, lt=1.0,
                             description="stop when the best loss improves by less than this "
                                         "fraction over `patience` rounds (0: off)")
    patience: int = Field(10, ge=1, le=100000)
    seed: int = Field(0, ge=0, description="random seed; same seed, same run, interrupted or not")
    failed: Literal["impute", "exclude"] = Field(
        "impute", description="failed evaluations: imputed at the worst loss seen, or left out")
    retries: int = Field(
        3, ge=0, le=10, description="extra attempts of a simulation that failed or timed out before "
                                    "its configuration counts as failed (external solvers; the native "
                                    "model's failures repeat and are not retried)")
    worker_timeout_s: float = Field(
        300.0, gt=0, description="--scheduler: stop with an error after this long (s) without any "
                                 "Dask worker")
    truth: dict[str, float] | None = Field(
        None, description="synthetic check: 'measured' curves simulated at these values")
    restarts: int = Field(8, ge=1, le=1000, description="acquisition optimiser restarts")
    raw_samples: int = Field(256, ge=8, le=100000, description="acquisition optimiser raw samples")
    noise: float | Literal["fit"] = Field(
        1e-6, description="GP noise variance of log(loss): a small fixed value for a "
                          "deterministic simulator, or 'fit' to fit a noise term (thesis)")
    local_evaluations: int = Field(
        0, ge=0, description="final evaluations searched in a box around the best point")
    local_radius: float = Field(0.1, gt=0, le=0.5,
                                description="half-width of that box in unit-cube coordinates")
    polish: int | None = Field(
        None, ge=0, le=100000,
        description=f"most evaluations of a local search (Powell's method) from the best point "
                    f"after the Bayesian optimisation, run on the forward model itself; default "
                    f"{POLISH_FAST} with the built-in 1-D model, whose evaluations cost "
                    f"milliseconds, and 0 with an external simulator or the 2-D solver; 0: off")

    def polish_evaluations(self, fast: bool) -> int:
        """The local search's budget: ``polish`` when given, else :data:`POLISH_FAST` for a
        ``fast`` simulator (the built-in 1-D model) and 0 for a slow one."""
        if self.polish is not None:
            return self.polish
        return POLISH_FAST if fast else 0

    @property
    def noise_variance(self) -> float | None:
        """The GP's fixed noise variance, or ``None`` when the noise is fitted."""
        return None if self.noise == "fit" else float(self.noise)

    def check(self) -> None:
        """Raise :class:`ConfigError` for settings that contradict each other."""
        if self.budget < self.init:
            raise ConfigError(f"calibration: need init ({self.init}) <= budget ({self.budget})")


class CorrectionSpec(CodeBuilt):
    """Settings of the importance-sampling correction of the posterior
    (``[posterior.correction]``; ``[posterior] correct_draws``, when given, overrides its ``draws``).

    Attributes:
        draws: most proposal draws in total (points outside the prior box cost no forward run).
        per_iteration: proposal draws per AMIS iteration.
        ess_target, k_target: stop early, after at least two iterations, once the smoothed
            weights have an ESS >= ess_target and a Pareto k-hat <= k_target.  An ESS of
            2000, not a few hundred: a second region holding a few per cent of the posterior
            moves the correlations by up to 0.2, and its estimated mass settles only as the
            proposals keep drawing there; neither the ESS nor k-hat sees a region that is
            under-drawn (``benchmarks/posterior_accuracy.py``).
        centres: kernels M of the mixture proposal.
        nu: degrees of freedom of the Student-t kernels.
        defensive: share beta of the uniform prior in every proposal.  A quarter: the
            emulator can miss a second region of high posterior density altogether, and only
            the uniform draws can find it (with 10 % the corrected correlations of a
            two-region test posterior were off by 0.18-0.29 over four seeds, with 25 % by
            0.10-0.21, for a similar number of forward runs: 2,983-3,743 against 2,081-4,258).
        widen_first: bandwidth factor of the first proposal (fitted to emulator draws).
        widen: bandwidth factor of the later proposals.
        ess_floor: minimum effective sample size of the tempered weights a proposal is fitted to.
        fit_temperature: exponent T of the tempered posterior pi^T the proposals are fitted
            to (see the module docstring; 1: fitted to pi).  With 1/2 the accuracy
            benchmark's quantile and correlation errors over eight seeds (fixed emulator
            start) fell from 0.086 and 0.130 on average to 0.069 and 0.081 in its first case
            and from 0.057 and 0.116 to 0.053 and 0.097 in its second.  The cost: the draws now
            run out on both (10,200-10,900 forward runs, were 8,900-10,900), and the coverage
            benchmark spends 7,200 runs per dataset (was 5,500); the thesis posterior still
            stops at ESS 2000 after about 2,300 runs.
        local: kernels shaped by the centres' nearest neighbours (see :func:`fit_proposal`).
        clusters: components of the Gaussian mixture that shapes the kernels and shares out
            the centres (see :func:`fit_proposal`); 1: one global covariance, centres drawn
            in proportion to the weights.  With 1, the accuracy benchmark's thin second
            region was drawn with kernels shaped for the main one: correlation errors of
            0.15-0.21 remained after 10,500 forward runs (four seeds).
        chains: centres carried by Metropolis-Hastings chains on the exact posterior (the
            rest are drawn afresh every iteration; at most ``centres``; 0: none).  A chain
            moves at most once per iteration, with the first draw of its own kernel, so it
            costs no forward run; a chain that reaches a long arm of the posterior walks
            along it (see the module docstring and ``benchmarks/posterior_accuracy.py``).
            The correction then needs more draws to reach its ESS target, since chains
            started where the emulator was wrong walk in slowly.
        batch: points per forward call.
    """

    draws: int = Field(14000, ge=0,
                        description="most proposal draws in total "
                                    "(points outside the prior box cost no forward run)")
    per_iteration: int = Field(500, ge=1, description="proposal draws per iteration")
    ess_target: float = Field(2000.0, gt=0,
                               description="stop early once the smoothed weights "
                                           "have at least this importance ESS")
    k_target: float = Field(0.5, gt=0, description="... and a Pareto k-hat at most this")
    centres: int = Field(200, ge=1, description="Student-t kernels of the mixture proposal")
    nu: float = Field(5.0, gt=0, description="degrees of freedom of the Student-t kernels")
    defensive: float = Field(0.25, ge=0, lt=1, description="share of the uniform prior in every proposal")
    widen_first: float = Field(1.5, gt=0,
                                description="bandwidth factor of the first proposal "
                                            "(fitted to emulator draws)")
    widen: float = Field(1.0, gt=0, description="bandwidth factor of the later proposals")
    ess_floor: float = Field(50.0, gt=0,
                              description="minimum ESS of the tempered weights a proposal is fitted to")
    batch: int = Field(500, ge=1, description="points per forward call")
    local: bool = Field(False, description="kernels shaped by the centres' nearest neighbours")
    clusters: int = Field(8, ge=1, description="components of the Gaussian mixture that shapes the kernels")
    chains: int = Field(100, ge=0,
                         description="centres carried by Metropolis-Hastings chains on the exact posterior")
    fit_temperature: float = Field(0.5, gt=0, le=1,
                                    description="exponent T of the tempered posterior "
                                                "pi^T the proposals are fitted to")


REFINE_EMULATED = 800
"""Default budget of the active learning when the emulator's posterior is reported alone."""
REFINE_CORRECTED = 400
"""... and when the importance correction follows, which needs the emulator as a proposal
that covers the posterior, not validated to a nat."""

REFINE_CURVES = 1400
"""Default active-learning budget of the curve emulator (``emulator = "curves"``), which
learns from whole force curves and stops once validated and confirmed: on the synthetic
accuracy benchmark after 411-731 forward runs in all (the calibration's included), on the
nine measured thesis trials (7 free parameters) after 621-1,381 and on three of the six
cross-validation folds after 581-1,221; the other three folds spend it unvalidated."""

ROUND_RUNS_CURVES = 40
"""Default forward runs per active-learning round of the curve emulator: 30 posterior draws,
whose errors validate the round, and 10 exploring."""
ROUND_RUNS_LOSS = (9, 30)
"""Fewest and most forward runs per active-learning round of the log-loss emulator by
default: a quarter of its budget within these."""


class PosteriorSpec(Strict):
    """Settings of ``smcbayes posterior``; CLI options override them."""

    emulator: Literal["auto", "loss", "curves"] = Field(
        "auto", description="what the GP emulates: 'curves', each training configuration's force curve, "
                            "the likelihood then computed from the emulated curves (a loss at the "
                            "nominal contact or the end state's, without the displacement term, "
                            "clipped 'none' or 'flow_stop'; its posterior is sampled by importance on "
                            "the emulator, without a correction unless correct_draws asks for one); "
                            "'loss', the log loss (any loss settings); 'auto': 'curves' where the "
                            "project's loss and data allow it (not on noise-free curves, nor without "
                            "the flow-stop times or end states the loss needs), else 'loss'")
    walkers: int = Field(32, ge=4, le=10000, description="emcee walkers")
    steps: int = Field(10000, ge=1, le=10_000_000, description="maximum steps per chain")
    functions: int = Field(0, ge=0, le=1000,
                           description="GP sample functions whose posteriors alone make the sampled "
                                       "mixture (0: the GP mean's posterior, pooled with those of the "
                                       "spread check's sample functions when pool_functions is on)")
    pool_functions: bool = Field(True, description="carry the emulator's uncertainty into the reported "
                                                   "posterior: pool the GP mean's posterior with those of "
                                                   "the spread check's GP sample functions, so that what "
                                                   "the GP cannot rule out widens the result (not with "
                                                   "functions > 0, the correction or noise-free data)")
    refine: int | None = Field(
        None, ge=0, le=1_000_000,
        description=f"most forward evaluations of the active learning of the emulator (rounds of "
                    f"fresh posterior draws and exploring points: where the GP is unsure and a "
                    f"tempered posterior could be large with the log-loss emulator, draws of the "
                    f"posterior mass the expected loss's variance hides with the curve one; it "
                    f"stops earlier once validated and GP sample functions no longer move the "
                    f"posterior); default {REFINE_CURVES} with the "
                    f"curve emulator; with the log-loss one {REFINE_EMULATED}, or "
                    f"{REFINE_CORRECTED} when the importance correction follows (it needs a "
                    f"proposal, not a validated emulator)")
    round_runs: int | None = Field(
        None, ge=ROUND_RUNS_LOSS[0], le=400,
        description=f"forward runs per active-learning round, one batch through the executor (with a "
                    f"Dask scheduler each run on each training configuration is one task, so a round "
                    f"is this times the configurations in tasks); the emulator learns between rounds "
                    f"only, so rounds larger or smaller than the default change how many runs it "
                    f"needs, either way; default {ROUND_RUNS_CURVES} with the curve emulator, a "
                    f"quarter of the budget within {ROUND_RUNS_LOSS[0]}-{ROUND_RUNS_LOSS[1]} with "
                    f"the log-loss one")
    draws: int = Field(100, ge=1, le=1_000_000,
                       description="posterior draws through the forward model for bands and checks")
    seed: int = Field(0, ge=0, description="random seed (same seed, same posterior)")
    threads: int | None = Field(None, ge=1, le=1024,
                                description="threads of the emulator's arithmetic (sample functions and "
                                            "batches of the importance samples run side by side); "
                                            "default: the cores this process may use; the posterior is "
                                            "the same to the last digit whatever the number")
    refine_tolerance_nats: float = Field(
        1.0, gt=0, description="active learning stops once the emulator's out-of-sample error at "
                               "fresh posterior draws is below this (nats) in three rounds in a row, "
                               "the quantiles are stable (each round and over the three) and the "
                               "emulator's spread is at most 0.10")
    correct_draws: int | None = Field(
        None, ge=0, le=10_000_000,
        description=f"most proposal draws of the importance correction by the exact forward model "
                    f"(each inside the prior box costs a forward run); default: 0 with the curve "
                    f"emulator (its validated posterior is reported) and with the log-loss one "
                    f"for an external simulator or the 2-D solver, "
                    f"{CorrectionSpec.model_fields['draws'].default} ([posterior.correction] draws) "
                    f"with the log-loss emulator and the built-in 1-D model, whose runs cost "
                    f"milliseconds; 0: the actively learned emulator's posterior alone")
    correction: CorrectionSpec = Field(CorrectionSpec(), description="the importance correction's "
                                       "other settings ([posterior.correction])")

    def resolved(self, slow: bool, *, curves: bool) -> PosteriorSpec:
        """These settings with the defaults that depend on the simulator, the loss and the
        emulator filled in (``emulator``, ``correct_draws``, ``refine``, ``round_runs``).

        ``auto`` takes the curve emulator where the project's loss and data allow it
        (``curves``, as the posterior stage finds), else the log-loss one.  The curve
        emulator's validated posterior is reported without a correction unless asked: on
        the synthetic accuracy benchmark it met every target
        after 411-731 forward runs in all, where the log-loss emulator needs the correction's
        11,000-12,000 runs of the built-in 1-D model to meet them.  With the log-loss
        emulator the stage corrects the emulated posterior by the exact one with the
        built-in 1-D model (a forward run costs milliseconds); with a ``slow`` one (an
        external simulator, whose run may take minutes, or the 2-D solver's seconds) it
        reports the emulator's posterior alone unless asked.  The active learning's budget
        and round size follow from the emulator and the correction.
        """
        emulator = ("curves" if curves else "loss") if self.emulator == "auto" else self.emulator
        draws = self.correct_draws if self.correct_draws is not None else \
            (0 if slow or emulator == "curves" else self.correction.draws)
        refine = self.refine if self.refine is not None else REFINE_CURVES if emulator == "curves" else \
            (REFINE_CORRECTED if draws > 0 else REFINE_EMULATED)
        rounds = self.round_runs if self.round_runs is not None else ROUND_RUNS_CURVES \
            if emulator == "curves" else min(max(refine // 4, ROUND_RUNS_LOSS[0]), ROUND_RUNS_LOSS[1])
        return self.model_copy(update={"emulator": emulator, "correct_draws": draws, "refine": refine,
                                       "round_runs": rounds})


class DiagnoseSpec(Strict):
    """Settings of ``smcbayes diagnose``; CLI options override them."""

    effects: list[str] | None = Field(None, description="candidate effects (default: all not already on)")
    holdout: list[str] | None = Field(
        None, description="held-out configurations (default: the middle speed of each charge group)")
    pair: bool = Field(False, description=("also re-calibrate two effects together: the named "
                                           "one and the best-scoring other"))
    seed: int = Field(0, ge=0, description="random seed (same seed, same ranking)")
    population: int = Field(64, ge=5, le=100000, description="parameter sets per generation")
    generations: int = Field(50, ge=1, le=100000,
                             description="optimiser generations per re-calibration")
    restarts: int = Field(2, ge=1, le=1000,
                          description="independent evolutions per re-calibration, the best kept")
    min_score: float = Field(3.0, description="penalised held-out score (log Bayes factor) needed to "
                                              "name an effect; candidates scoring within it of the "
                                              "best are told apart by their evidence on all trials")
    max_effects: int = Field(3, ge=1, le=10,
                             description="forward selection grows the named effect set up to this size, "
                                         "adding an effect while it scores min_score against the set "
                                         "(1: the best single effect only)")


def override(spec: BaseModel, values: Mapping[str, Any], source: str = "command line") -> Any:
    """Copy of ``spec`` with the non-``None`` ``values`` set, validated again.

    Raises:
        ConfigError: one line naming the option and what is accepted.
    """
    given = {k: v for k, v in values.items() if v is not None}
    if not given:
        return spec
    try:
        return type(spec).model_validate({**spec.model_dump(), **given})
    except ValidationError as err:
        e = err.errors()[0]
        name = str(e["loc"][0]) if e["loc"] else "?"
        flag = "--" + name.replace("_", "-")
        raise ConfigError(f"{source}: {flag} {e.get('input')!r}: "
                          f"{e['msg'].removeprefix('Value error, ')}") from None


def default_of(spec: type[BaseModel], name: str) -> Any:
    """The default of one field (for ``--help`` texts)."""
    return spec.model_fields[name].default


def choices_of(spec: type[BaseModel], name: str) -> tuple[str, ...]:
    """The values a ``Literal`` field allows (for ``choices=`` of a command-line option)."""
    return tuple(get_args(spec.model_fields[name].annotation))


def help_of(spec: type[BaseModel], name: str) -> str:
    """``description (default X)`` of one field, for ``--help``."""
    field = spec.model_fields[name]
    text = field.description or name
    # a default of None is resolved at run time, and the description says how
    return text if field.default is None else f"{text} (default {field.default})"
