"""Pumps: fixed displacement, and pressure-compensated variable displacement.

Delivery Q = η_v·D·n [m³/s] (:func:`flow`) with D [m³/rev], n [rev/s]; ideal shaft torque τ = D·Δp/(2π)
[N·m] (:func:`torque`).  A compensated pump destrokes over a band above its setting:
D(p_out) = D_max·clip((p_c + band − p_out)/band, 0, 1) (:func:`compensated_displacement_with_derivative`).
A fixed pump is packed as a compensated one with p_c = inf.

Packing: the pump-branch table, columns :data:`COLUMNS` (:func:`pack`).

Example
-------
>>> round(flow(1e-5, 25.0, 0.95), 10)
0.0002375
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .parameters import param, table
from .ramps import unit_clip_with_derivative


@dataclass(frozen=True, kw_only=True)
class PumpFixed:
    """Fixed-displacement pump: Q = η_v·D·n, τ = D·Δp/(2π)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Geometric displacement D [m³/rev]."""
    speed: float = param("rev/s", low=0.0, high=1000.0, low_open=False, default=0.0)
    """Nominal shaft speed n [rev/s]; scenarios may schedule it."""
    volumetric_efficiency: float = param("-", low=0.0, high=1.0, default=1.0)
    """η_v [-]."""
    PORTS = ("inlet", "outlet")


@dataclass(frozen=True, kw_only=True)
class PumpCompensated:
    """Pressure-compensated variable pump: full displacement below the setting, zero at setting + band."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Maximum displacement D_max [m³/rev]."""
    speed: float = param("rev/s", low=0.0, high=1000.0, low_open=False, default=0.0)
    """Nominal shaft speed n [rev/s]."""
    compensator_pressure: float = param("Pa", low=0.0, high=1e9)
    """Outlet pressure where destroking starts [Pa, absolute]."""
    compensator_band: float = param("Pa", low=0.0, high=1e8, default=1e6)
    """Pressure rise over which the displacement falls to zero [Pa]."""
    PORTS = ("inlet", "outlet")


@kernel
def compensated_displacement_with_derivative(max_displacement, outlet, compensator, band):
    """Displacement [m³/rev] at outlet pressure ``outlet`` [Pa] and dD/dp_out [m³/(rev·Pa)]."""
    frac, dfrac = unit_clip_with_derivative((compensator + band - outlet) / band)
    return max_displacement * frac, -max_displacement * dfrac / band


@kernel
def flow(displacement, speed, efficiency):
    """Delivery Q = η_v·D·n [m³/s]; D [m³/rev], n [rev/s]."""
    return efficiency * displacement * speed


@kernel
def torque(displacement, delta_p):
    """Ideal pump (or motor) shaft torque τ = D·Δp/(2π) [N·m]; D [m³/rev], Δp [Pa]."""
    return displacement * delta_p / (2.0 * math.pi)


COLUMNS = ("displacement", "efficiency", "compensator", "band")
"""Pump-branch table: (maximum) displacement [m³/rev], η_v [-], compensator setting [Pa] (inf: fixed pump),
band [Pa]."""
P_DISP, P_EFF, P_COMP, P_BAND = range(len(COLUMNS))


def pack(model) -> np.ndarray:
    """The pump-branch table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`COLUMNS`."""
    return table(COLUMNS, len(model.pump_displacement), displacement=model.pump_displacement,
                 efficiency=model.pump_efficiency, compensator=model.pump_compensator, band=model.pump_band)
