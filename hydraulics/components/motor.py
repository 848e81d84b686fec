"""Hydraulic motor: swallows Q = D·ω/(2π) from port a to b; shaft torque τ = D·(p_a − p_b)/(2π).

An actuator (coordinate: shaft angle [rad], effort: torque [N·m]); its flow is a branch set by the shaft
speed (:func:`flow`), its torque is :func:`hydraulics.components.pumps.torque`, and its cross-port leakage a
laminar branch.

Packing: the motor table (its actuator and port nodes), columns :data:`INDEX_COLUMNS` (:func:`pack_index`).

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
from .parameters import param


@dataclass(frozen=True, kw_only=True)
class Motor:
    """Hydraulic motor: swallows Q = D·ω/(2π) from port a to b; torque τ = D·(p_a − p_b)/(2π)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Displacement D [m³/rev]."""
    leakage_conductance: float = param("m^3/(s*Pa)", low=0.0, high=1e-6, low_open=False, default=0.0)
    """Cross-port leakage conductance [m³/(s·Pa)]."""
    PORTS = ("a", "b")


@kernel
def flow(displacement, shaft_speed):
    """Flow [m³/s] swallowed at shaft speed ω [rad/s]: Q = D·ω/(2π), D [m³/rev]."""
    return displacement * shaft_speed / (2.0 * math.pi)


INDEX_COLUMNS = ("actuator", "a", "b")
"""Motor index table: actuator number, node of port a, node of port b."""
MI_ACT, MI_A, MI_B = range(len(INDEX_COLUMNS))


def pack_index(model) -> np.ndarray:
    """The motor index table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`INDEX_COLUMNS`."""
    count = len(model.motor_actuator)
    return np.column_stack([np.asarray(c, np.int64).reshape(count) for c in
                            (model.motor_actuator, model.motor_a_node, model.motor_b_node)])
