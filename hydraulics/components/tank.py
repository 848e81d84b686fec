"""Tank: a reservoir at a fixed absolute pressure (a fixed node of the network; no law of its own).

Example
-------
>>> Tank().pressure
101325.0
"""

from __future__ import annotations

from dataclasses import dataclass

from .parameters import param


@dataclass(frozen=True, kw_only=True)
class Tank:
    """Reservoir at a fixed absolute pressure."""

    pressure: float = param("Pa", low=0.0, high=1e8, low_open=False, default=1.01325e5)
    """Absolute pressure [Pa]."""
    PORTS = ("port",)

    def fixed_pressure(self, fluid) -> float:
        """Absolute pressure [Pa] the network holds its net at (a component with this method is a fixed node)."""
        return self.pressure
