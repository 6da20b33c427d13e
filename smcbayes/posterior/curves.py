"""An emulator of the forward model's force curves, and the likelihood computed from them.

The posterior stage's default emulator is a GP of the scalar log loss.  That target is
hard: with N_eff / 2 of order 25-75, one nat of log-likelihood is about 1-4 % of the loss,
and the loss has kinks and flat arms where a parameter stops acting (wall slip that
switches off, a yield stress above every flow stress).  The force curves themselves are
smooth and nearly log-linear in the unit-cube (log) coordinates, so this module emulates
the curves and computes the loss from the emulated curves, exactly as the loss computes it
from simulated ones (calibrate-emulate-sample: Cleary, Garbuno-Inigo, Lan, Schneider &
Stuart 2021, "Calibrate, emulate, sample", J. Comput. Phys. 424, 109716; output
emulation by principal components: Higdon, Gattiker, Williams & Rightley 2008, "Computer
model calibration using high-dimensional output", JASA 103, 570).

Features of one parameter row: each training configuration's force at ``n`` nodes evenly
spaced in time over [0, t_switch] (the built-in solver's own closing output nodes, so
nothing is lost in the resampling), its switch time t_switch and, with the contact of the
end state, its end height (mm).  The emulator: principal
components of log(F + 1 kN) over the training rows (as many as bring the reconstruction
error of the best third of the rows below ``tolerance``), a linear trend in the unit-cube
coordinates by least squares, and a GP with one Matern-5/2 correlation (ARD lengthscales,
nugget, fitted by the concentrated likelihood of the leading components) and one scale
per output on the residuals.  The expected loss adds the emulator's variance of the
squared error, so that where the emulator is unsure the likelihood is lower, not
arbitrary.

The scales are fitted over the whole training set, the calibration's points far out included;
where the posterior lives the points are dense and the outputs smoother, and the GP's
variance there can be several times too large (on the measured thesis trials the leading
components' errors at fresh posterior draws were 0.4-0.8 of the predicted sd).
:meth:`CurveEmulator.calibrate` rescales each output's variance by its mean squared
standardised leave-one-out error at chosen rows (the active learning's latest batches):
the cross-validation estimate of a GP's variance, which stays right where the covariance
model is misspecified (Bachoc 2013, "Cross validation and maximum likelihood estimations
of hyper-parameters of Gaussian processes with model misspecification", Comput. Stat.
Data Anal. 66, 55), here on the region the posterior samples.

Loss settings covered: contact at the nominal stack height or from each trial's end state
(the end height, gap at the switch plus set speed times switch time, is one more emulated
output per configuration), no displacement term, clip ``none`` or ``flow_stop``
(:class:`CurveLossUnsupported` otherwise).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.linalg.lapack import dpotri
from scipy.optimize import minimize

from smcbayes.errors import ConfigError
from smcbayes.forward.nodes import interp_rows
from smcbayes.forward.result import SimulationResult
from smcbayes.posterior._blocks import BLOCK, PARALLEL_ROWS
from smcbayes.posterior.threads import in_worker
from smcbayes.simulation.problem import Problem

Array = NDArray[np.float64]

FORCE_FLOOR_KN = 1.0
"""Added before the log of the force: keeps log(F) finite at first contact."""

CALIBRATION_MIN_POINTS = 20
"""Fewest rows whose leave-one-out errors may calibrate the outputs' variances."""

CALIBRATION_BOUNDS = (0.05, 20.0)
"""Range of an output's variance factor: rows that happen to sit on the mean (or one wild
row) cannot make the emulator certain (or useless)."""

FIT_COMPONENTS = 8
"""Leading principal components whose likelihood sets the shared correlation."""

LENGTHSCALE_BOUNDS = (0.02, 5.0)
"""Lengthscale bounds in the unit cube: beyond a few cube widths the linear trend already
describes a direction."""

NUGGET_BOUNDS = (1e-9, 1e-1)
"""Bounds of the correlation's nugget (a share of each output's variance); :data:`JITTER`
is added to the diagonal besides."""

