"""Counterbalance (over-centre) valve: free flow valve→load through a check, load→valve only through a relief
stage that the load pressure and the pilot pressure open together.

Two poppets between the same two ports form one orifice of area

    A = A_leak + A_r·S(z_r) + A_c·S(z_c),
    z_r = (p_L + r·p_X − r_b·p_V − p_set)/w_r,   z_c = (p_V − p_L − p_crack)/w_c,

with gauge pressures p_L (``load``, the cylinder side), p_V (``valve``, the directional-valve side) and p_X
(``pilot``) above the fluid's reference pressure, the C¹ smooth step S of
:func:`hydraulics.components.ramps.smooth_step_with_derivative`, and the orifice law Q(A, p_L − p_V) of
:mod:`hydraulics.components.orifice` (either direction; Q > 0 from load to valve).  The relief stage starts to
open where p_L + r·p_X − r_b·p_V reaches the setting p_set and is fully open w_r above it: with the pilot
vented the valve holds any load pressure below p_set (set it about 1.3× the highest load pressure), and piloted
it opens at

    p_X = (p_set − p_L + r_b·p_V)/r,

the pilot ratio r (pilot area / load-seat area, 3:1 … 10:1) dividing the pressure the pilot has to supply.  The
back-pressure ratio r_b (area the valve-port pressure acts on to close the poppet / load-seat area) is 0 for a
valve whose spring chamber is vented to atmosphere; for one vented to the valve port, the valve port's pressure
adds to the setting (r_b > 0, from the maker's data).

Derivatives, with Q_Δ = ∂Q/∂Δp and Q_A = ∂Q/∂A at fixed area, D_r = Q_A·A_r·S'(z_r)/w_r and
D_c = Q_A·A_c·S'(z_c)/w_c:

    ∂Q/∂p_L = Q_Δ + D_r − D_c,   ∂Q/∂p_V = −Q_Δ − r_b·D_r + D_c,   ∂Q/∂p_X = r·D_r.

Limitations: quasi-static poppets (no spool dynamics, no flow forces); the pilot draws no flow; the relief
stage's opening is a smooth step in pressure, not a spring–flow-force balance.

Ports: ``load``, ``valve``, ``pilot``.  Packing: one row per valve, columns :data:`COLUMNS` (:func:`law_row`),
read by :func:`flow_with_derivatives` (:attr:`CounterbalanceValve.BRANCH_LAW`).

References: H. Exner et al., *Hydraulics: Basic Principles and Components*, Bosch Rexroth 2011 (counterbalance
valves: setting and pilot ratio); MathWorks, Simscape Fluids, *Counterbalance Valve (IL)* (force balance of
the pilot, load and back pressures on the relief stage, pilot ratio and back-pressure ratio).

Example
-------
>>> from hydraulics.fluid import Fluid
>>> valve = CounterbalanceValve(setting_pressure=1.3e7, pilot_ratio=4.0, area=2e-5)
>>> row = valve.law_row(Fluid())
>>> ambient = Fluid().reference_pressure
>>> abs(flow_with_derivatives(row, ambient + 1e7, ambient, ambient)[0]) < 1e-7  # 100 bar held, pilot vented
True
>>> flow_with_derivatives(row, ambient + 1e7, ambient, ambient + 1e6)[0] > 1e-4  # 10 bar of pilot opens it
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

COLUMNS = ("setting", "band", "ratio", "back_ratio", "ambient", "area", "cracking", "check_band", "check_area",
           "leakage", "k", "c")
"""Row of one valve: relief setting [Pa gauge], relief opening band [Pa], pilot ratio r and back-pressure ratio
r_b [-], reference pressure [Pa], relief area [m²], check cracking pressure and opening band [Pa], check area and
closed area [m²], orifice-law constants k, c."""
SETTING, BAND, RATIO, BACK_RATIO, AMBIENT, AREA, CRACKING, CHECK_BAND, CHECK_AREA, LEAKAGE, K, C = range(len(COLUMNS))


@kernel
def flow_with_derivatives(row, p_load, p_valve, p_pilot):
    """Flow Q [m³/s] from ``load`` to ``valve`` and ∂Q/∂p_load, ∂Q/∂p_valve, ∂Q/∂p_pilot [m³/(s·Pa)] at absolute
    port pressures [Pa]; ``row``: the valve's parameters, columns :data:`COLUMNS`."""
    ambient = row[AMBIENT]
    band = row[BAND]
    z = (p_load - ambient + row[RATIO] * (p_pilot - ambient) - row[BACK_RATIO] * (p_valve - ambient)
         - row[SETTING]) / band
    y, dy = smooth_step_with_derivative(z)
    check_band = row[CHECK_BAND]
    y_check, dy_check = smooth_step_with_derivative((p_valve - p_load - row[CRACKING]) / check_band)
    area = row[LEAKAGE] + row[AREA] * y + row[CHECK_AREA] * y_check
    dp = p_load - p_valve
    q, g = orifice_flow_with_derivative(area, row[K], row[C], dp)
    q_area = orifice_flow_area_derivative(area, row[K], row[C], dp)
    relief = q_area * row[AREA] * dy / band
    check = q_area * row[CHECK_AREA] * dy_check / check_band
    return q, g + relief - check, -g - row[BACK_RATIO] * relief + check, row[RATIO] * relief


@dataclass(frozen=True, kw_only=True)
class CounterbalanceValve:
    """Counterbalance valve (ports load, valve, pilot); law :func:`flow_with_derivatives`."""

    setting_pressure: float = param("Pa", low=0.0, high=1e8)
    """Relief setting p_set: gauge load pressure that opens it with the pilot vented [Pa] (≈ 1.3× the highest
    load pressure)."""
    pilot_ratio: float = param("-", low=0.0, high=100.0, default=4.0)
    """Pilot ratio r: pilot area / load-seat area [-] (3 … 10 typical)."""
    back_pressure_ratio: float = param("-", low=0.0, high=100.0, low_open=False, default=0.0)
    """Back-pressure ratio r_b: area the valve-port pressure closes the relief stage on / load-seat area [-]
    (0: spring chamber vented to atmosphere)."""
    opening_band: float = param("Pa", low=0.0, high=1e8, default=1e6)
    """Rise of p_L + r·p_X − r_b·p_V above the setting over which the relief stage opens fully [Pa]."""
    area: float = param("m^2", low=0.0, high=0.01)
    """Relief stage area fully open [m²]."""
    check_area: float = param("m^2", low=0.0, high=0.01, default=None)
    """Check stage area fully open [m²]; defaults to ``area``."""
    check_cracking_pressure: float = param("Pa", low=0.0, high=1e7, low_open=False, default=1e5)
    """Differential pressure p_V − p_L that cracks the check stage [Pa]."""
    check_opening_band: float = param("Pa", low=0.0, high=1e7, default=2e5)
    """Rise of p_V − p_L above cracking over which the check stage opens fully [Pa]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-11)
    """Area with both stages closed [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("load", "valve", "pilot")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = flow_with_derivatives

    def __post_init__(self):
        if self.check_area is None:
            object.__setattr__(self, "check_area", self.area)

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(COLUMNS, 1, setting=self.setting_pressure, band=self.opening_band, ratio=self.pilot_ratio,
                     back_ratio=self.back_pressure_ratio, ambient=fluid.reference_pressure, area=self.area,
                     cracking=self.check_cracking_pressure, check_band=self.check_opening_band,
                     check_area=self.check_area, leakage=self.leakage_area, k=k, c=c)[0]
