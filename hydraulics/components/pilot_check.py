"""Pilot-operated check valve: free flow a→b above cracking; reverse flow b→a only when piloted open.

The poppet opens with the seat pressure difference and with the pilot piston (pilot area / seat area r,
drained to ambient):

    z = (r·(p_x − p_amb) + p_a − p_b − p_crack)/band,   y = S(z),   A = A_leak + A_max·y,

with the C¹ smooth step S of :func:`hydraulics.components.ramps.smooth_step_with_derivative`, and the orifice
law Q(A, p_a − p_b) of :mod:`hydraulics.components.orifice` (either direction).  Without pilot pressure it is a
check valve (closed, leakage only, for p_b > p_a − p_crack): a load-holding valve on a cylinder's load side.
With r·(p_x − p_amb) > p_b − p_a + p_crack + band it is fully open both ways.

Derivatives, with Q_Δ = ∂Q/∂Δp and Q_A = ∂Q/∂A at fixed area and dA/dz = A_max·S'(z):

    ∂Q/∂p_a = Q_Δ + Q_A·dA/dz/band,  ∂Q/∂p_b = −Q_Δ − Q_A·dA/dz/band,  ∂Q/∂p_x = Q_A·dA/dz·r/band.

Ports: ``a`` (free-flow inlet), ``b`` (load side), ``pilot``.  Packing: one row per valve, columns
:data:`COLUMNS` (:func:`law_row`), read by :func:`flow_with_derivatives`, the law the network calls for every
valve of this kind (:attr:`PilotCheckValve.BRANCH_LAW`).

References: H. Exner et al., *Hydraulics: Basic Principles and Components*, Bosch Rexroth 2011, §6.2 (pilot
operated check valves).

Example
-------
>>> from hydraulics.fluid import Fluid
>>> valve = PilotCheckValve(area=1e-5, pilot_area_ratio=3.0)
>>> row = valve.law_row(Fluid())
>>> q, dq_a, dq_b, dq_x = flow_with_derivatives(row, 1e5, 1e7, 1e5)  # load side at 100 bar, no pilot: closed
>>> abs(q) < 1e-7 and dq_x == 0.0
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .orifice import coefficients as orifice_coefficients
from .orifice import flow_area_derivative as orifice_flow_area_derivative
from .orifice import flow_with_derivative as orifice_flow_with_derivative
from .parameters import param, table
from .ramps import smooth_step_with_derivative

COLUMNS = ("cracking", "band", "ratio", "ambient", "area", "leakage", "k", "c")
"""Row of one valve: cracking pressure [Pa], opening band [Pa], pilot area ratio r [-], pilot drain pressure
[Pa], full and closed areas [m²], orifice-law constants k, c."""
CRACKING, BAND, RATIO, AMBIENT, AREA, LEAKAGE, K, C = range(len(COLUMNS))


@kernel
def flow_with_derivatives(row, p_a, p_b, p_x):
    """Flow Q [m³/s] from ``a`` to ``b`` and ∂Q/∂p_a, ∂Q/∂p_b, ∂Q/∂p_x [m³/(s·Pa)] at absolute port pressures
    [Pa] (``p_x``: pilot); ``row``: the valve's parameters, columns :data:`COLUMNS`."""
    band = row[BAND]
    z = (row[RATIO] * (p_x - row[AMBIENT]) + p_a - p_b - row[CRACKING]) / band
    y, dy = smooth_step_with_derivative(z)
    area = row[LEAKAGE] + row[AREA] * y
    dp = p_a - p_b
    q, g = orifice_flow_with_derivative(area, row[K], row[C], dp)
    dq_dz = orifice_flow_area_derivative(area, row[K], row[C], dp) * row[AREA] * dy / band
    return q, g + dq_dz, -g - dq_dz, dq_dz * row[RATIO]


@dataclass(frozen=True, kw_only=True)
class PilotCheckValve:
    """Pilot-operated check valve (ports a, b, pilot); law :func:`flow_with_derivatives`."""

    cracking_pressure: float = param("Pa", low=0.0, high=1e8, low_open=False, default=2e5)
    """Opening pressure difference p_a − p_b without pilot [Pa]."""
    opening_band: float = param("Pa", low=0.0, high=1e8, default=1e6)
    """Rise of the opening pressure over which the poppet goes from closed to fully open [Pa]."""
    pilot_area_ratio: float = param("-", low=0.0, high=100.0, default=3.0)
    """Pilot piston area / seat area r [-]."""
    area: float = param("m^2", low=0.0, high=0.01)
    """Fully open area [m²]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-11)
    """Closed area [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("a", "b", "pilot")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = flow_with_derivatives

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(COLUMNS, 1, cracking=self.cracking_pressure, band=self.opening_band, ratio=self.pilot_area_ratio,
                     ambient=fluid.reference_pressure, area=self.area, leakage=self.leakage_area, k=k, c=c)[0]