JITTER = 1e-8
"""Added to the correlation's diagonal besides the nugget: a margin that keeps the matrix
numerically positive definite, and its Cholesky factorisation possible, with a nugget at
its lower bound."""


class CurveLossUnsupported(ConfigError):
    """The project's loss needs more of a simulation than the emulated force curves."""


class CurveFeatures:
    """The loss's view of a simulation: force at nodes evenly spaced over [0, t_switch],
    t_switch and, with the contact of the end state, the end height, per training
    configuration.

    Args:
        problem: the calibration problem (training configurations, data, loss, solver).
        nodes: nodes per configuration (default: the solver's closing output points).
    """

    def __init__(self, problem: Problem, nodes: int | None = None) -> None:
        spec = problem.project.loss
        if spec.contact_mode == "profile" or spec.w_displacement > 0 or spec.clip == "force_limit":
            raise CurveLossUnsupported(
                "the curve emulator covers a loss at the nominal contact or the contact of the end state, "
                "without the displacement term, clipped 'none' or 'flow_stop' (this project: contact "
                f"'{spec.contact_mode}', w_displacement {spec.w_displacement}, clip '{spec.clip}')")
        self.ids = list(problem.train_ids)
        self.spec = spec
        self.measured = [problem.dataset.measurements[cid] for cid in self.ids]
        self.nodes = int(nodes or problem.project.solver.output_closing_points)
        self.tau = np.linspace(0.0, 1.0, self.nodes)
        self.grid = np.linspace(0.0, 1.0, spec.grid_points)
        self.end_state = spec.contact_mode == "end_state"
        if spec.clip == "flow_stop" and any(m.flow_stop_s is None for m in self.measured):
            raise CurveLossUnsupported("clip 'flow_stop' needs every training trial's flow-stop time")
        if self.end_state and any(m.end_stack_mm is None or not m.speed_mm_s for m in self.measured):
            raise CurveLossUnsupported("contact 'end_state' needs every training trial's end state and "
                                       "set speed")
        self._end_stack = np.array([m.end_stack_mm if self.end_state else 0.0 for m in self.measured], float)
        self._speed = np.array([m.speed_mm_s if self.end_state else 1.0 for m in self.measured], float)
        self._grids: tuple[Array, Array, Array, Array, NDArray[np.int64]] | None = None

    @property
    def size(self) -> int:
        """Features per row: K n forces (kN), K switch times (s) and, with the contact of
        the end state, K end heights (mm)."""
        return len(self.ids) * (self.nodes + 1 + int(self.end_state))

    def of(self, results: Mapping[str, SimulationResult]) -> tuple[Array, NDArray[np.bool_]]:
        """Features ``(P, size)`` of simulated rows and the rows that succeeded ``(P,)``.

        The end height of a row is its gap at the switch plus the set speed times the
        switch time (mm; :func:`smcbayes.data.loss.end_state_offsets_mm`): emulated as one
        output rather than from the gap and the switch time, whose errors it would add."""
        forces, switches, ends = [], [], []
        ok = np.ones(results[self.ids[0]].rows, dtype=bool)
        for cid, m in zip(self.ids, self.measured, strict=True):
            r = results[cid]
            good = r.ok & np.all(np.isfinite(r.time_s), axis=1) & np.all(np.isfinite(r.force_kN), axis=1)
            t = np.where(good[:, None], r.time_s, np.arange(r.time_s.shape[1])[None, :])
            f = np.where(good[:, None], r.force_kN, 0.0)
            ts = np.where(good & np.isfinite(r.switch_time_s), r.switch_time_s, t[:, -1])
            forces.append(interp_rows(ts[:, None] * self.tau[None, :], t, f))
            switches.append(ts)
            if self.end_state:
                gap = interp_rows(ts[:, None], t, np.where(good[:, None], r.gap_mm, 0.0))[:, 0]
                end = gap + m.speed_mm_s * ts
                # the loss places such a row at the nominal contact (offset 0)
                ends.append(np.where(np.isfinite(end), end, m.end_stack_mm))
            ok &= good
        return np.hstack(forces + [np.column_stack(switches + ends)]), ok

    def _measured_grids(self) -> tuple[Array, Array, Array, Array, NDArray[np.int64]]:
        """The measured curves as :func:`~._curve_kernel.loss_rows` reads them: each
        configuration's usual window end ``(K,)`` (s) and its measured force on that window's
        grid ``(K, G)`` (kN), and the curves concatenated with their starts ``(K + 1,)``;
        interpolated once per instance, as every call compares with the same curves."""
        if self._grids is None:
            from smcbayes.posterior._curve_kernel import measured_on_grid  # numba loads on first use

            flow_stop = self.spec.clip == "flow_stop"
            ends = np.array([m.flow_stop_s if flow_stop else m.force.time_s[-1] for m in self.measured],
                            dtype=float)
            times = [np.asarray(m.force.time_s, dtype=float) for m in self.measured]
            forces = [np.asarray(m.force.values, dtype=float) for m in self.measured]
            common = np.empty((len(self.measured), self.grid.shape[0]))
            for k in range(len(self.measured)):
                measured_on_grid(float(ends[k]), self.grid, times[k], forces[k], common[k])
            starts = np.concatenate([[0], np.cumsum([len(t) for t in times])]).astype(np.int64)
            self._grids = (ends, common, np.concatenate(times), np.concatenate(forces), starts)
        return self._grids

    def loss(self, features: Array) -> Array:
        """The global loss ``(P,)`` (kN^2) of features ``(P, size)``, as
        :func:`smcbayes.data.loss.evaluate_loss` computes it from the simulations (both
        curves linearly interpolated onto the window's grid; :mod:`._curve_kernel`).  Each
        configuration's delay (s) of the simulated closing is 0 at the nominal contact and,
        from the end state, the contact offset (clipped to +-``contact_offset_mm`` when
        above 0) over the set speed."""
        from smcbayes.posterior._curve_kernel import loss_rows, loss_rows_parallel  # numba loads on first use

        features = np.ascontiguousarray(features, dtype=float)
        if features.ndim != 2 or features.shape[1] != self.size:
            # the compiled kernel would read the next row's values, or past the last one
            raise ValueError(f"curve features of shape {features.shape}: {self.size} per row expected")
        ends, common, times, forces, starts = self._measured_grids()
        out = np.empty(features.shape[0])
        args = (features, self.nodes, self.end_state, self.spec.clip == "flow_stop",
                float(self.spec.contact_offset_mm), self._end_stack, self._speed, ends, common, self.grid,
                times, forces, starts, out)
        if len(out) >= PARALLEL_ROWS and not in_worker():
            loss_rows_parallel(*args, BLOCK)
        else:
            loss_rows(*args)
        return self.spec.w_force * out / len(self.ids)


