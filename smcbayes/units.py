"""Unit conversions between the engineering units at the edges and SI inside.

Config keys, CSV columns and result fields carry their unit in the name
(``speed_mm_s``, ``force_kN``, ``tau_c_MPa``); everything inside the solvers is SI
(m, s, Pa, Pa s, N, K, kg).
"""

from __future__ import annotations

MM = 1e-3
"""metres per millimetre"""
KN = 1e3
"""newtons per kilonewton"""
MPA = 1e6
"""pascals per megapascal"""
G = 1e-3
"""kilograms per gram"""
G_CM3 = 1e3
"""kg/m^3 per g/cm^3"""
ZERO_C_K = 273.15
"""kelvin at 0 degrees Celsius"""


def celsius_to_kelvin(temperature_C: float) -> float:
    """Convert a temperature from degrees Celsius to kelvin."""
    return temperature_C + ZERO_C_K
