"""Volume: a lumped oil volume (line, manifold, port volume) that joins its net's node.

The node's volume is V = V_0 + V_0·(p − p_ref)/β_wall (elastic wall, :attr:`Volume.wall_bulk_modulus`);
the network sums it with the other volumes on the node (``hydraulics.network``).

Example
-------
>>> Volume(volume=1e-3).wall_bulk_modulus
inf
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .parameters import param


@dataclass(frozen=True, kw_only=True)
class Volume:
    """A lumped oil volume (line, manifold, port volume)."""

    volume: float = param("m^3", low=0.0, high=10.0)
    """Volume at the reference pressure [m³]."""
    wall_bulk_modulus: float = param("Pa", low=1e7, high=1e12, low_open=False, default=math.inf)
    """Wall compliance as a bulk modulus [Pa]; inf = rigid."""
    PORTS = ("port",)
