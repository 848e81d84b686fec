"""Check valve: closed (leakage only) below cracking, area rising linearly to full opening; orifice law.

A(Δp) = A_leak + A_max·clip((Δp − p_crack)/(p_full − p_crack), 0, 1) and Q = orifice law at A(Δp)
(:mod:`hydraulics.components.orifice`), so dQ/dΔp = ∂Q/∂Δp + ∂Q/∂A·dA/dΔp (:func:`flow_with_derivative`).

A law component (:data:`hydraulics.components.BRANCH_LAWS`): ports ``inlet``, ``outlet``; one row of
:data:`COLUMNS` per valve (:meth:`CheckValve.law_row`), read by :func:`branch_law`; its kink hook
:func:`law_piece` numbers the pieces of the opening (closed, opening, fully open).

Example
-------
>>> area_with_derivative(5.5e4, 1e4, 1e5, 1e-4, 0.0)
(5e-05, 1.111111111111111e-09)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .orifice import coefficients as orifice_coefficients
from .orifice import flow_area_derivative as orifice_flow_area_derivative
from .orifice import flow_with_derivative as orifice_flow_with_derivative
from .parameters import CircuitError, param, table
from .ramps import ramp_piece, unit_clip_with_derivative


@kernel
def area_with_derivative(dp, cracking, full_open, max_area, leakage_area):
    """Open area [m²] at Δp = inlet − outlet [Pa] and dA/dΔp [m²/Pa]."""
    span = full_open - cracking
    frac, dfrac = unit_clip_with_derivative((dp - cracking) / span)
    return leakage_area + max_area * frac, max_area * dfrac / span


@kernel
def flow_with_derivative(dp, cracking, full_open, max_area, leakage_area, k, c):
    """Flow Q [m³/s] and total dQ/dΔp [m³/(s·Pa)] at Δp = inlet − outlet [Pa]; (k, c) of the orifice law."""
    a, da = area_with_derivative(dp, cracking, full_open, max_area, leakage_area)
    q, g = orifice_flow_with_derivative(a, k, c, dp)
    return q, g + orifice_flow_area_derivative(a, k, c, dp) * da


COLUMNS = ("cracking", "full_open", "area", "leakage", "k", "c")
"""Row of one valve: cracking and full-open pressures [Pa], full and closed areas [m²], orifice-law constants
k, c (:func:`hydraulics.components.orifice.coefficients`)."""
K_CRACK, K_FULL, K_AREA, K_LEAK, K_K, K_C = range(len(COLUMNS))


@kernel
def branch_law(row, p_in, p_out, p_pilot):
    """Flow Q [m³/s] from ``inlet`` to ``outlet`` and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_pilot (= 0) [m³/(s·Pa)] at
    absolute port pressures [Pa]; ``row``: the valve's parameters, columns :data:`COLUMNS`."""
    q, g = flow_with_derivative(p_in - p_out, row[K_CRACK], row[K_FULL], row[K_AREA], row[K_LEAK], row[K_K],
                                row[K_C])
    return q, g, -g, 0.0


@kernel
def law_piece(row, state, h, p_in, p_out, p_pilot):
    """Piece of the opening Δp lies on: 0 closed (Δp ≤ p_crack), 1 opening, 2 fully open (Δp ≥ p_full)."""
    return ramp_piece((p_in - p_out - row[K_CRACK]) / (row[K_FULL] - row[K_CRACK]), 1.0)


@dataclass(frozen=True, kw_only=True)
class CheckValve:
    """Check valve: closed below cracking, area rising linearly to full opening (ports inlet, outlet); law
    :func:`branch_law`."""

    cracking_pressure: float = param("Pa", low=0.0, high=1e8, low_open=False, default=1e4)
    """Differential pressure where it starts to open [Pa]."""
    full_open_pressure: float = param("Pa", low=0.0, high=1e8, default=1e5)
    """Differential pressure where it is fully open [Pa]."""
    area: float = param("m^2", low=0.0, high=0.01)
    """Fully open area [m²]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-10)
    """Closed area [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("inlet", "outlet")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = branch_law
    LAW_PIECE = law_piece

    def check(self, where: str) -> None:
        """Raise CircuitError (prefixed by ``where``) unless the valve opens over a positive span."""
        if self.full_open_pressure <= self.cracking_pressure:
            raise CircuitError(f"{where}, field 'full_open_pressure': must exceed cracking_pressure")

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(COLUMNS, 1, cracking=self.cracking_pressure, full_open=self.full_open_pressure,
                     area=self.area, leakage=self.leakage_area, k=k, c=c)[0]
