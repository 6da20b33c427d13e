"""How the posterior's numba kernels share a large call out over numba's threads.

The correlation rows (:mod:`._matern_kernel`), the curve loss (:mod:`._curve_kernel`) and
the mixture proposal's density (:mod:`._proposal_kernel`) each have a threaded variant
that takes the rows in blocks; each row's arithmetic is the serial kernel's, so the values
do not depend on the number of threads.
"""

from __future__ import annotations

PARALLEL_ROWS = 256
"""Rows (points) of a call from which the threaded variant pays: the emcee samplers' calls
of 16 rows would spend longer waking the threads than computing."""

BLOCK = 64
"""Rows per block of a threaded variant."""
