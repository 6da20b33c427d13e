"""Sim-to-real gap diagnosis (``smcbayes diagnose``).

* :mod:`~smcbayes.diagnose.where`: where the calibrated model misses the measurements
  (per configuration, phase and normalised time; timing/amplitude/shape; a text verdict);
* :mod:`~smcbayes.diagnose.which`: which unmodelled effect explains the gap (signature
  score, warm-started re-calibration, held-out test with a penalty for extra parameters);
* :mod:`~smcbayes.diagnose.shrink`: how far the gap shrinks with the best effect;
* :mod:`~smcbayes.diagnose.run`: the whole diagnosis of a calibration run, written to disk.
"""

from smcbayes.diagnose.fit import DiagnosisContext, FitSettings
from smcbayes.diagnose.run import DiagnoseSettings, diagnose

__all__ = ["DiagnosisContext", "FitSettings", "DiagnoseSettings", "diagnose"]
