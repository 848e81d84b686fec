"""Direct pressure-relief valve: Q = G·(Δp − p_crack) above cracking, 0 below, C¹ at the cracking point.

Q = G·r(Δp − p_crack) with the smooth ramp r of :func:`hydraulics.components.ramps.smooth_ramp_with_derivative`
over a width w = :data:`REGULARISATION`·p_crack, so that Newton's method sees a continuous slope.

A law component (:data:`hydraulics.components.BRANCH_LAWS`): ports ``inlet``, ``outlet``; one row of
:data:`COLUMNS` per valve (:meth:`ReliefValve.law_row`), read by :func:`branch_law`; its kink hook
:func:`law_piece` numbers the ramp's pieces (closed, blending, open).

Example
-------
>>> flow_with_derivative(2.1e7, 2e7, 1e-11, 2e4)
(9.9e-06, 1e-11)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .parameters import param, table
from .ramps import ramp_piece, smooth_ramp_with_derivative

REGULARISATION = 1e-3  # [-] width of the C¹ blend at the cracking point, relative to the cracking pressure


@kernel
def flow_with_derivative(dp, cracking, gradient, width):
    """Relief flow Q [m³/s] and dQ/dΔp [m³/(s·Pa)] at Δp = inlet − outlet [Pa]; ``cracking`` [Pa], ``gradient``
    G [m³/(s·Pa)], ``width`` [Pa] of the blend."""
    ramp, slope = smooth_ramp_with_derivative(dp - cracking, width)
    return gradient * ramp, gradient * slope


COLUMNS = ("cracking", "gradient", "width")
"""Row of one valve: cracking pressure [Pa], gradient G [m³/(s·Pa)], blend width w [Pa]."""
R_CRACK, R_GRAD, R_WIDTH = range(len(COLUMNS))


@kernel
def branch_law(row, p_in, p_out, p_pilot):
    """Flow Q [m³/s] from ``inlet`` to ``outlet`` and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_pilot (= 0) [m³/(s·Pa)] at
    absolute port pressures [Pa]; ``row``: the valve's parameters, columns :data:`COLUMNS`."""
    q, g = flow_with_derivative(p_in - p_out, row[R_CRACK], row[R_GRAD], row[R_WIDTH])
    return q, g, -g, 0.0


@kernel
def law_piece(row, state, h, p_in, p_out, p_pilot):
    """Piece of the ramp Δp lies on: 0 closed (Δp ≤ p_crack), 1 blending, 2 open (Δp ≥ p_crack + w)."""
    return ramp_piece(p_in - p_out - row[R_CRACK], row[R_WIDTH])


@dataclass(frozen=True, kw_only=True)
class ReliefValve:
    """Direct pressure-relief valve: Q = G·(Δp − p_crack) above cracking (ports inlet, outlet); law
    :func:`branch_law`."""

    cracking_pressure: float = param("Pa", low=0.0, high=1e9)
    """Differential cracking pressure [Pa]."""
    gradient: float = param("m^3/(s*Pa)", low=0.0, high=1e-3)
    """Pressure–flow gradient G [m³/(s·Pa)]; override = Q/G."""
    PORTS = ("inlet", "outlet")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = branch_law
    LAW_PIECE = law_piece

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` (the blend width w = :data:`REGULARISATION`·p_crack); ``fluid``
        unused (the law is in pressure differences)."""
        return table(COLUMNS, 1, cracking=self.cracking_pressure, gradient=self.gradient,
                     width=REGULARISATION * self.cracking_pressure)[0]
