"""Hydraulic motor: swallows Q = D·ω/(2π) from port a to b; shaft torque τ = D·(p_a − p_b)/(2π).

An actuator (coordinate: shaft angle [rad], effort: torque [N·m]).  Its flow is a law component
(:data:`hydraulics.components.BRANCH_LAWS`) whose input is its own shaft speed (``ACTUATOR_INPUT``): the branch
from port a to b carries :func:`flow_law`, with ∂Q/∂ω = D/(2π) (:func:`velocity_rate`) and no pressure
dependence; its power Q·(μ_a − μ_b) is the work delivered to the shaft.  Its torque is
:func:`hydraulics.components.pumps.torque`, and its cross-port leakage a laminar branch.

Packing: the law row (:data:`COLUMNS`, :meth:`Motor.law_row`) and the motor table (its actuator and port nodes,
columns :data:`INDEX_COLUMNS`, :func:`pack_index`) that the torque reads.

Limitations: no volumetric or mechanical efficiency; the displacement is fixed.

Example
-------
>>> round(flow(2 * 3.141592653589793e-5, 10.0), 12)
0.0001
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .parameters import param, table

COLUMNS = ("displacement",)
"""Law row of one motor: displacement D [m³/rev]."""
M_DISP = 0


@kernel
def flow(displacement, shaft_speed):
    """Flow [m³/s] swallowed at shaft speed ω [rad/s]: Q = D·ω/(2π), D [m³/rev]."""
    return displacement * shaft_speed / (2.0 * math.pi)


@kernel
def flow_law(row, p_a, p_b, p_pilot, inputs):
    """Flow Q = D·ω/(2π) [m³/s] from port a to b at the shaft speed ``inputs[0]`` = ω [rad/s], and
    ∂Q/∂p_a = ∂Q/∂p_b = ∂Q/∂p_pilot = 0 [m³/(s·Pa)] (the flow is displaced, not driven by the pressures)."""
    return flow(row[M_DISP], inputs[0]), 0.0, 0.0, 0.0


@kernel
def velocity_rate(row):
    """∂Q/∂ω = D/(2π) [m³/rad] of :func:`flow_law`."""
    return row[M_DISP] / (2.0 * np.pi)


@dataclass(frozen=True, kw_only=True)
class Motor:
    """Hydraulic motor: swallows Q = D·ω/(2π) from port a to b; torque τ = D·(p_a − p_b)/(2π)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Displacement D [m³/rev]."""
    leakage_conductance: float = param("m^3/(s*Pa)", low=0.0, high=1e-6, low_open=False, default=0.0)
    """Cross-port leakage conductance [m³/(s·Pa)]."""
    PORTS = ("a", "b")
    LAW_COLUMNS = COLUMNS
    BRANCH_LAW = flow_law
    ACTUATOR_INPUT = True
    """Its law's input is its own shaft speed [rad/s]; its flow's power is work on the shaft."""
    VELOCITY_RATE = velocity_rate

    def law_row(self, fluid) -> np.ndarray:
        """This motor's row of :data:`COLUMNS` (``fluid`` unused: the law is volumetric)."""
        return table(COLUMNS, 1, displacement=self.displacement)[0]


INDEX_COLUMNS = ("actuator", "a", "b")
"""Motor index table: actuator number, node of port a, node of port b."""
MI_ACT, MI_A, MI_B = range(len(INDEX_COLUMNS))


def pack_index(model) -> np.ndarray:
    """The motor index table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`INDEX_COLUMNS`."""
    count = len(model.motor_actuator)
    return np.column_stack([np.asarray(c, np.int64).reshape(count) for c in
                            (model.motor_actuator, model.motor_a_node, model.motor_b_node)])
