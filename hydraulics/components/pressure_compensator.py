"""Pressure compensator (two-way, normally open): holds its outlet a set difference above a load pressure, so the
metering edge downstream sees a constant pressure drop and its flow follows the spool alone (the pre-compensator
of a load-sensing section).

The pressure-regulated orifice (:func:`hydraulics.components.regulated.regulated_flow`) with the load pressure
p_L (port ``load``, read only) in place of the ambient: the spool balances p_out against p_L plus the spring,

    z = (Δp_set − (p_out − p_L))/w,   A = A_leak + A_max·S(z),   Q = Q_orifice(A, p_in − p_out),

so the outlet stays in [p_L + Δp_set − w, p_L + Δp_set] while the inlet can supply it; derivatives

    ∂Q/∂p_in = Q_Δ,   ∂Q/∂p_out = −Q_Δ − D,   ∂Q/∂p_L = D,   D = Q_A·A_max·S'(z)/w.

Ports: ``inlet`` (pump), ``outlet`` (to the metering edge), ``load`` (the section's work port or its LS signal).
Packing: the regulated orifice's row (:data:`hydraulics.components.regulated.COLUMNS`, setting = Δp_set).

Limitations: quasi-static spool; no check function (reverse flow passes the same area).  Downstream of the
metering edge (flow sharing) the spool balances its *inlet* against the LS line instead: the kind
``post_compensator`` (:mod:`hydraulics.components.post_compensator`).

References: H. Exner et al., *Hydraulics: Basic Principles and Components*, Bosch Rexroth 2011 (load-sensing
directional valves: individual pressure compensators upstream and downstream of the metering orifice).

Example
-------
>>> from hydraulics.fluid import Fluid
>>> valve = PressureCompensator(pressure_difference=1e6, area=2e-5)
>>> row, p = valve.law_row(Fluid()), 1e7
>>> flow_with_derivatives(row, p + 5e6, p + 1.1e6, p)[0] < 1e-6 < flow_with_derivatives(row, p + 5e6, p + 5e5, p)[0]
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .orifice import coefficients as orifice_coefficients
from .parameters import param, table
from .regulated import COLUMNS, regulated_flow


@kernel
def flow_with_derivatives(row, p_in, p_out, p_load):
    """Flow Q [m³/s] from ``inlet`` to ``outlet`` and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_load [m³/(s·Pa)] at absolute port
    pressures [Pa]."""
    q, g, closing = regulated_flow(row, p_in, p_out, p_load)
    return q, g, -g - closing, closing


@dataclass(frozen=True, kw_only=True)
class PressureCompensator:
    """Pressure compensator of a load-sensing section (ports inlet, outlet, load); law :func:`flow_with_derivatives`."""

    pressure_difference: float = param("Pa", low=0.0, high=1e8)
    """Δp_set: outlet pressure above the load pressure at which it shuts [Pa] (the metering drop it holds)."""
    regulation_band: float = param("Pa", low=0.0, high=1e8, default=2e5)
    """Fall of p_out − p_load below Δp_set over which it opens fully [Pa]."""
    area: float = param("m^2", low=0.0, high=0.01)
    """Area fully open [m²]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-11)
    """Area when shut [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("inlet", "outlet", "load")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = flow_with_derivatives

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of the regulated orifice's columns in ``fluid``."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(COLUMNS, 1, setting=self.pressure_difference, band=self.regulation_band,
                     ambient=fluid.reference_pressure, area=self.area, leakage=self.leakage_area, k=k, c=c)[0]
