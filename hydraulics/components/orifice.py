"""Orifice: turbulent flow with a laminar region near Δp = 0; also the law of every valve metering edge.

The turbulent law Q = C_d·A·sqrt(2Δp/ρ) holds for |Δp| ≫ p_tr; near Δp = 0 it is blended into a laminar
(linear) law,

    Q = C_d·A·sqrt(2/ρ) · Δp / (Δp² + p_tr²)^(1/4),   p_tr = (ρ/2)·(Re_c·ν/(C_d·D_h))²,   D_h = sqrt(4A/π),

written with A^(3/2) so that A = 0 gives exactly zero flow and slope:
Q = k·Δp·A^(3/2)/(A²Δp² + c²)^(1/4) with k = C_d·sqrt(2/ρ) and c = p_tr·A (independent of A,
:func:`coefficients`).  Q and dQ/dΔp stay finite everywhere.

References: H. E. Merritt, *Hydraulic Control Systems*, Wiley 1967, §2.4 (orifice flow, critical Reynolds
number 10–1000; 150 is the value several lumped-parameter tools use).

Packing: the metering edges of the 4/3 valves form the network's orifice-branch table, columns :data:`COLUMNS`
(:func:`pack`); a fixed :class:`Orifice` is a law component (:data:`hydraulics.components.BRANCH_LAWS`), one row
of :data:`LAW_COLUMNS` per orifice read by :func:`branch_law`.

Example
-------
>>> k, c = coefficients(0.7, 850.0, 4.6e-5)
>>> q, g = flow_with_derivative(1e-5, k, c, 1e6)
>>> round(q * 6e4, 2)  # L/min through 10 mm² at 10 bar
20.37
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .parameters import param, table

CRITICAL_REYNOLDS = 150.0  # [-] laminar–turbulent transition of a sharp-edged orifice (Merritt §2.4: 10–1000)


def coefficients(discharge_coefficient, density, kinematic_viscosity):
    """Constants (k, c) of the orifice law: k = C_d·sqrt(2/ρ) [m^(3/2)/kg^(1/2)], c = p_tr·A [Pa·m²]."""
    cd = np.asarray(discharge_coefficient, dtype=float)
    c = 0.5 * density * (CRITICAL_REYNOLDS * kinematic_viscosity) ** 2 * np.pi / (4.0 * cd**2)
    return cd * np.sqrt(2.0 / density), c


@kernel
def flow_with_derivative(area, k, c, dp):
    """Orifice flow Q [m³/s] (from upstream to downstream) and dQ/dΔp [m³/(s·Pa)] at open area ``area`` [m²] and
    pressure difference ``dp`` = upstream − downstream [Pa]; (k, c) from :func:`coefficients`.

    Q = k·Δp·A^(3/2)/s^(1/4), dQ/dΔp = k·A^(3/2)·(A²Δp²/2 + c²)/s^(5/4), s = A²Δp² + c²
    (sqrt(sqrt(s)) and A·sqrt(A): s^(1/4) and A^(3/2) to within an ulp, several times cheaper than pow).
    """
    adp = area * dp
    a_dp_sq = adp * adp
    s = a_dp_sq + c * c
    root4 = math.sqrt(math.sqrt(s))
    a32 = area * math.sqrt(area)
    return k * dp * a32 / root4, k * a32 * (0.5 * a_dp_sq + c * c) / (s * root4)


@kernel
def flow_area_derivative(area, k, c, dp):
    """∂Q/∂A [m/s] of :func:`flow_with_derivative` (for pressure-opened valves):
    k·Δp·sqrt(A)·(A²Δp² + 3c²/2)/s^(5/4)."""
    adp = area * dp
    a_dp_sq = adp * adp
    s = a_dp_sq + c * c
    return k * dp * math.sqrt(area) * (a_dp_sq + 1.5 * c * c) / (s * math.sqrt(math.sqrt(s)))


LAW_COLUMNS = ("area", "k", "c")
"""Row of one fixed orifice: area A [m²], law constants k, c (:func:`coefficients`)."""
F_AREA, F_K, F_C = range(len(LAW_COLUMNS))


@kernel
def branch_law(row, p_a, p_b, p_pilot):
    """Flow Q [m³/s] from ``a`` to ``b`` through a fixed orifice and ∂Q/∂p_a, ∂Q/∂p_b, ∂Q/∂p_pilot (= 0)
    [m³/(s·Pa)] at absolute port pressures [Pa]; ``row``: columns :data:`LAW_COLUMNS`."""
    q, g = flow_with_derivative(row[F_AREA], row[F_K], row[F_C], p_a - p_b)
    return q, g, -g, 0.0


@dataclass(frozen=True, kw_only=True)
class Orifice:
    """Fixed orifice (ports a, b); law :func:`branch_law`."""

    area: float = param("m^2", low=0.0, high=0.1)
    """Open area A [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("a", "b")
    LAW_COLUMNS = LAW_COLUMNS
    BRANCH_LAW = branch_law

    def law_row(self, fluid) -> np.ndarray:
        """This orifice's row of :data:`LAW_COLUMNS` in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
        k, c = coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(LAW_COLUMNS, 1, area=self.area, k=k, c=c)[0]


COLUMNS = ("k", "c", "base_area", "max_area", "centre_area", "sign")
"""Orifice-branch table: law constants k, c; area when closed [m²] (leakage); metering area
fully open [m²]; open/tandem centre passage area [m²]; metering direction (+1 opens with s > 0, −1 with s < 0,
0 no metering)."""
O_K, O_C, O_BASE, O_MAX, O_CENTRE, O_SIGN = range(len(COLUMNS))


def pack(model) -> np.ndarray:
    """The orifice-branch table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`COLUMNS`."""
    fluid = model.fluid
    k, c = coefficients(model.orifice_cd, fluid.density, fluid.kinematic_viscosity)
    return table(COLUMNS, len(model.orifice_cd), k=k, c=c, base_area=model.orifice_base_area,
                 max_area=model.orifice_max_area, centre_area=model.orifice_centre_area, sign=model.orifice_sign)
