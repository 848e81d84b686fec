"""One-way flow control valve: a throttle with a bypass check valve (free flow a→b, metered flow b→a).

The throttle (area A_t) and the check valve (:mod:`hydraulics.components.check_valve`) in parallel are one
orifice of area A(Δp) = A_t + A_max·clip((Δp − p_crack)/(p_full − p_crack), 0, 1), Δp = p_a − p_b: the check
valve's law with the throttle as its closed area (:func:`hydraulics.components.check_valve.flow_with_derivative`).
Typical use: meter-out speed control of a cylinder (the throttle on the outflow, the check passing the inflow).

Ports: ``a``, ``b``.  Packing: one row per valve, columns :data:`COLUMNS` (:func:`law_row`).

Example
-------
>>> from hydraulics.fluid import Fluid
>>> valve = ThrottleCheckValve(throttle_area=1e-6, area=1e-4)
>>> q_free = flow_with_derivatives(valve.law_row(Fluid()), 1e6, 0.0, 0.0)[0]
>>> q_metered = -flow_with_derivatives(valve.law_row(Fluid()), 0.0, 1e6, 0.0)[0]
>>> q_free > 50 * q_metered > 0
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .check_valve import flow_with_derivative as check_valve_flow
from .orifice import coefficients as orifice_coefficients
from .parameters import CircuitError, param, table

COLUMNS = ("cracking", "full_open", "area", "throttle", "k", "c")
"""Row of one valve: check cracking and full-open pressures [Pa], check area and throttle area [m²], orifice-law
constants k, c."""
CRACKING, FULL_OPEN, AREA, THROTTLE, K, C = range(len(COLUMNS))


@kernel
def flow_with_derivatives(row, p_a, p_b, p_x):
    """Flow Q [m³/s] from ``a`` to ``b`` and ∂Q/∂p_a, ∂Q/∂p_b, ∂Q/∂p_x (0: two ports) [m³/(s·Pa)]."""
    q, g = check_valve_flow(p_a - p_b, row[CRACKING], row[FULL_OPEN], row[AREA], row[THROTTLE], row[K], row[C])
    return q, g, -g, 0.0


@dataclass(frozen=True, kw_only=True)
class ThrottleCheckValve:
    """One-way flow control valve (ports a, b); law :func:`flow_with_derivatives`."""

    throttle_area: float = param("m^2", low=0.0, high=0.01)
    """Area of the throttle (both directions) [m²]."""
    area: float = param("m^2", low=0.0, high=0.01)
    """Fully open area of the bypass check valve (a→b) [m²]."""
    cracking_pressure: float = param("Pa", low=0.0, high=1e8, low_open=False, default=1e4)
    """Check valve cracking pressure [Pa]."""
    full_open_pressure: float = param("Pa", low=0.0, high=1e8, default=1e5)
    """Check valve fully open pressure [Pa]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("a", "b")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = flow_with_derivatives

    def check(self, where: str) -> None:
        """Raise CircuitError (prefixed by ``where``) unless the check valve opens over a positive span."""
        if self.full_open_pressure <= self.cracking_pressure:
            raise CircuitError(f"{where}, field 'full_open_pressure': must exceed cracking_pressure")

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(COLUMNS, 1, cracking=self.cracking_pressure, full_open=self.full_open_pressure, area=self.area,
                     throttle=self.throttle_area, k=k, c=c)[0]
