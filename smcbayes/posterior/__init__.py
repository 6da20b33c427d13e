"""Posterior of the calibrated parameters: emulated likelihood, emcee, predictive bands.

The GP fitted during calibration emulates log(loss); this package turns it into a
likelihood (:mod:`likelihood`), samples it (:mod:`sampler`), summarises and stores the
chains (:mod:`summary`), refines and checks the emulator (:mod:`refine`), and pushes
posterior draws through the forward model (:mod:`predictive`).
"""
