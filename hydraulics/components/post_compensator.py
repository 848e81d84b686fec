"""Post-compensator (two-way, between a section's metering edge and its work port): throttles until its inlet, the
metering edge's outlet, stands at the highest load pressure (the LS line), so every section's metering edge sees
the same drop, supply − LS; at saturation that drop falls for all sections alike and the pump's flow is shared in
proportion to the metering areas whatever the loads (flow sharing, "LUDV").

The spool balances its inlet pressure p_in (opening) against the LS pressure p_LS (port ``ls``, read only) and a
weak spring Δp_s:

    z = (p_in − p_LS − Δp_s)/w + 1,   A = A_leak + A_max·S(z),   Q = Q_orifice(A, p_in − p_out),

with the C¹ smooth step S of :func:`hydraulics.components.ramps.smooth_step_with_derivative` (fully open for
p_in ≥ p_LS + Δp_s, shut for p_in ≤ p_LS + Δp_s − w) and the orifice law of :mod:`hydraulics.components.orifice`
(either direction).  The section whose load is highest sets the LS line (take the LS signal from the inlet, the
metering edge's outlet, through the shuttle chain): its compensator stands open; every other one throttles its
lighter load up to that pressure.  Derivatives, with Q_Δ = ∂Q/∂Δp and D = Q_A·A_max·S'(z)/w:

    ∂Q/∂p_in = Q_Δ + D,   ∂Q/∂p_out = −Q_Δ,   ∂Q/∂p_LS = −D.

Ports: ``inlet`` (metering edge's outlet), ``outlet`` (work port), ``ls`` (the LS line).  Packing: one row per
valve, columns :data:`COLUMNS` (:func:`law_row`), read by :func:`flow_with_derivatives`.

Limitations: quasi-static spool; no load-holding check of its own (reverse flow passes the open area: put a check
valve after it where a load must not drive back).

References: H. Exner et al., *Hydraulics: Basic Principles and Components*, Bosch Rexroth 2011 (load-sensing
directional valves with individual pressure compensators downstream of the metering orifice: flow sharing,
LUDV).

Example
-------
>>> from hydraulics.fluid import Fluid
>>> valve = PostCompensator(area=2e-5)
>>> row, p_ls = valve.law_row(Fluid()), 1e7
>>> shut, open_ = (flow_with_derivatives(row, p_ls + d, 5e6, p_ls)[0] for d in (-5e5, 1e5))
>>> shut < 1e-6 < open_
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

COLUMNS = ("spring", "band", "area", "leakage", "k", "c")
"""Row of one valve: spring Δp_s [Pa], regulation band w [Pa], full and closed areas [m²], orifice-law constants
k, c."""
SPRING, BAND, AREA, LEAKAGE, K, C = range(len(COLUMNS))


@kernel
def flow_with_derivatives(row, p_in, p_out, p_ls):
    """Flow Q [m³/s] from ``inlet`` to ``outlet`` and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_LS [m³/(s·Pa)] at absolute port
    pressures [Pa]."""
    band = row[BAND]
    y, dy = smooth_step_with_derivative((p_in - p_ls - row[SPRING]) / band + 1.0)
    area = row[LEAKAGE] + row[AREA] * y
    dp = p_in - p_out
    q, g = orifice_flow_with_derivative(area, row[K], row[C], dp)
    opening = orifice_flow_area_derivative(area, row[K], row[C], dp) * row[AREA] * dy / band
    return q, g + opening, -g, -opening


@dataclass(frozen=True, kw_only=True)
class PostCompensator:
    """Post-compensator of a flow-sharing load-sensing section (ports inlet, outlet, ls); law
    :func:`flow_with_derivatives`."""

    area: float = param("m^2", low=0.0, high=0.01)
    """Area fully open [m²]."""
    spring_pressure: float = param("Pa", low=0.0, high=1e7, low_open=False, default=0.0)
    """Δp_s: inlet pressure above the LS line at which it is fully open [Pa] (its weak spring)."""
    regulation_band: float = param("Pa", low=0.0, high=1e8, default=2e5)
    """Fall of the inlet below p_LS + Δp_s over which it shuts [Pa]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-11)
    """Area when shut [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("inlet", "outlet", "ls")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = flow_with_derivatives

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` in ``fluid``."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(COLUMNS, 1, spring=self.spring_pressure, band=self.regulation_band, area=self.area,
                     leakage=self.leakage_area, k=k, c=c)[0]
