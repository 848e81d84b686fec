"""Direct-acting pressure-reducing valve (two-way): normally open, closing as the outlet pressure rises to the
setting, so the outlet is held between setting − band and the setting whatever the inlet pressure.

The outlet pressure acts on the spool against the spring; the metering area is

    z = (p_set − p_out)/w,   y = S(z),   A = A_leak + A_max·y,

with the outlet's gauge pressure p_out (above the fluid's reference pressure, the spring chamber drained there),
the C¹ smooth step S of :func:`hydraulics.components.ramps.smooth_step_with_derivative` (fully open for
p_out ≤ p_set − w, closed at p_out ≥ p_set) and the orifice law Q(A, p_in − p_out) of
:mod:`hydraulics.components.orifice`.  In steady flow Q the outlet settles where Q(A(p_out), p_in − p_out) = Q:
inside the band [p_set − w, p_set] while the fully open valve could pass more than Q at the inlet pressure.

Derivatives, with Q_Δ = ∂Q/∂Δp and Q_A = ∂Q/∂A at fixed area:

    ∂Q/∂p_in = Q_Δ,   ∂Q/∂p_out = −Q_Δ − Q_A·A_max·S'(z)/w,   (no pilot terminal).

Limitations: the drain (pilot and spring-chamber leakage) is not modelled and the valve does not relieve: with the
outlet dead-ended, its leakage lets the outlet creep above the setting towards the inlet pressure (a three-way
reducing/relieving valve would bleed it to tank).  Reverse flow (p_out > p_in) passes through the same area (no
bypass check).  Quasi-static spool (no dynamics, no flow forces).

The law is the pressure-regulated orifice of :mod:`hydraulics.components.regulated` with the ambient as its
reference.  Ports: ``inlet``, ``outlet``.  Packing: one row per valve, columns :data:`COLUMNS` (:func:`law_row`), read by
:func:`flow_with_derivatives` (:attr:`PressureReducingValve.BRANCH_LAW`).

References: H. Exner et al., *Hydraulics: Basic Principles and Components*, Bosch Rexroth 2011 (pressure
reducing valves, direct operated, two-way); H. E. Merritt, *Hydraulic Control Systems*, Wiley 1967, §2.4
(orifice flow).

Example
-------
>>> from hydraulics.fluid import Fluid
>>> valve = PressureReducingValve(setting_pressure=3e6, area=1e-5)
>>> row, ambient = valve.law_row(Fluid()), Fluid().reference_pressure
>>> abs(flow_with_derivatives(row, ambient + 2e7, ambient + 3e6, 0.0)[0]) < 1e-7  # outlet at the setting: shut
True
>>> flow_with_derivatives(row, ambient + 2e7, ambient + 2e6, 0.0)[0] > 1e-4  # outlet 10 bar below: open
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .orifice import coefficients as orifice_coefficients
from .parameters import param, table
from .regulated import AMBIENT, COLUMNS, regulated_flow

@kernel
def flow_with_derivatives(row, p_in, p_out, p_x):
    """Flow Q [m³/s] from ``inlet`` to ``outlet`` and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_x (0: two ports) [m³/(s·Pa)] at
    absolute port pressures [Pa]; ``row``: the valve's parameters, columns :data:`COLUMNS`."""
    q, g, closing = regulated_flow(row, p_in, p_out, row[AMBIENT])
    return q, g, -g - closing, 0.0


@dataclass(frozen=True, kw_only=True)
class PressureReducingValve:
    """Pressure-reducing valve, two-way, drain not modelled (ports inlet, outlet); law :func:`flow_with_derivatives`."""

    setting_pressure: float = param("Pa", low=0.0, high=1e8)
    """Outlet gauge pressure at which the valve is shut [Pa]."""
    regulation_band: float = param("Pa", low=0.0, high=1e8, default=5e5)
    """Fall of the outlet pressure below the setting over which the valve opens fully [Pa]."""
    area: float = param("m^2", low=0.0, high=0.01)
    """Metering area fully open [m²]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-11)
    """Area when shut [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("inlet", "outlet")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = flow_with_derivatives

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(COLUMNS, 1, setting=self.setting_pressure, band=self.regulation_band,
                     ambient=fluid.reference_pressure, area=self.area, leakage=self.leakage_area, k=k, c=c)[0]
