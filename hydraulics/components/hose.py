"""Hose: a lumped volume at ``compressible`` fidelity, a π-line (half volume per end, laminar resistance
between them) at ``lines`` fidelity.

The line's resistance is Hagen–Poiseuille's, G = π·d⁴/(128·μ·L) [m³/(s·Pa)] (:func:`line_conductance`), a
:class:`LaminarResistance` between the line's two end nodes.

:class:`LaminarResistance` is the law Q = G·(p_a − p_b) of every laminar branch the network makes: a hose's line
at ``lines`` fidelity, a cylinder's or motor's internal leakage (their ``leakage_conductance``).  It is a law
component (:data:`hydraulics.components.BRANCH_LAWS`) without a circuit-file type: one row of :data:`COLUMNS`
per branch, read by :func:`laminar_law`.

Example
-------
>>> round(Hose(length=2.0, inner_diameter=0.02).volume, 9)
0.000628319
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .parameters import param, table


@dataclass(frozen=True, kw_only=True)
class Hose:
    """A hose; at ``compressible`` fidelity its volume joins the net its ends connect."""

    length: float = param("m", low=0.0, high=200.0)
    """Length [m]."""
    inner_diameter: float = param("m", low=0.0, high=0.5)
    """Inner diameter [m]."""
    wall_bulk_modulus: float = param("Pa", low=1e7, high=1e12, low_open=False, default=math.inf)
    """Wall compliance as a bulk modulus [Pa] (rubber hose ≈ 1e8–1e9); inf = rigid."""
    PORTS = ("a", "b")

    @property
    def volume(self) -> float:
        """Internal volume π·d²/4·L [m³]."""
        return math.pi * self.inner_diameter**2 / 4.0 * self.length


def line_conductance(inner_diameter, length, dynamic_viscosity):
    """Laminar (Hagen–Poiseuille) conductance of a pipe, G = π·d⁴/(128·μ·L) [m³/(s·Pa)]; μ [Pa·s]."""
    return math.pi * inner_diameter**4 / (128.0 * dynamic_viscosity * length)


COLUMNS = ("conductance",)
"""Row of one laminar branch: conductance G [m³/(s·Pa)]."""
L_CONDUCTANCE = 0


@kernel
def laminar_law(row, p_a, p_b, p_pilot):
    """Flow Q = G·(p_a − p_b) [m³/s] from ``a`` to ``b`` and ∂Q/∂p_a = G, ∂Q/∂p_b = −G, ∂Q/∂p_pilot = 0
    [m³/(s·Pa)] at absolute port pressures [Pa]; ``row``: columns :data:`COLUMNS`."""
    g = row[L_CONDUCTANCE]
    return g * (p_a - p_b), g, -g, 0.0


@dataclass(frozen=True, kw_only=True)
class LaminarResistance:
    """Laminar resistance Q = G·(p_a − p_b) (ports a, b): a hose's line, an actuator's internal leakage; law
    :func:`laminar_law`."""

    conductance: float = param("m^3/(s*Pa)", low=0.0, high=1.0)
    """Conductance G [m³/(s·Pa)]."""
    PORTS = ("a", "b")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = laminar_law

    def law_row(self, fluid) -> np.ndarray:
        """This resistance's row of :data:`COLUMNS` (``fluid`` unused: G is given)."""
        return table(COLUMNS, 1, conductance=self.conductance)[0]
