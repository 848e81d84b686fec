"""Pumps: fixed displacement, and pressure-compensated variable displacement, as law components.

Delivery Q = η_v·D·n [m³/s] (:func:`flow`) from ``inlet`` to ``outlet`` with D [m³/rev] and the shaft speed n
[rev/s], the component's scheduled input ``speed`` (default: its field ``speed``); ideal shaft torque
τ = D·Δp/(2π) [N·m] (:func:`torque`).  A compensated pump destrokes over a band w above its setting p_c:

    D(p_out) = D_max·clip((p_c + w − p_out)/w, 0, 1),      ∂Q/∂p_out = −η_v·D_max·n/w inside the band, else 0

(:func:`compensated_displacement_with_derivative`, :func:`flow_with_derivatives`).  A fixed pump has the same law
with p_c = inf (its row: :meth:`PumpFixed.law_row`).  The kink hook :func:`law_piece` numbers the compensator's
pieces (full displacement, destroking, destroked).  The pumps' work Q·(μ_out − μ_in) enters the energy ledger as
pump work (``SOURCE``).

Limitations: no leakage and no torque limit; the compensator acts at once (no swash plate dynamics: see
:mod:`hydraulics.components.pump_load_sensing` for a regulated swash plate).

Example
-------
>>> round(flow(1e-5, 25.0, 0.95), 10)
0.0002375
>>> import numpy as np
>>> pump = PumpCompensated(displacement=1e-5, speed=25.0, compensator_pressure=2e7, compensator_band=1e6)
>>> q, _, dq_out, _ = flow_with_derivatives(pump.law_row(None), 1e5, 2.05e7, 0.0, np.array(pump.input_start()))
>>> round(q, 10), round(dq_out * 1e6 / -2.5e-4, 12)  # half destroked; ∂Q/∂p_out = −D·n/w
(0.000125, 1.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .parameters import param, table
from .ramps import ramp_piece, unit_clip_with_derivative

COLUMNS = ("displacement", "efficiency", "compensator", "band")
"""Row of one pump: (maximum) displacement [m³/rev], η_v [-], compensator setting [Pa] (inf: fixed pump), band [Pa]."""
P_DISP, P_EFF, P_COMP, P_BAND = range(len(COLUMNS))


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


@kernel
def flow_with_derivatives(row, p_in, p_out, p_pilot, inputs):
    """Delivery Q [m³/s] from inlet to outlet at the shaft speed ``inputs[0]`` [rev/s] and the outlet pressure
    ``p_out`` [Pa], and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_pilot [m³/(s·Pa)] (only the compensator reads a pressure)."""
    displacement, slope = compensated_displacement_with_derivative(row[P_DISP], p_out, row[P_COMP], row[P_BAND])
    speed = inputs[0]
    return flow(displacement, speed, row[P_EFF]), 0.0, flow(slope, speed, row[P_EFF]), 0.0


@kernel
def law_piece(row, state, h, p_in, p_out, p_pilot):
    """Kink hook: the compensator's piece at ``p_out`` [Pa], 2 at full displacement, 1 destroking, 0 destroked."""
    return ramp_piece((row[P_COMP] + row[P_BAND] - p_out) / row[P_BAND], 1.0)


@dataclass(frozen=True, kw_only=True)
class PumpFixed:
    """Fixed-displacement pump: Q = η_v·D·n, τ = D·Δp/(2π) (ports inlet, outlet; input speed)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Geometric displacement D [m³/rev]."""
    speed: float = param("rev/s", low=0.0, high=1000.0, low_open=False, default=0.0)
    """Nominal shaft speed n [rev/s]; scenarios may schedule it."""
    volumetric_efficiency: float = param("-", low=0.0, high=1.0, default=1.0)
    """η_v [-]."""
    PORTS = ("inlet", "outlet")
    LAW_COLUMNS = COLUMNS
    INPUTS = ("speed",)
    INPUT_UNITS = ("rev/s",)
    BRANCH_LAW = flow_with_derivatives
    LAW_PIECE = law_piece  # constant: no compensator
    SOURCE = True
    """Its flow's power Q·(μ_out − μ_in) is pump work, not dissipation."""

    def input_start(self) -> tuple:
        """The shaft speed [rev/s] when no scenario schedules it: the field ``speed``."""
        return (self.speed,)

    def law_row(self, fluid) -> np.ndarray:
        """This pump's row of :data:`COLUMNS`: no compensator (``fluid`` unused: the law is volumetric)."""
        return table(COLUMNS, 1, displacement=self.displacement, efficiency=self.volumetric_efficiency,
                     compensator=math.inf, band=1.0)[0]


@dataclass(frozen=True, kw_only=True)
class PumpCompensated:
    """Pressure-compensated variable pump: full displacement below the setting, zero at setting + band (ports inlet,
    outlet; input speed)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Maximum displacement D_max [m³/rev]."""
    speed: float = param("rev/s", low=0.0, high=1000.0, low_open=False, default=0.0)
    """Nominal shaft speed n [rev/s]; scenarios may schedule it."""
    compensator_pressure: float = param("Pa", low=0.0, high=1e9)
    """Outlet pressure where destroking starts [Pa, absolute]."""
    compensator_band: float = param("Pa", low=0.0, high=1e8, default=1e6)
    """Pressure rise over which the displacement falls to zero [Pa]."""
    PORTS = ("inlet", "outlet")
    LAW_COLUMNS = COLUMNS
    INPUTS = ("speed",)
    INPUT_UNITS = ("rev/s",)
    BRANCH_LAW = flow_with_derivatives
    LAW_PIECE = law_piece
    SOURCE = True
    """Its flow's power Q·(μ_out − μ_in) is pump work, not dissipation."""

    def input_start(self) -> tuple:
        """The shaft speed [rev/s] when no scenario schedules it: the field ``speed``."""
        return (self.speed,)

    def law_row(self, fluid) -> np.ndarray:
        """This pump's row of :data:`COLUMNS` (η_v = 1; ``fluid`` unused: the law is volumetric)."""
        return table(COLUMNS, 1, displacement=self.displacement, efficiency=1.0,
                     compensator=self.compensator_pressure, band=self.compensator_band)[0]
