"""Component kinds of a hydraulic circuit: one module per kind, and the registry.

Each module holds its parameter dataclass (frozen, keyword-only; every field carries its unit and allowed range
in ``field(metadata=...)`` through :func:`param`), its law(s) with analytic derivatives as compiled scalar
functions (:mod:`hydraulics._jit`), and its packing into the network's tables (named columns).
:data:`COMPONENT_TYPES` maps the circuit-file ``type`` name to the dataclass; :func:`build_component` validates
a table read from a circuit file against it, so every message names the file, the component, the field and the
allowed range.

Example
-------
>>> build_component("orifice", {"area": 1e-5}, "circuit.toml: component 'o1'")
Orifice(area=1e-05, discharge_coefficient=0.7)
"""

from __future__ import annotations

from dataclasses import MISSING, fields

from .accumulator import Accumulator
from .check_valve import CheckValve
from .counterbalance import CounterbalanceValve
from .cylinder import Cylinder
from .flow_control import FlowControlValve
from .hose import Hose
from .motor import Motor
from .orifice import Orifice
from .parameters import CircuitError, check_number, describe_range, param
from .pilot_check import PilotCheckValve
from .pressure_reducing import PressureReducingValve
from .pressure_source import PressureSource
from .pumps import PumpCompensated, PumpFixed
from .relief import ReliefValve
from .tank import Tank
from .throttle_check import ThrottleCheckValve
from .valve_4_3 import Valve43
from .volume import Volume

COMPONENT_TYPES = {
    "tank": Tank,
    "pump_fixed": PumpFixed,
    "pump_compensated": PumpCompensated,
    "orifice": Orifice,
    "valve_4_3": Valve43,
    "relief_valve": ReliefValve,
    "check_valve": CheckValve,
    "volume": Volume,
    "hose": Hose,
    "cylinder": Cylinder,
    "motor": Motor,
    "accumulator": Accumulator,
    "pilot_check_valve": PilotCheckValve,
    "throttle_check_valve": ThrottleCheckValve,
    "counterbalance_valve": CounterbalanceValve,
    "pressure_reducing_valve": PressureReducingValve,
    "flow_control_valve": FlowControlValve,
    "pressure_source": PressureSource,
}
"""Circuit-file ``type`` name → parameter class."""

BRANCH_LAWS = tuple(cls for cls in COMPONENT_TYPES.values() if hasattr(cls, "BRANCH_LAW"))
"""The component classes that bring their own branch law, in registry order (their law number in the network).

Such a class declares ``PORTS`` (two or three: the flow runs from the first to the second port; a third is a
pilot terminal whose pressure the law reads), ``LAW_COLUMNS`` (the names of its parameter row),
``law_row(fluid)`` (that row) and ``BRANCH_LAW``, a compiled function
``law(row, p_from, p_to, p_pilot) -> (Q, ∂Q/∂p_from, ∂Q/∂p_to, ∂Q/∂p_pilot)`` [m³/s, m³/(s·Pa)].
Adding such a component takes its module and one line in :data:`COMPONENT_TYPES`."""
LAW_WIDTH = max([len(cls.LAW_COLUMNS) for cls in BRANCH_LAWS], default=1)
"""Floats per row of the network's law-branch table (the widest law's row)."""


def build_component(kind: str, table: dict, where: str):
    """Build and validate a component of type ``kind`` from a circuit-file table.

    ``where`` prefixes every error (e.g. ``"circuit.toml: component 'pump'"``).
    Keys ``name``, ``type`` and ``ports`` are handled by the caller.  A class with a ``check(where)`` method
    validates relations between its fields there.
    """
    cls = COMPONENT_TYPES[kind]
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise CircuitError(f"{where}: unknown field(s) {unknown} for type '{kind}'; allowed: {sorted(known)}")
    values = {}
    for name, f in known.items():
        meta = f.metadata
        if name not in table:
            if f.default is MISSING:
                raise CircuitError(f"{where}: missing field '{name}' ({describe_range(meta)})")
            continue
        value = table[name]
        if meta["choices"]:
            if value not in meta["choices"]:
                raise CircuitError(f"{where}, field '{name}': {value!r} is not {describe_range(meta)}")
            values[name] = value
        else:
            values[name] = check_number(value, meta, f"{where}, field '{name}'")
    component = cls(**values)
    check = getattr(component, "check", None)
    if check is not None:
        check(where)
    return component


__all__ = ["BRANCH_LAWS", "COMPONENT_TYPES", "LAW_WIDTH", "CircuitError", "build_component", "check_number", "describe_range", "param",
           "Accumulator", "CheckValve", "CounterbalanceValve", "Cylinder", "FlowControlValve", "Hose", "Motor", "Orifice",
           "PilotCheckValve", "PressureReducingValve", "PumpCompensated", "PumpFixed", "ReliefValve", "Tank",
           "ThrottleCheckValve", "Valve43", "Volume"]
