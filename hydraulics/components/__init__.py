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
from .pressure_compensator import PressureCompensator
from .post_compensator import PostCompensator
from .counterbalance import CounterbalanceValve
from .cylinder import Cylinder
from .flow_control import FlowControlValve
from .hose import Hose, LaminarResistance
from .metering import check_table
from .motor import Motor
from .orifice import Orifice
from .parameters import CircuitError, check_number, describe_range, param
from .pilot_check import PilotCheckValve
from .pressure_reducing import PressureReducingValve
from .pressure_source import PressureSource
from .pump_load_sensing import PumpLoadSensing
from .pumps import PumpCompensated, PumpFixed
from .relief import ReliefValve
from .relief_poppet import ReliefPoppet
from .tank import Tank
from .throttle_check import ThrottleCheckValve
from .valve_4_3 import Valve43
from .variable_orifice import VariableOrifice
from .volume import Volume

COMPONENT_TYPES = {
    "tank": Tank,
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
    "relief_valve_poppet": ReliefPoppet,
    "pump_load_sensing": PumpLoadSensing,
    "pressure_compensator": PressureCompensator,
    "post_compensator": PostCompensator,
    "variable_orifice": VariableOrifice,
    "pump_fixed": PumpFixed,
    "pump_compensated": PumpCompensated,
}
"""Circuit-file ``type`` name → parameter class (the law components' branches follow this order in the network:
the fixed-displacement and compensated pumps last, after every other law but those driven by their actuator,
:data:`BRANCH_LAWS`)."""
VALVE_KINDS = tuple(kind for kind, cls in COMPONENT_TYPES.items() if hasattr(cls, "METERING_EDGES"))
"""The types whose passages a commanded spool meters (``METERING_EDGES``, ``edges(ports)``, ``COMMAND_RANGE``):
the network's valves, commanded by name (:attr:`hydraulics.network.NetworkModel.valve_names`)."""


def law_actuated(cls) -> bool:
    """Whether the law of component class ``cls`` is driven by its own actuator's velocity (``ACTUATOR_INPUT``)."""
    return bool(getattr(cls, "ACTUATOR_INPUT", False))


BRANCH_LAWS = ((LaminarResistance,)
               + tuple(cls for cls in COMPONENT_TYPES.values() if hasattr(cls, "BRANCH_LAW") and not law_actuated(cls))
               + tuple(cls for cls in COMPONENT_TYPES.values() if hasattr(cls, "BRANCH_LAW") and law_actuated(cls)))
