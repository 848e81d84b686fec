"""Pressure-compensated two-way flow control valve: a metering orifice in series with a compensator that keeps
the pressure drop across the orifice at Δp_c, so the flow stays at its setting whatever the pressure drop.

With an ideal compensator (fully open while the valve's drop Δp = p_in − p_out is below Δp_c, throttling the
excess above it) the metering orifice sees min(Δp, Δp_c); the law blends the two with the C¹ smooth ramp r of
:func:`hydraulics.components.ramps.smooth_ramp_with_derivative` over a width w centred on Δp_c:

    Δp_m = Δp − r(Δp − Δp_c + w/2, w),   Q = Q_orifice(A_m, Δp_m),   ∂Q/∂Δp = Q_Δ(A_m, Δp_m)·(1 − r'),

the orifice law of :mod:`hydraulics.components.orifice`: Q = Q_set exactly for Δp ≥ Δp_c + w/2, the orifice
alone for Δp ≤ Δp_c − w/2 (and in reverse flow, where the compensator is pushed fully open and the valve
meters uncompensated).  The metering area A_m is the one that passes Q_set at Δp_c through the orifice law,
laminar blend included: A_m = A_t·sqrt(ω), A_t = Q_set/(C_d·sqrt(2Δp_c/ρ)), ω the root above 1 of
ω³ − ω − (p_tr/Δp_c)² = 0, p_tr the orifice's transition pressure at A_t (:func:`metering_area`).

Derivatives: ∂Q/∂p_in = −∂Q/∂p_out = Q_Δ·(1 − r'); no pilot terminal.

Limitations: ideal compensator (no spring rate: real valves let the flow rise by a few percent over their
pressure range; no compensator dynamics, so no start-up jump); no bypass check for reverse flow; viscosity
fixed (no temperature compensation).

Ports: ``inlet``, ``outlet``.  Packing: one row per valve, columns :data:`COLUMNS` (:func:`law_row`), read by
:func:`flow_with_derivatives` (:attr:`FlowControlValve.BRANCH_LAW`).

References: H. Exner et al., *Hydraulics: Basic Principles and Components*, Bosch Rexroth 2011 (flow control
valves, two-way, pressure-compensated); H. E. Merritt, *Hydraulic Control Systems*, Wiley 1967, §2.4.

Example
-------
>>> from hydraulics.fluid import Fluid
>>> valve = FlowControlValve(flow_setting=1e-4)  # 6 L/min
>>> row = valve.law_row(Fluid())
>>> [round(flow_with_derivatives(row, dp, 0.0, 0.0)[0] * 6e4, 4) for dp in (1e6, 1e7)]
[6.0, 6.0]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .orifice import coefficients as orifice_coefficients
from .orifice import flow_with_derivative as orifice_flow_with_derivative
from .parameters import CircuitError, param, table
from .ramps import smooth_ramp_with_derivative

COLUMNS = ("compensator", "width", "area", "k", "c")
"""Row of one valve: compensator pressure drop Δp_c [Pa], blend width w [Pa], metering area A_m [m²],
orifice-law constants k, c."""
COMPENSATOR, WIDTH, AREA, K, C = range(len(COLUMNS))


@kernel
def flow_with_derivatives(row, p_in, p_out, p_x):
    """Flow Q [m³/s] from ``inlet`` to ``outlet`` and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_x (0: two ports) [m³/(s·Pa)] at
    absolute port pressures [Pa]; ``row``: the valve's parameters, columns :data:`COLUMNS`."""
    width = row[WIDTH]
    dp = p_in - p_out
    excess, slope = smooth_ramp_with_derivative(dp - row[COMPENSATOR] + 0.5 * width, width)
    q, g = orifice_flow_with_derivative(row[AREA], row[K], row[C], dp - excess)
    g = g * (1.0 - slope)
    return q, g, -g, 0.0


def metering_area(flow, compensator, k, c) -> float:
    """Area A_m [m²] that passes ``flow`` [m³/s] at ``compensator`` Δp_c [Pa] through the orifice law with
    constants (k, c) (:func:`hydraulics.components.orifice.coefficients`).

    Q = k·Δp·A^(3/2)/(A²Δp² + c²)^(1/4) with A = A_t·sqrt(ω), A_t = Q/(k·sqrt(Δp)) gives ω³ − ω − ε = 0,
    ε = (c/(A_t·Δp))²; its one positive root is above 1 (Descartes' rule of signs).
    """
    turbulent = flow / (k * math.sqrt(compensator))
    eps = (c / (turbulent * compensator)) ** 2
    roots = np.roots([1.0, 0.0, -1.0, -eps])
    omega = max(r.real for r in roots if abs(r.imag) <= 1e-9 * abs(r))
    return turbulent * math.sqrt(omega)


@dataclass(frozen=True, kw_only=True)
class FlowControlValve:
    """Pressure-compensated flow control valve (ports inlet, outlet); law :func:`flow_with_derivatives`."""

    flow_setting: float = param("m^3/s", low=0.0, high=0.1)
    """Flow Q_set held for pressure drops above the compensator's [m³/s]."""
    compensator_pressure: float = param("Pa", low=0.0, high=1e7, default=6e5)
    """Pressure drop Δp_c the compensator holds across the metering orifice: the valve's least working drop [Pa]."""
    blend_width: float = param("Pa", low=0.0, high=1e7, default=None)
    """Width w of the blend between orifice and held flow, centred on Δp_c [Pa]; defaults to 0.2·Δp_c."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d of the metering orifice [-]."""
    PORTS = ("inlet", "outlet")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = flow_with_derivatives

    def __post_init__(self):
        if self.blend_width is None:
            object.__setattr__(self, "blend_width", 0.2 * self.compensator_pressure)

    def check(self, where: str) -> None:
        """Raise CircuitError (prefixed by ``where``) unless the blend lies at positive pressure drops."""
        if self.blend_width >= 2.0 * self.compensator_pressure:
            raise CircuitError(f"{where}, field 'blend_width': {self.blend_width!r} Pa must be smaller than "
                               f"2·compensator_pressure = {2.0 * self.compensator_pressure!r} Pa")

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        area = metering_area(self.flow_setting, self.compensator_pressure, float(k), float(c))
        return table(COLUMNS, 1, compensator=self.compensator_pressure, width=self.blend_width, area=area, k=k,
                     c=c)[0]
