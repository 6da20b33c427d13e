"""Weighted Gaussian mixture (EM) against known mixtures."""

from __future__ import annotations

import warnings

import numpy as np
from scipy.stats import multivariate_normal

from smcbayes.posterior.mixture import fit_mixture, thin

# a broad main region and a small, thin second region turned another way
W2 = 0.05
M1, M2 = np.array([0.3, 0.3]), np.array([0.8, 0.75])
C1 = np.array([[0.010, 0.008], [0.008, 0.010]])
C2 = np.array([[0.0016, -0.0012], [-0.0012, 0.0010]])


def _log_density(x: np.ndarray) -> np.ndarray:
    return np.logaddexp(np.log(1 - W2) + multivariate_normal(M1, C1).logpdf(x),
                        np.log(W2) + multivariate_normal(M2, C2).logpdf(x))


def test_weighted_em_recovers_a_small_thin_component_from_importance_weights() -> None:
    rng = np.random.default_rng(0)
    x = rng.random((20000, 2))  # uniform draws, weighted to the mixture: the weights carry the shape
    lw = _log_density(x)
    w = np.exp(lw - lw.max())
    mix = fit_mixture(x, w, 2, rng)
    small = int(np.argmin(mix.weight))
    assert abs(mix.weight[small] - W2) < 0.01
    np.testing.assert_allclose(mix.mean[small], M2, atol=0.01)
    np.testing.assert_allclose(mix.mean[1 - small], M1, atol=0.01)
    # the main component keeps its shape; the small one is widened towards the whole sample
    # (pseudo-points of the global covariance), never narrowed below its own spread
    corr = mix.cov[1 - small][0, 1] / np.sqrt(mix.cov[1 - small][0, 0] * mix.cov[1 - small][1, 1])
    assert corr > 0.7
    np.testing.assert_allclose(np.diag(mix.cov[1 - small]), np.diag(C1), rtol=0.2)
    assert np.all(np.diag(mix.cov[small]) > 0.9 * np.diag(C2))
    # responsibilities assign the component means to their own components
    assert np.argmax(mix.log_resp(M2[None, :])[0]) == small


def test_one_component_is_the_weighted_mean_and_a_shrunk_covariance() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal([0.4, 0.6], [0.05, 0.1], size=(2500, 2))  # below max_points: no thinning
    mix = fit_mixture(x, np.ones(x.shape[0]), 1, rng)
    np.testing.assert_allclose(mix.weight, [1.0])
    np.testing.assert_allclose(mix.mean[0], x.mean(0), atol=1e-12)
    np.testing.assert_allclose(mix.cov[0], np.cov(x.T), rtol=1e-2)


def test_few_effective_points_give_few_finite_components() -> None:
    rng = np.random.default_rng(2)
    x = rng.random((50, 3))
    w = np.zeros(50)
    w[:5] = 1.0  # five points carry all the weight
    mix = fit_mixture(x, w, 8, rng)
    assert mix.weight.size == 1
    assert np.all(np.linalg.eigvalsh(mix.cov[0]) > 0)


def test_thinning_keeps_heavy_points_and_the_weighted_mean() -> None:
    rng = np.random.default_rng(3)
    x = rng.random((20000, 3))
    w = np.exp(-30.0 * np.sum((x - 0.3) ** 2, axis=1))
    w /= w.sum()
    xt, wt = thin(x, w, 2000, rng)
    assert 1800 < xt.shape[0] < 2200
    heaviest = x[np.argsort(w)[-50:]]
    assert all(np.any(np.all(xt == h, axis=1)) for h in heaviest)
    np.testing.assert_allclose(wt @ xt / wt.sum(), w @ x, atol=0.01)


def test_thinning_weights_700_nats_below_their_sum_keeps_its_count_without_a_warning() -> None:
    """A weight below count / DBL_MAX overflows count / w and exp(c): the bisection runs on
    logarithms (the overflow kept every point)."""
    rng = np.random.default_rng(4)
    x = rng.random((20000, 2))
    log_w = -1500.0 * np.sum((x - 0.5) ** 2, axis=1)
    w = np.exp(log_w - log_w.max())
    assert 0.0 < w[w > 0].min() < np.finfo(float).tiny  # subnormal
    # 1,000 heavy points and the rest 720 nats lighter: the threshold itself lies past exp's range
    two = np.where(np.arange(20000) < 1000, 1.0, np.exp(-720.0))
    for weights, count in ((w, 2000), (two, 3000)):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            xt, wt = thin(x, weights / weights.sum(), count, rng)
        assert 0.9 * count < xt.shape[0] < 1.1 * count
        np.testing.assert_allclose(wt @ xt / wt.sum(), weights @ x / weights.sum(), atol=0.02)


def test_the_compiled_em_steps_give_the_responsibilities_and_scatter_of_the_formulas() -> None:
    from smcbayes.posterior._mixture_kernel import e_step, scatter

    rng = np.random.default_rng(5)
    n, d, k = 400, 3, 4
    x, w = rng.random((n, d)), rng.random(n)
    w /= w.sum()
    alpha, mean = rng.dirichlet(np.ones(k)), rng.random((k, d))
    cov = np.array([a @ a.T / d + 0.01 * np.eye(d) for a in rng.normal(size=(k, d, d)) * 0.2])
    chol = np.linalg.cholesky(cov)
    log_det = np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)
    const = np.log(alpha) - log_det - 0.5 * d * np.log(2 * np.pi)
    resp = np.empty((n, k))
    inv = np.ascontiguousarray(np.linalg.inv(chol).transpose(1, 2, 0))
    loglik = e_step(x, w, np.ascontiguousarray(mean.T), inv, const, resp)
    joint = np.log(alpha) + np.column_stack([multivariate_normal(m, c).logpdf(x)
                                             for m, c in zip(mean, cov, strict=True)])
    norm = np.logaddexp.reduce(joint, axis=1)
    np.testing.assert_allclose(loglik, w @ norm, rtol=1e-12)
    np.testing.assert_allclose(resp, np.exp(joint - norm[:, None]) * w[:, None], rtol=1e-10, atol=1e-300)
    out = np.empty((d, d, k))
    scatter(x, resp, np.ascontiguousarray(mean.T), out)
    diff = x[None, :, :] - mean[:, None, :]
    expected = np.einsum("kn,kna,knb->kab", resp.T, diff, diff)
    np.testing.assert_allclose(out.transpose(2, 0, 1), expected, rtol=1e-12)
