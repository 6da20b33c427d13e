"""Reports of a run directory: one self-contained HTML page and a Markdown twin.

Sections (each only when its stage was run): data, calibration, posterior, predictive
bands, sim-to-real gap diagnosis, reproducibility.  Use :func:`write_report`.
"""

from smcbayes.report.build import write_report

__all__ = ["write_report"]