def matern52(a: Array, b: Array | None, lengthscales: Array) -> Array:
    """Matern-5/2 correlation ``(N, M)`` of points ``a (N, d)`` and ``b (M, d)``,
    lengthscales ``(d,)``; with ``b`` None, of ``a`` with itself ``(N, N)``, exactly
    symmetric (:mod:`._matern_kernel`)."""
    from smcbayes.posterior._matern_kernel import (  # numba loads on first use
        matern52_rows,
        matern52_rows_parallel,
        matern52_self,
    )

    sa = np.ascontiguousarray(np.asarray(a, dtype=float) / lengthscales)
    if b is not None and np.shape(b)[1] != sa.shape[1]:
        # the kernel would read past the shorter rows
        raise ValueError(f"matern52: points of {sa.shape[1]} and {np.shape(b)[1]} coordinates")
    if b is None:
        out = np.empty((len(sa), len(sa)))
        matern52_self(sa, np.ascontiguousarray(sa.T), out)
        return out
    out = np.empty((len(sa), len(b)))
    sbt = np.ascontiguousarray((np.asarray(b, dtype=float) / lengthscales).T)
    if len(sa) >= PARALLEL_ROWS and not in_worker():
        matern52_rows_parallel(sa, sbt, out, BLOCK)
    else:
        matern52_rows(sa, sbt, out)
    return out


