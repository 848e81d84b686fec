"""Direct pressure-relief valve: Q = G·(Δp − p_crack) above cracking, 0 below, C¹ at the cracking point.

Q = G·r(Δp − p_crack) with the smooth ramp r of :func:`hydraulics.components.ramps.smooth_ramp_with_derivative`
over a width w = :data:`REGULARISATION`·p_crack, so that Newton's method sees a continuous slope.

Packing: the relief-branch table, columns :data:`COLUMNS` (:func:`pack`).

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
from .ramps import smooth_ramp_with_derivative

REGULARISATION = 1e-3  # [-] width of the C¹ blend at the cracking point, relative to the cracking pressure


@dataclass(frozen=True, kw_only=True)
class ReliefValve:
    """Direct pressure-relief valve: Q = G·(Δp − p_crack) above cracking."""

    cracking_pressure: float = param("Pa", low=0.0, high=1e9)
    """Differential cracking pressure [Pa]."""
    gradient: float = param("m^3/(s*Pa)", low=0.0, high=1e-3)
    """Pressure–flow gradient G [m³/(s·Pa)]; override = Q/G."""
    PORTS = ("inlet", "outlet")


@kernel
def flow_with_derivative(dp, cracking, gradient, width):
    """Relief flow Q [m³/s] and dQ/dΔp [m³/(s·Pa)] at Δp = inlet − outlet [Pa]; ``cracking`` [Pa], ``gradient``
    G [m³/(s·Pa)], ``width`` [Pa] of the blend."""
    ramp, slope = smooth_ramp_with_derivative(dp - cracking, width)
    return gradient * ramp, gradient * slope


COLUMNS = ("cracking", "gradient", "width")
"""Relief-branch table: cracking pressure [Pa], gradient G [m³/(s·Pa)], blend width [Pa]."""
R_CRACK, R_GRAD, R_WIDTH = range(len(COLUMNS))


def pack(model) -> np.ndarray:
    """The relief-branch table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`COLUMNS`."""
    return table(COLUMNS, len(model.relief_cracking), cracking=model.relief_cracking, gradient=model.relief_gradient,
                 width=REGULARISATION * model.relief_cracking)