"""The component classes that bring their own branch law (their law number in the network is their place here):
:class:`LaminarResistance` (the branches the network makes for hose lines and actuator leakage, no circuit-file
type), then the registry's, in registry order, those driven by their actuator (``ACTUATOR_INPUT``) last.

Such a class declares

* ``PORTS``: two or more port names; the flow runs from the first to the second port, a third is a pilot
  terminal whose pressure the law reads;
* ``LAW_COLUMNS`` (the names of its parameter row) and ``law_row(fluid)`` (that row);
* ``BRANCH_LAW``, a compiled function ``law(row, p_from, p_to, p_pilot) -> (Q, ∂Q/∂p_from, ∂Q/∂p_to, ∂Q/∂p_pilot)``
  [m³/s, m³/(s·Pa)] at absolute port pressures [Pa];

and, for a component with states of its own (a poppet's lift and speed, …), also

* ``STATES``: their names, ``STATE_UNITS`` their units and ``state_start()`` their values at rest;
* ``BRANCH_LAW`` then takes ``(row, state, h, p_from, p_to, p_pilot)``: ``state`` holds the states at the start
  of a step of ``h`` [s], and the law returns the flow through the component *at the end of the step*, with its
  states advanced over the step by the component's own (implicit or exact) update driven by the end pressures,
  and the total pressure derivatives of that flow;
* ``STATE_END``, a compiled function ``end(row, state, h, p_from, p_to, p_pilot, out)`` writing those end states
  into ``out`` (called once the step's end pressures are known).

A law with kinks (a poppet reaching its seat or stop, a regulator saturating) may declare its kink hook
``LAW_PIECE``, a compiled function ``piece(row, state, h, p_from, p_to, p_pilot) -> int`` numbering the pieces of
its law: a step whose start and end pressures are on different pieces is not accepted from one linearisation
(:meth:`hydraulics.network.NetworkModel.law_pieces`).

A law component that delivers power (a pump) sets ``SOURCE = True``: its flow's power enters the energy ledger
as pump work instead of dissipation.

A law driven by scheduled inputs (a pump's shaft speed) declares

* ``INPUTS``: their names, ``INPUT_UNITS`` their units and ``input_start()`` their values when nothing schedules
  them (e.g. the ``speed`` field);
* ``BRANCH_LAW`` then takes the inputs' values as one more, last argument ``inputs`` (an array, in the order of
  ``INPUTS``): ``law(row, p_from, p_to, p_pilot, inputs)``, or ``law(row, state, h, p_from, p_to, p_pilot, inputs)``
  with states.  The values are those held over the step.  ``STATE_END`` and ``LAW_PIECE`` take no inputs: a law's
  own states and its pieces may not depend on them (a pump's regulator reads pressures, not the shaft speed).

An actuator whose flow its own motion displaces (a motor's shaft swallowing D·ω/(2π)) sets
``ACTUATOR_INPUT = True``:

* ``BRANCH_LAW`` then takes its actuator's velocity [m/s | rad/s] as its one input, ``law(row, p_from, p_to,
  p_pilot, inputs)`` with ``inputs[0]`` the velocity held over the step (no scheduled ``INPUTS``, no states);
* ``VELOCITY_RATE``, a compiled function ``rate(row) -> ∂Q/∂v`` [m² | m³/rad], gives the flow's velocity
  derivative (the law is linear in the velocity), which the couplings' velocity Jacobians read;
* its flow's power Q·(μ_from − μ_to) is work delivered to the actuator (the ledger's motor work), not
  dissipation.

The network schedules ``INPUTS`` by the component's name (by ``component.input`` for a component with several
inputs): they are entries of the network's control vector of pump speeds (:attr:`hydraulics.network.NetworkModel.pump_names`,
``NetworkControl.pump_speed``), which scenarios, controllers and logs address by name.

The network numbers the states of all components in one vector (the valves' spools first, then each stateful
component's states in circuit order: :attr:`hydraulics.network.NetworkModel.component_state_names`); the kernels, the
packing and the logs follow from these declarations, so adding such a component takes its module and one line
in :data:`COMPONENT_TYPES`."""
LAW_WIDTH = max([len(cls.LAW_COLUMNS) for cls in BRANCH_LAWS], default=1)
"""Floats per row of the network's law-branch table (the widest law's row)."""


def law_sources() -> tuple:
    """1 for each law of :data:`BRANCH_LAWS` that is a power source (``SOURCE``), else 0, in law order."""
    return tuple(int(bool(getattr(cls, "SOURCE", False))) for cls in BRANCH_LAWS)


def law_states(cls) -> tuple:
    """Names of the states of a component class (empty for a stateless one)."""
    return tuple(getattr(cls, "STATES", ()))


def law_inputs(cls) -> tuple:
    """Names of the scheduled inputs of a component class (empty for a law without inputs)."""
    return tuple(getattr(cls, "INPUTS", ()))


def input_names(name: str, cls) -> tuple:
    """The names a scenario schedules the inputs of component ``name`` of class ``cls`` by: the component's name
    for its one input, ``name.input`` for each of several."""
    own = law_inputs(cls)
    return (name,) if len(own) == 1 else tuple(f"{name}.{i}" for i in own)


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
        if meta.get("tables"):
            if not isinstance(value, dict):
                raise CircuitError(f"{where}, field '{name}': expected {describe_range(meta)}, got {value!r}")
            values[name] = tuple((str(key), tuple(zip(*check_table(knots, f"{where}, field '{name}', table '{key}'"))))
                                 for key, knots in value.items())
        elif meta["choices"]:
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


__all__ = ["BRANCH_LAWS", "COMPONENT_TYPES", "LAW_WIDTH", "VALVE_KINDS", "CircuitError", "build_component", "input_names", "law_actuated", "law_inputs", "law_sources", "law_states", "check_number", "describe_range", "param",
           "Accumulator", "CheckValve", "CounterbalanceValve", "Cylinder", "FlowControlValve", "Hose", "LaminarResistance",
           "Motor", "Orifice", "PilotCheckValve", "PostCompensator", "PressureCompensator", "PressureReducingValve",
           "PumpCompensated", "PumpLoadSensing", "PumpFixed", "ReliefPoppet", "ReliefValve", "Tank",
           "ThrottleCheckValve", "Valve43", "VariableOrifice", "Volume"]