@dataclass
class _Correlation:
    lengthscales: Array
    nugget: float
    chol: Array


def _concentrated_nll(params: Array, x: Array, z: Array) -> tuple[float, Array]:
    """Negative log likelihood of outputs ``z (N, J)`` under one correlation, each output's
    scale profiled out, and its gradient ``(d + 1,)`` in ``params`` (the log lengthscales
    ``(d,)`` and the log nugget).

    With ``q_j = z_j' R^-1 z_j`` and ``a_j = R^-1 z_j``, the likelihood
    ``N/2 sum_j log(q_j / N) + J/2 log|R|`` has derivative ``1/2 tr(W dR)`` with
    ``W = J R^-1 - sum_j (N / q_j) a_j a_j'`` (Rasmussen & Williams 2006, "Gaussian
    Processes for Machine Learning", eq. 5.9, with each scale at its optimum): one inverse
    from the factor instead of a factorisation per parameter for finite differences."""
    from smcbayes.posterior._matern_kernel import matern52_lengthscale_gradient  # numba loads on first use

    n, j = z.shape
    lengthscales, nugget = np.exp(params[:-1]), float(np.exp(params[-1]))
    r = matern52(x, None, lengthscales)
    r[np.diag_indices_from(r)] += nugget + JITTER
    try:
        # the matrix is this call's own, finite and exactly symmetric: its transpose is the
        # Fortran-ordered array LAPACK factorises in place, without a copy or a scan of its
        # N^2 entries, and the solve skips the same scan of the factor
        c = cho_factor(r.T, lower=True, overwrite_a=True, check_finite=False)
    except np.linalg.LinAlgError:
        return 1e12, np.zeros_like(params)
    a = cho_solve(c, z, check_finite=False)
    q = np.einsum("ij,ij->j", z, a)
    logdet = 2.0 * np.sum(np.log(np.diag(c[0])))
    value = float(0.5 * n * np.sum(np.log(q / n)) + 0.5 * j * logdet)
    inverse, info = dpotri(c[0], lower=1, overwrite_c=1)
    if info != 0:
        return 1e12, np.zeros_like(params)
    b = a * np.sqrt(n / q)
    # only the lower triangle of the inverse is written; that of W, read through its
    # C-ordered transpose, is all the gradient needs
    w = inverse
    w *= j
    w -= b @ b.T
    grad = np.empty_like(params)
    sa = np.ascontiguousarray(x / lengthscales)
    matern52_lengthscale_gradient(sa, np.ascontiguousarray(sa.T), w.T, grad[:-1])
    grad[-1] = 0.5 * nugget * np.trace(w)
    return value, grad


def fit_correlation(x: Array, z: Array, start: _Correlation | None = None) -> _Correlation:
    """ARD lengthscales and nugget of one Matern-5/2 correlation for outputs ``z (N, J)``
    (standardised; constant columns are ignored), from two fixed starts or from ``start``
    (an earlier fit on fewer points, whose optimum moves little as points are added), by
    L-BFGS-B on the concentrated likelihood and its analytic gradient."""
    z = z[:, z.std(axis=0) > 1e-12]
    z = z / z.std(axis=0) if z.shape[1] else np.zeros((len(x), 1))
    d = x.shape[1]
    bounds = [tuple(np.log(LENGTHSCALE_BOUNDS))] * d + [tuple(np.log(NUGGET_BOUNDS))]
    best = None
    # one start from an earlier fit: a fit per round of the active learning, at half the cost
    starts = ([np.log(np.r_[start.lengthscales, max(start.nugget, NUGGET_BOUNDS[0])])]
              if start is not None else
              [np.array([np.log(ls)] * d + [np.log(nug)]) for ls, nug in ((0.3, 1e-4), (1.0, 1e-6))])
    for x0 in starts:
        res = minimize(_concentrated_nll, np.clip(x0, *np.array(bounds).T), args=(x, z), method="L-BFGS-B",
                       jac=True, bounds=bounds)
        best = res if best is None or res.fun < best.fun else best
    ls, nug = np.exp(best.x[:-1]), float(np.exp(best.x[-1]))
    r = matern52(x, None, ls)
    r[np.diag_indices_from(r)] += nug + JITTER
    chol = np.linalg.cholesky(r)
    return _Correlation(ls, nug, chol)


