"""A deterministic simulator's GP: the small fixed noise stays quiet and survives a reload."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from gpytorch.utils.warnings import NumericalWarning

from smcbayes.surrogate.gp import fit_surrogate, load_surrogate, save_surrogate


def test_small_fixed_noise_fits_and_reloads_without_numerical_warning(tmp_path: Path) -> None:
    """The noise of 1e-8 lies below gpytorch's floor: neither fitting nor rebuilding the GP
    from ``gp.pt`` (the posterior stage's first step) passes gpytorch's warning on to the
    terminal, and the rebuilt GP predicts as the fitted one."""
    rng = np.random.default_rng(3)
    x = rng.random((12, 2))
    y = np.log(1.0 + np.sum((x - 0.4) ** 2, axis=1))
    with warnings.catch_warnings():
        warnings.simplefilter("error", NumericalWarning)
        fitted = fit_surrogate(x, y, "matern52", seed=0, noise=1e-8)
        save_surrogate(tmp_path / "gp.pt", fitted, {})
        loaded, _ = load_surrogate(tmp_path / "gp.pt")
    probe = rng.random((5, 2))
    np.testing.assert_allclose(loaded.predict(probe)[0], fitted.predict(probe)[0], rtol=1e-9, atol=1e-12)
