"""Hose: a lumped volume at ``compressible`` fidelity, a π-line (half volume per end, laminar resistance
between them) at ``lines`` fidelity.

The line's resistance is Hagen–Poiseuille's, G = π·d⁴/(128·μ·L) [m³/(s·Pa)] (:func:`line_conductance`),
packed into the network's laminar branches.

Example
-------
>>> round(Hose(length=2.0, inner_diameter=0.02).volume, 9)
0.000628319
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .parameters import param


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