class CurveEmulator:
    """Principal components of the log force curves + the scalar features (switch times,
    end heights), a linear trend and a shared-correlation GP (see the module docstring).

    Args:
        features: the feature map of the problem.
        x: unit-cube training points ``(N, d)`` (a repeated row counts once).
        y: their features ``(N, features.size)``.
        tolerance: log-force reconstruction RMS error allowed on the best rows (a third of
            them, at least 50).
        max_components: upper bound on the principal components.
        start: an earlier emulator of the same problem, whose correlation starts the fit.
    """

    def __init__(self, features: CurveFeatures, x: Array, y: Array, tolerance: float = 5e-4,
                 max_components: int = 60, start: CurveEmulator | None = None) -> None:
        # a repeated row makes the correlation's fit collapse to its shortest lengthscales
        first = np.sort(np.unique(x, axis=0, return_index=True)[1])
        x, y = x[first], y[first]
        self.features, self.x, self.y = features, x, y
        nk = len(features.ids) * features.nodes
        logf = np.log(np.maximum(y[:, :nk], 0.0) + FORCE_FLOOR_KN)
        self.mean_log = logf.mean(axis=0)
        centred = logf - self.mean_log
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        best = np.argsort(features.loss(y))[: max(50, len(y) // 3)]
        j = min(max_components, vt.shape[0])
        for count in range(1, j + 1):
            rec = centred[best] @ vt[:count].T @ vt[:count]
            if np.sqrt(np.mean((centred[best] - rec) ** 2)) < tolerance:
                j = count
                break
        self.basis = vt[:j]
        self.components = j
        scalars = y[:, nk:]
        self.scalar_mean, sd = scalars.mean(axis=0), scalars.std(axis=0)
        # a feature constant to rounding (the end height while the ram keeps the set speed):
        # standardised, its rounding noise would be an output of unit variance and raise the
        # shared nugget of every output
        varies = sd > 1e-9 * np.maximum(np.abs(self.scalar_mean), 1.0)
        self.scalar_sd = np.where(varies, sd, 1.0)
        scaled = np.where(varies, scalars - self.scalar_mean, 0.0) / self.scalar_sd
        z = np.hstack([centred @ self.basis.T, scaled])
        self.trend = np.linalg.lstsq(self._h(x), z, rcond=None)[0]
        z = z - self._h(x) @ self.trend
        self.corr = fit_correlation(x, np.hstack([z[:, :FIT_COMPONENTS], z[:, j:]]),
                                    None if start is None else start.corr)
        self.alpha = cho_solve((self.corr.chol, True), z)
        self.scale2 = np.einsum("ij,ij->j", z, self.alpha) / len(x)
        self.variance_factor = np.ones_like(self.scale2)
        self.calibration_rows = 0
        self._profile: tuple[Array, Array, Array] | None = None

    def _node_profile(self) -> Array:
        """The output variances' share of var log(F + 1 kN) at each node ``(K n,)``: output
        variances @ basis^2, kept while :attr:`scale2` and :attr:`variance_factor` are the
        same arrays (they are replaced, never edited in place), as recomputing it would
        dominate the samplers' calls of a few rows."""
        cached = self._profile
        if cached is None or cached[0] is not self.scale2 or cached[1] is not self.variance_factor:
            profile = self.output_variance[:self.components] @ (self.basis ** 2)
            cached = (self.scale2, self.variance_factor, profile)
            self._profile = cached
        return cached[2]

    @property
    def output_variance(self) -> Array:
        """Each output's GP variance ``(J + S,)``: the fitted scale times its calibration."""
        return self.scale2 * self.variance_factor

    def calibrate(self, points: Array) -> None:
        """Scale each output's variance by its mean squared standardised leave-one-out error
        at the training rows ``points`` ``(M, d)`` (others are ignored), within
        :data:`CALIBRATION_BOUNDS`; with fewer than :data:`CALIBRATION_MIN_POINTS` of them,
        or for an output the GP predicts without variance, the fit stands.

        Leave-one-out by the closed form of Dubrule (1983, "Cross validation of kriging in
        a unique neighborhood", Math. Geol. 15, 687), the trend held fixed: the error at
        row i is ``alpha_i / (K^-1)_ii`` and its variance ``scale2 / (K^-1)_ii``.  The
        principal components and the trend keep the left-out row, so the errors of later
        components are somewhat low; the factor is measured on the noisy prediction
        (nugget included) and scales the latent variance too.  It holds wherever the
        emulator's variance is read: the sample functions and the expected loss.  Each call
        starts from the fit's own variances.
        """
        index = {row.tobytes(): k for k, row in enumerate(self.x)}
        keys = [r.tobytes() for r in np.asarray(points, dtype=float)]
        rows = np.unique([index[k] for k in keys if k in index]).astype(int)
        if len(rows) < CALIBRATION_MIN_POINTS:
            return
        unit = np.zeros((len(self.x), len(rows)))
        unit[rows, np.arange(len(rows))] = 1.0
        diag = np.sum(solve_triangular(self.corr.chol, unit, lower=True) ** 2, axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            z2 = self.alpha[rows] ** 2 / diag[:, None] / self.scale2[None, :]
        factor = np.clip(np.mean(z2, axis=0), *CALIBRATION_BOUNDS)
        self.variance_factor = np.where(self.scale2 > 0.0, factor, 1.0)
        self.calibration_rows = len(rows)

    @staticmethod
    def _h(x: Array) -> Array:
        return np.hstack([np.ones((len(x), 1)), x])

    def predict(self, x: Array, variance: bool = False) -> tuple[Array, Array | None]:
        """GP mean ``(P, J + S)`` of the outputs at ``x (P, d)`` and, if asked, their variance."""
        mean, share = self._mean_and_share(x, variance)
        return mean, None if share is None else share[:, None] * self.output_variance[None, :]

    def _mean_and_share(self, x: Array, variance: bool) -> tuple[Array, Array | None]:
        """GP mean ``(P, J + S)`` at ``x (P, d)`` and, if asked, the correlation's share of
        every output's variance ``(P,)`` (one correlation: the variances are this share
        times :attr:`output_variance`)."""
        r = matern52(x, self.x, self.corr.lengthscales)
        mean = r @ self.alpha + self._h(x) @ self.trend
        if not variance:
            return mean, None
        # the factor is the emulator's own and finite: scipy's check would scan its N^2
        # entries at every call, 18 % of a 16-row call of the samplers at 735 points
        v = solve_triangular(self.corr.chol, r.T, lower=True, check_finite=False)
        return mean, np.maximum(1.0 + self.corr.nugget - np.sum(v * v, axis=0), 0.0)

    def curves(self, outputs: Array) -> Array:
        """Features ``(P, size)`` of predicted outputs ``(P, J + S)`` (S scalar features)."""
        j = self.components
        force = np.exp(self.mean_log + outputs[:, :j] @ self.basis) - FORCE_FLOOR_KN
        return np.hstack([force, self.scalar_mean + outputs[:, j:] * self.scalar_sd])

    def loss(self, x: Array, variance: bool = False) -> Array:
        """Emulated loss ``(P,)`` at ``x (P, d)``: of the mean curves; with ``variance`` plus
        the mean over nodes of the emulator's variance of the force, s^2 (kN^2; to first
        order var F = (F + 1 kN)^2 var log(F + 1 kN)), the expected loss."""
        if variance:
            mean_loss, s2 = self.loss_terms(x)
            return mean_loss + s2
        mean, _ = self._mean_and_share(x, False)
        return self.features.loss(self.curves(mean))

    def loss_terms(self, x: Array) -> tuple[Array, Array]:
        """The mean curves' loss ``(P,)`` at ``x (P, d)`` and the variance term s^2 ``(P,)``
        that the expected loss adds to it (:meth:`loss`; both in the loss's units, kN^2)."""
        mean, share = self._mean_and_share(x, True)
        y = self.curves(mean)
        if share is None:
            raise RuntimeError("the GP's variance was asked for and not computed")
        nk = len(self.features.ids) * self.features.nodes
        # var log(F + 1 kN) at the nodes is share x (output variances @ basis^2): a product
        # of a row's share and one node profile, so no (P, J) @ (J, nodes) product is needed
        profile = self._node_profile()
        s2 = self.features.spec.w_force * share * (((y[:, :nk] + FORCE_FLOOR_KN) ** 2) @ profile) / nk
        return self.features.loss(y), s2


def log_posterior(emulator: CurveEmulator, n_eff: float, variance: bool = True) -> Callable[[Array], Array]:
    """Emulated log posterior on the unit cube, ``(P, d) -> (P,)``: -(N_eff / 2) log L, L as
    :meth:`CurveEmulator.loss` gives it."""
    a = 0.5 * n_eff
    return _on_cube(lambda u: -a * np.log(np.maximum(emulator.loss(u, variance), 1e-300)))


def log_hidden_mass(emulator: CurveEmulator, n_eff: float) -> Callable[[Array], Array]:
    """Log of the posterior mass that the expected loss's variance term hides, on the unit
    cube, ``(P, d) -> (P,)``, unnormalised: p_mean - p_expected = L^-a (1 - (1 + s^2 / L)^-a),
    a = N_eff / 2, L the mean curves' loss and s^2 the variance term
    (:meth:`CurveEmulator.loss_terms`).  The expected loss is never below the mean curves'
    loss, so the difference is never negative; it vanishes where the emulator is sure and
    follows the mean curves' posterior where it is unsure: where the mean says the data may
    fit and too few runs let the emulated posterior in.  Where the variance is small it is
    about p_mean a s^2 / L: the density times the nats the variance term takes off the log
    likelihood, which grow with the emulator's variance, like the variance-times-density
    acquisition of VBMC (Acerbi 2018, "Variational Bayesian Monte Carlo", NeurIPS 31).
    Where it is large it is bounded by p_mean, where BAPE's variance of the likelihood
    grows without bound (Kandasamy, Schneider & Poczos 2017, "Query efficient posterior
    estimation in scientific experiments via Bayesian active learning", Artificial
    Intelligence 243, 45-56)."""
    a = 0.5 * n_eff

    def log_density(u: Array) -> Array:
        mean_loss, s2 = emulator.loss_terms(u)
        mean_loss = np.maximum(mean_loss, 1e-300)
        with np.errstate(divide="ignore"):
            hidden = np.log(-np.expm1(-a * np.log1p(np.maximum(s2, 0.0) / mean_loss)))
        return -a * np.log(mean_loss) + hidden

    return _on_cube(log_density)


def _on_cube(log_density: Callable[[Array], Array]) -> Callable[[Array], Array]:
    """``log_density`` ``(P, d) -> (P,)`` called on the rows inside the unit cube only,
    -inf at the others."""
    def log_prob(u: Array) -> Array:
        u = np.atleast_2d(u)
        out = np.full(u.shape[0], -np.inf)
        inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
        if np.any(inside):
            out[inside] = log_density(u[inside])
        return out

    return log_prob
