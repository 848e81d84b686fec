"""The pressure-regulated orifice: the law shared by the valves whose spool balances their outlet pressure against a
reference pressure and a spring (the pressure-reducing valve, the pressure compensator).

    z = (p_set − (p_out − p_ref))/w,   y = S(z),   A = A_leak + A_max·y,   Q = Q_orifice(A, p_in − p_out),

with the C¹ smooth step S of :func:`hydraulics.components.ramps.smooth_step_with_derivative` (open for
p_out − p_ref ≤ p_set − w, shut at p_set) and the orifice law of :mod:`hydraulics.components.orifice`.

Packing: one row per valve, columns :data:`COLUMNS`.

Example
-------
>>> from hydraulics.components.orifice import coefficients
>>> k, c = coefficients(0.7, 870.0, 4.6e-5)
>>> row = np.array([3e6, 5e5, 1e5, 1e-5, 1e-11, k, c])
>>> q, slope, closing = regulated_flow(row, 2e7, 2.1e6, 1e5)  # 10 bar below the setting: open
>>> q > 1e-4 and closing == 0.0
True
"""

from __future__ import annotations

import numpy as np  # noqa: F401 (the example)

from .._jit import kernel
from .orifice import flow_area_derivative as orifice_flow_area_derivative
from .orifice import flow_with_derivative as orifice_flow_with_derivative
from .ramps import smooth_step_with_derivative

COLUMNS = ("setting", "band", "ambient", "area", "leakage", "k", "c")
"""Row of one valve: setting [Pa gauge], regulation band [Pa], reference pressure [Pa], full and closed areas
[m²], orifice-law constants k, c."""
SETTING, BAND, AMBIENT, AREA, LEAKAGE, K, C = range(len(COLUMNS))


@kernel
def regulated_flow(row, p_in, p_out, p_reference):
    """Flow Q [m³/s] from ``inlet`` to ``outlet`` of the valve that holds p_out − p_reference at the setting, its
    orifice slope ∂Q/∂Δp and its closing term Q_A·A_max·S'(z)/w [m³/(s·Pa)] (∂Q/∂p_out = −slope − closing,
    ∂Q/∂p_reference = closing), at absolute pressures [Pa]; ``row``: columns :data:`COLUMNS`."""
    band = row[BAND]
    y, dy = smooth_step_with_derivative((row[SETTING] - (p_out - p_reference)) / band)
    area = row[LEAKAGE] + row[AREA] * y
    dp = p_in - p_out
    q, g = orifice_flow_with_derivative(area, row[K], row[C], dp)
    closing = orifice_flow_area_derivative(area, row[K], row[C], dp) * row[AREA] * dy / band
    return q, g, closing
