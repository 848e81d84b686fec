"""Gas-charged accumulator (polytropic gas): liquid volume added to its node above the precharge.

p·V_g^n = p_0·V_0^n, so V_liquid = V_0·(1 − (p_0/p)^(1/n)) above the precharge p_0 and zero below (the bladder
rests on its seat); dV/dp = V_0·(p_0/p)^(1/n)/(n·p) (:func:`liquid_volume_with_derivative`).

Packing: the accumulator table, columns :data:`COLUMNS` (:func:`pack`).

Example
-------
>>> round(liquid_volume_with_derivative(2e7, 1e-3, 1e7, 1.0)[0], 12)
0.0005
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel, maximum
from .parameters import param, table


@dataclass(frozen=True, kw_only=True)
class Accumulator:
    """Gas-charged accumulator (polytropic gas)."""

    gas_volume: float = param("m^3", low=0.0, high=10.0)
    """Gas volume at precharge V_0 [m³]."""
    precharge_pressure: float = param("Pa", low=0.0, high=1e9)
    """Precharge absolute pressure p_0 [Pa]."""
    polytropic_index: float = param("-", low=1.0, high=1.67, low_open=False, default=1.4)
    """Polytropic index n [-] (1 isothermal, 1.4 adiabatic)."""
    PORTS = ("port",)


@kernel
def liquid_volume_with_derivative(p, gas, pre, n):
    """Liquid volume [m³] at pressure ``p`` [Pa] and dV/dp [m³/Pa]; ``gas`` V_0 [m³], ``pre`` p_0 [Pa], ``n`` [-]."""
    pc = maximum(p, pre)
    ratio = (pre / pc) ** (1.0 / n)
    if p > pre:
        return gas * (1.0 - ratio), gas * ratio / (n * pc)
    return 0.0, 0.0


COLUMNS = ("gas_volume", "precharge", "index")
"""Accumulator table: V_0 [m³], p_0 [Pa], n [-]."""
ACC_GAS, ACC_PRE, ACC_INDEX = range(len(COLUMNS))


def pack(model) -> np.ndarray:
    """The accumulator table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`COLUMNS`."""
    return table(COLUMNS, len(model.accumulator_node), gas_volume=model.accumulator_gas_volume,
                 precharge=model.accumulator_precharge, index=model.accumulator_index)
