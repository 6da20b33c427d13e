"""Bayesian calibration: design of experiments, GP surrogate, acquisition, BO loop.

The layer sees the forward model only through the simulator seam of
:mod:`smcbayes.simulation` ("evaluate these parameter vectors on this configuration").
Torch and BoTorch are imported by :mod:`smcbayes.surrogate.gp` and
:mod:`smcbayes.surrogate.acquisition` only, so worker processes that just run simulations
stay light.
"""
