"""Ideal pressure source: one port held at a fixed gauge pressure, whatever flow it gives or takes.

The network makes its net a fixed node at the absolute pressure p = p_ref + Δp_s (:meth:`PressureSource.fixed_pressure`,
p_ref the fluid's reference pressure), like a tank; oil leaves it at the rate the branches on its net draw.  The
work it supplies is counted in the energy ledger as supplied work (with the pumps' work):

    P_s = μ(p)·(Σ Q of the branches leaving its net − Σ Q of those entering it)   [W],

μ the pressure potential of :meth:`hydraulics.fluid.Fluid.pressure_potential` (≈ Δp_s for pure oil; a stiff supply
of unlimited flow: the ideal source of Hopsan's ``PressureSource``, Simscape Fluids' "Pressure Source (IL)").
A supply at Δp_s through an orifice of area a and discharge coefficient C_d into a cylinder of cap area A lifting a
load F moves it at v = (C_d·a/A)·√(2·(Δp_s − F/A)/ρ).

**Limitations**: no flow limit and no dynamics (an ideal source); the pressure is gauge, above the reference, and
fixed for the run (no schedule).

Example
-------
>>> from hydraulics.fluid import Fluid
>>> PressureSource(pressure=2.0e7).fixed_pressure(Fluid())
20101325.0
"""

from __future__ import annotations

from dataclasses import dataclass

from .parameters import param


@dataclass(frozen=True, kw_only=True)
class PressureSource:
    """Ideal pressure source: one port at a fixed gauge pressure (its delivered work in the energy ledger)."""

    pressure: float = param("Pa", low=0.0, high=1e9, low_open=False)
    """Gauge pressure Δp_s above the fluid's reference pressure [Pa]."""
    PORTS = ("port",)

    def fixed_pressure(self, fluid) -> float:
        """Absolute pressure [Pa] the network holds its net at: p_ref + Δp_s."""
        return fluid.reference_pressure + self.pressure
