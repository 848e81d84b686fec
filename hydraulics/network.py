"""Network assembly: nodes (volumes with pressure states) and branches (flow laws).

A :class:`NetworkModel` is built once from a :class:`~hydraulics.circuit.Circuit`
and is immutable; :class:`NetworkState` and :class:`NetworkControl` are made by
the model so their sizes always match it (Newton's Model / State / Control
split).

Nodes
    Every net of the circuit is a node.  Tank nets are *fixed* nodes (known
    pressure); every other node holds an oil content m [m³ at the reference
    density] and a volume V(x, p) = V_fixed + Σ chamber volumes(x) + wall
    expansion(p) + accumulator liquid(p).  Its absolute pressure solves
    m = V(x, p)·φ(p) (see :mod:`hydraulics.fluid`), floored at the cavitation
    pressure (a node with too little oil holds a vapour void at that pressure).
    At ``compressible`` fidelity the two ends of a hose are one node holding
    the hose volume.

Branches
    Flow laws Q [m³/s at reference density] from a ``from`` to a ``to`` node, each
    with analytic derivatives with respect to the pressure of each of its terminals:
    valve edges (orifices whose area the spool sets), rigid branches (the flow a rigid
    actuator's rod displaces, set by its speed and its valve's direction; see ``FIDELITIES``)
    and *law branches*: the components that bring their own law
    (:data:`hydraulics.components.BRANCH_LAWS`: laminar resistances of hose lines and
    actuator leaks, fixed orifices, relief and check valves, counterbalance valves, pumps,
    motors, …), which may read a third, pilot terminal (``branch_pilot``), scheduled inputs
    (a pump's shaft speed: ``pump_names``) or their own actuator's velocity (a motor's flow
    set by its shaft speed).  The law branches are grouped by law, in the order of
    ``BRANCH_LAWS``, each law's in circuit order (:meth:`NetworkModel.law_branches`).

Actuators
    Cylinders (coordinate: rod extension x [m], effort: force [N]) and motors
    (coordinate: shaft angle [rad], effort: torque [N·m]), in circuit order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .circuit import Circuit
from .components import (BRANCH_LAWS, COMPONENT_TYPES, LAW_WIDTH, VALVE_KINDS, CircuitError, PumpFixed, input_names,
                         law_actuated, law_inputs, law_sources, law_states)
from .components.metering import characteristics as metering_characteristics
from .components.hose import LaminarResistance, line_conductance
from .numerics import PRESSURE_INVERSION_MAX_ITERATIONS, PRESSURE_INVERSION_TOLERANCE  # noqa: F401 (documented here)


ACTUATOR_CYLINDER = 0
ACTUATOR_MOTOR = 1

FIDELITIES = ("incompressible", "compressible", "lines")
"""``incompressible``: no pressure states; actuators follow their metered flow up to the relief force
(see :class:`hydraulics.coupling.CouplingIncompressible`).
``compressible``: chamber pressure states, each hose lumped into the net its ends join.
``lines``: each hose is a π-line — half its volume at each end net, a laminar
(Hagen–Poiseuille) resistance between them — for pressure-wave and valve-slam studies.

Levels may differ per actuator (``actuator_fidelity`` of :meth:`NetworkModel.from_circuit`):
``compressible`` and ``lines`` mix freely (see :func:`line_hoses`).  ``incompressible`` for every
actuator leaves no pressure states at all; for some actuators only, those become *rigid*
actuators of a compressible network (see :func:`rigid_actuator_nets`): their chamber nets are
not pressure states, and a rigid branch from their valve's P net to its T net carries the flow
their rods displace, so the supply they share with the compressible actuators stays exact."""


def _vector(values, size):
    """``values`` as a C-contiguous, writeable float64 array of ``size`` entries (the one type the kernels take)."""
    a = np.ascontiguousarray(values, dtype=np.float64).reshape(size)
    return a if a.flags.writeable else a.copy()


def _rows(values, width):
    """``values`` of shape (..., width) as a C-contiguous float64 array of rows (one sample each) and its leading shape."""
    a = np.asarray(values, dtype=np.float64)
    lead = a.shape[:-1] if a.ndim else ()
    rows = np.ascontiguousarray(a).reshape(math.prod(lead), width)  # (not -1: width may be 0)
    return (rows if rows.flags.writeable else rows.copy()), lead


def _broadcast_rows(*arrays):
    """The (values, width) pairs ``arrays`` broadcast over their leading axes, each as rows (:func:`_rows`), and the
    common leading shape."""
    values = [np.asarray(a, dtype=np.float64) for a, _ in arrays]
    rows = []
    for v, (_, w) in zip(values, arrays):  # one sample each (a per-step plant's call): nothing to broadcast
        if v.ndim != 1:
            break
        rows.append(_rows(v, w)[0])
    else:
        return tuple(rows), ()
    lead = np.broadcast_shapes(*(v.shape[:-1] for v in values))
    return tuple(_rows(v if v.shape[:-1] == lead else np.broadcast_to(v, lead + (w,)), w)[0]
                 for v, (_, w) in zip(values, arrays)), lead


class _UnionFind:
    def __init__(self):
        self.parent = {}

    def find(self, a):
        self.parent.setdefault(a, a)
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def union(self, a, b):
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[max(ra, rb)] = min(ra, rb)


def _fixed(component) -> bool:
    """Whether a component makes its one net a fixed node: its parameters have ``fixed_pressure(fluid)`` [Pa]."""
    return hasattr(component.params, "fixed_pressure")


def fixed_pressure_components(circuit: Circuit) -> list:
    """The components that hold their net at a fixed pressure (tanks, pressure sources), in circuit order."""
    return [c for c in circuit.components if _fixed(c)]


def prune(circuit: Circuit, drives=None):
    """Drop components that no cylinder or motor reaches through shared nets (tank nets do not connect); a circuit
    without any cylinder or motor (a test rig) is kept whole.

    ``drives`` (names of the actuators the scene has, e.g. the MJCF's) also drops
    every cylinder or motor not among them and the branches that fed only those:
    for each net n, the parts the circuit falls into without n that hold a dropped
    actuator and no kept one (a valve section with its hoses and port reliefs
    hanging off the supply net) are dropped whole.
    Returns the reduced circuit and the names of the dropped components.
    """
    tank_nets = {c.ports["port"] for c in fixed_pressure_components(circuit)}
    if drives is not None:
        circuit, dropped = _prune_undriven(circuit, set(drives), tank_nets)
        circuit, rest = prune(circuit)
        return circuit, dropped + rest
    by_net = {}
    for c in circuit.components:
        for net in c.ports.values():
            by_net.setdefault(net, []).append(c)
    reached = {c.name for c in circuit.by_kind("cylinder", "motor")}
    if not reached:  # no actuator at all: a test rig (a pump and valves on volumes), kept whole
        return circuit, ()
    frontier = [c for c in circuit.components if c.name in reached]
    while frontier:
        c = frontier.pop()
        for net in c.ports.values():
            if net in tank_nets:
                continue
            for other in by_net[net]:
                if other.name not in reached:
                    reached.add(other.name)
                    frontier.append(other)
    keep_tanks = {net for c in circuit.components if c.name in reached for net in c.ports.values()}
    kept = tuple(c for c in circuit.components if c.name in reached or (_fixed(c) and c.ports["port"] in keep_tanks))
    pruned = tuple(c.name for c in circuit.components if c not in kept)
    if not pruned:
        return circuit, ()
    return Circuit(circuit.fluid, kept, circuit.source), pruned


def _prune_undriven(circuit: Circuit, drives: set, tank_nets: set):
    """``circuit`` without the actuators not in ``drives`` and the parts that only feed them (see :func:`prune`)."""
    actuators = {c.name for c in circuit.by_kind("cylinder", "motor")}
    gone = actuators - drives
    if not gone:
        return circuit, ()
    nets = {net for c in circuit.components for net in c.ports.values() if net not in tank_nets}
    drop = set(gone)
    for cut in nets:
        uf = _UnionFind()
        index = {c.name: i for i, c in enumerate(circuit.components)}
        by_net = {}
        for c in circuit.components:
            for net in c.ports.values():
                if net != cut and net not in tank_nets:
                    by_net.setdefault(net, []).append(index[c.name])
        for members in by_net.values():
            for other in members[1:]:
                uf.union(members[0], other)
        parts = {}
        for c in circuit.components:
            if not _fixed(c):
                parts.setdefault(uf.find(index[c.name]), []).append(c.name)
        for names in parts.values():
            if set(names) & gone and not set(names) & (actuators - gone):
                drop.update(names)
    kept = tuple(c for c in circuit.components if c.name not in drop)
    return Circuit(circuit.fluid, kept, circuit.source), tuple(c.name for c in circuit.components if c.name in drop)


def resolve_fidelity(circuit: Circuit, fidelity: str, actuator_fidelity=None) -> tuple:
    """Per-actuator fidelity levels (cylinders and motors in circuit order) and the network's level.

    ``fidelity`` is the default (the scene's level), ``actuator_fidelity`` maps actuator
    names to overriding levels.  Returns ``(levels, network_level)`` where the network's
    level is ``incompressible`` when every actuator is, ``lines`` when any is ``lines``
    (some hoses are lines), else ``compressible`` (``incompressible`` actuators among
    others are rigid actuators of that network).  Raises :class:`CircuitError` for an
    unknown level or name.
    """
    if fidelity not in FIDELITIES:
        raise CircuitError(f"{circuit.source}: fidelity {fidelity!r} is not one of {list(FIDELITIES)}")
    overrides = dict(actuator_fidelity or {})
    names = [c.name for c in circuit.by_kind("cylinder", "motor")]
    for name, level in overrides.items():
        if name not in names:
            raise CircuitError(f"{circuit.source}: fidelity for '{name}': no cylinder or motor of that name; actuators: {names}")
        if level not in FIDELITIES:
            raise CircuitError(f"{circuit.source}: fidelity for '{name}': {level!r} is not one of {list(FIDELITIES)}")
    levels = tuple(overrides.get(name, fidelity) for name in names)
    if levels and set(levels) == {"incompressible"}:
        return levels, "incompressible"
    if not levels:
        return levels, fidelity
    return levels, "lines" if "lines" in levels else "compressible"


def line_hoses(circuit: Circuit, fidelity: str, actuator_fidelity=None) -> frozenset:
    """Names of the hoses modelled as π-lines.

    A hose belongs to the actuators whose chamber (or motor port) net it joins once all
    hoses are lumped, i.e. the work-port hoses between a valve and a cylinder.  It is a
    line when one of its actuators is at ``lines`` (the higher level wins for a shared
    hose); a hose of no actuator (e.g. a supply hose) follows the default ``fidelity``.
    """
    hoses = circuit.by_kind("hose")
    if not actuator_fidelity:
        return frozenset(c.name for c in hoses) if fidelity == "lines" else frozenset()
    levels, _ = resolve_fidelity(circuit, fidelity, actuator_fidelity)
    uf = _UnionFind()
    for c in hoses:
        uf.union(c.ports["a"], c.ports["b"])
    owner_level = {}
    for c, level in zip(circuit.by_kind("cylinder", "motor"), levels):
        for net in c.ports.values():
            root = uf.find(net)
            owner_level[root] = "lines" if "lines" in (level, owner_level.get(root)) else level
    return frozenset(c.name for c in hoses if owner_level.get(uf.find(c.ports["a"]), fidelity) == "lines")


@dataclass
class NetworkState:
    """Time-varying state of a network (made by :meth:`NetworkModel.state`).

    Attributes
    ----------
    node_oil : ndarray, shape (node_count,)
        Oil content of each node [m³ at reference density]; NaN for fixed nodes.
    node_pressure : ndarray, shape (node_count,)
        Absolute pressure of each node [Pa], consistent with ``node_oil`` and
        ``actuator_position``.
    valve_spool : ndarray, shape (valve_count,)
        Spool position of each 4/3 valve [-], in [−1, 1].
    actuator_position : ndarray, shape (actuator_count,)
        Cylinder extension [m] or motor shaft angle [rad] the pressures refer to.
    actuator_velocity : ndarray, shape (actuator_count,)
        Cylinder rod speed [m/s] or motor shaft speed [rad/s].
    time : float
        Simulation time [s].
    node_oil_change : ndarray, shape (node_count,), or None
        Oil change of the step that ended in this state [m³ at reference density];
        NaN for fixed nodes (None: unknown, e.g. an initial state).  A warm start, like MuJoCo's
        ``qacc_warmstart``: the implicit couplings start the next step's Newton
        solve at the secant prediction ``node_oil + node_oil_change``
        (:func:`hydraulics.coupling.secant_oil_guess`), which changes the
        iterations only, not the equations or the tolerance.
    """

    node_oil: np.ndarray
    node_pressure: np.ndarray
    valve_spool: np.ndarray
    actuator_position: np.ndarray
    actuator_velocity: np.ndarray
    time: float = 0.0
    node_oil_change: np.ndarray | None = None

    def copy(self) -> "NetworkState":
        """Deep copy."""
        return NetworkState(
            self.node_oil.copy(),
            self.node_pressure.copy(),
            self.valve_spool.copy(),
            self.actuator_position.copy(),
            self.actuator_velocity.copy(),
            self.time,
            None if self.node_oil_change is None else self.node_oil_change.copy(),
        )

    def flat_oil_change(self):
        """``node_oil_change`` [m³] as the compiled steps keep it: zeros where none is known (a zero change starts
        the next Newton solve from the start oil, as None does)."""
        return 0.0 if self.node_oil_change is None else self.node_oil_change


@dataclass
class NetworkControl:
    """Operator inputs: spool commands [-] in [−1, 1] and pump speeds [rev/s]."""

    valve_command: np.ndarray
    pump_speed: np.ndarray


@dataclass(frozen=True)
class BranchFlows:
    """Flows of every branch and their derivatives, for one pressure vector.

    flow : shape (branch_count,) [m³/s], positive from ``branch_from`` to ``branch_to``.
    dflow_dfrom, dflow_dto : shape (branch_count,) [m³/(s·Pa)], derivatives with
    respect to the pressures of the two terminal nodes.
    dflow_dpilot : shape (branch_count,) [m³/(s·Pa)] or None (no pilot terminals), derivative with
    respect to the pressure of the third terminal ``branch_pilot`` (zero where there is none).
    """

    flow: np.ndarray
    dflow_dfrom: np.ndarray
    dflow_dto: np.ndarray
    dflow_dpilot: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class NetworkModel:
    """Static definition of a hydraulic network (built by :meth:`from_circuit`)."""

    circuit: Circuit
    node_names: tuple
    node_fixed: np.ndarray  # bool (node_count,)
    node_fixed_pressure: np.ndarray  # Pa, NaN for free nodes
    node_volume: np.ndarray  # m³, rigid volume at reference pressure
    node_wall_compliance: np.ndarray  # m³/Pa
    net_node: dict  # circuit net name -> node index
    # accumulators
    accumulator_node: np.ndarray
    accumulator_gas_volume: np.ndarray
    accumulator_precharge: np.ndarray
    accumulator_index: np.ndarray
    # actuators
    actuator_names: tuple
    actuator_kind: np.ndarray
    cylinder_actuator: np.ndarray  # actuator index of each cylinder
    cylinder_cap_node: np.ndarray
    cylinder_rod_node: np.ndarray
    cylinder_cap_area: np.ndarray
    cylinder_rod_area: np.ndarray
    cylinder_stroke: np.ndarray
    cylinder_dead_cap: np.ndarray
    cylinder_dead_rod: np.ndarray
    cylinder_coulomb: np.ndarray
    cylinder_static: np.ndarray
    cylinder_stribeck: np.ndarray
    cylinder_viscous: np.ndarray
    cylinder_pressure_friction: np.ndarray  # -, k_p of the seal friction's pressure dependence
    cylinder_cushion_length_cap: np.ndarray  # m, 0: no cushion
    cylinder_cushion_length_rod: np.ndarray  # m
    cylinder_cushion_area_cap: np.ndarray  # m², cushion orifice
    cylinder_cushion_area_rod: np.ndarray  # m²
    cylinder_cushion_cd: np.ndarray  # -
    cylinder_cushion_check: np.ndarray  # 1.0: a check valve frees the return from the cushion, 0.0: none
    motor_actuator: np.ndarray
    motor_a_node: np.ndarray
    motor_b_node: np.ndarray
    motor_displacement: np.ndarray
    # valves and pumps (controls)
    valve_names: tuple
    valve_time_constant: np.ndarray
    valve_overlap: np.ndarray
    pump_names: tuple  # the law components' scheduled inputs (their INPUTS: pump shaft speeds), in circuit order
    pump_nominal_speed: np.ndarray  # their values when nothing schedules them [rev/s]
    # branches, concatenated by kind; `branch_slices[kind]` gives each kind's range
    branch_names: tuple
    branch_from: np.ndarray
    branch_to: np.ndarray
    branch_slices: dict
    orifice_cd: np.ndarray
    orifice_base_area: np.ndarray
    orifice_max_area: np.ndarray
    orifice_centre_area: np.ndarray
    orifice_valve: np.ndarray  # valve index or -1
    orifice_sign: np.ndarray  # +1 opens with s > 0, -1 with s < 0, 0 no metering
    fidelity: str = "compressible"
    pruned: tuple = ()  # names of the circuit components that were not built
    incidence: np.ndarray = field(default=None, repr=False)  # (node_count, branch_count)
    actuator_fidelity: tuple = ()  # fidelity level of every actuator (cylinders and motors, circuit order)
    hose_lines: tuple = ()  # names of the hoses built as π-lines (own end nodes + laminar resistance)
    # rigid actuators: ``incompressible`` ones in a compressible network (their chamber nodes are fixed nodes
    # whose logged pressures the coupling derives from the effort); one rigid branch per metered one
    actuator_rigid: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # bool (actuator_count,)
    rigid_branch_actuator: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    rigid_valve: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # valve index of each rigid branch
    rigid_sign: np.ndarray = field(default_factory=lambda: np.zeros(0))  # +1: spool > 0 feeds the cap (port a)
    rigid_extend_area: np.ndarray = field(default_factory=lambda: np.zeros(0))  # m² (m³/rad): cap area, D/2π
    rigid_retract_area: np.ndarray = field(default_factory=lambda: np.zeros(0))  # m² (m³/rad): rod area, D/2π
    rigid_cd: np.ndarray = field(default_factory=lambda: np.zeros(0))  # discharge coefficient of the metering edges
    rigid_base_area: np.ndarray = field(default_factory=lambda: np.zeros(0))  # m², leakage area of a closed edge
    rigid_max_area: np.ndarray = field(default_factory=lambda: np.zeros(0))  # m², fully open edge
    # law branches (components with their own law, hydraulics.components.BRANCH_LAWS): third terminal of every
    # branch (-1: none), law of each law branch (index into BRANCH_LAWS) and its parameter row
    branch_pilot: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    law_kind: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    law_table: np.ndarray = field(default_factory=lambda: np.zeros((0, LAW_WIDTH)))
    # component states: the valves' spools, then the states of every stateful law component (its STATES, in
    # circuit order); the first state of each law branch in that vector (-1: a stateless law)
    law_state_offset: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    # scheduled inputs of the law components (their INPUTS: a pump's shaft speed), the entries of the control vector
    # ``NetworkControl.pump_speed`` (names ``pump_names``): the first input of each law branch there (-1: none); for a
    # law driven by its actuator (ACTUATOR_INPUT: a motor's flow), its actuator's index into the velocities
    law_input_offset: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    # second-order spools: each valve's spool rate in that vector (after the law components' states; -1: a
    # first-order spool), natural frequency [rad/s] and damping ratio [-]
    valve_rate_offset: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    valve_omega: np.ndarray = field(default_factory=lambda: np.zeros(0))
    valve_zeta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    component_state_names: tuple = ()  # "valve" for a spool, "component.state" for a law component's state
    component_state_units: tuple = ()
    component_state_start: np.ndarray = field(default_factory=lambda: np.zeros(0))  # values at rest
    valve_command_low: np.ndarray = field(default_factory=lambda: np.zeros(0))  # lowest command of each valve [-]
    # metering characteristic of every orifice branch (hydraulics.components.metering.COLUMNS: exponent, first
    # knot, knot count) and the knot table of the tabulated edges (metering.KNOT_COLUMNS)
    orifice_metering: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    metering_knots: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    # ------------------------------------------------------------------ build
    @classmethod
    def from_circuit(cls, circuit: Circuit, *, fidelity: str = "compressible", actuator_fidelity=None) -> "NetworkModel":
        """Assemble the network of ``circuit`` at the given fidelity.

        ``fidelity`` is the default level; ``actuator_fidelity`` ({actuator name: level})
        overrides it per cylinder or motor (:func:`resolve_fidelity`, :func:`line_hoses`):
        the hoses of a ``lines`` actuator become π-lines while the others stay lumped.
        ``fidelity`` of the model is then the network's level (``lines`` when any hose is
        a line); ``actuator_fidelity`` and ``hose_lines`` record the details.

        Components that no cylinder or motor can reach (tanks do not connect)
        are pruned: not built and not stepped; ``pruned`` names them.
        """
        if fidelity not in FIDELITIES:
            raise CircuitError(f"{circuit.source}: fidelity {fidelity!r} is not one of {FIDELITIES}")
        circuit, pruned = prune(circuit)
        levels, network_fidelity = resolve_fidelity(circuit, fidelity, actuator_fidelity)
        for c, level in zip(circuit.by_kind("cylinder", "motor"), levels):
            if level != "incompressible" or c.kind != "cylinder":
                continue
            for name in ("friction_pressure_coefficient", "cushion_length_cap", "cushion_length_rod"):
                if getattr(c.params, name) > 0.0:
                    raise CircuitError(f"{circuit.source}: component '{c.name}', field '{name}': must be 0 at fidelity "
                                       "'incompressible' (its rigid oil law has no seal load or cushion); use 'compressible'")
        line_set = line_hoses(circuit, fidelity, actuator_fidelity)
        if line_set and network_fidelity == "compressible":
            network_fidelity = "lines"  # a hose of no actuator follows the default level
        uf = _UnionFind()
        for c in circuit.components:
            for net in c.ports.values():
                uf.find(net)
        for c in circuit.by_kind("hose"):
            if c.name not in line_set:
                uf.union(c.ports["a"], c.ports["b"])
        roots = []
        for c in circuit.components:
            for net in c.ports.values():
                r = uf.find(net)
                if r not in roots:
                    roots.append(r)
        node_of = {r: i for i, r in enumerate(roots)}
        net_node = {net: node_of[uf.find(net)] for net in uf.parent}
        n = len(roots)
        names = [r for r in roots]
        fixed = np.zeros(n, bool)
        fixed_p = np.full(n, np.nan)
        volume = np.zeros(n)
        wall = np.zeros(n)
        has_chamber = np.zeros(n, bool)
        ref = circuit.fluid.reference_pressure

        def node(c, port):
            return net_node[c.ports[port]]

        for c in fixed_pressure_components(circuit):
            k, pressure = node(c, "port"), c.params.fixed_pressure(circuit.fluid)
            if fixed[k] and fixed_p[k] != pressure:
                raise CircuitError(f"{circuit.source}: component '{c.name}': net '{c.ports['port']}' joins two tanks or "
                                   "pressure sources at different pressures")
            fixed[k], fixed_p[k] = True, pressure
        # rigid actuators (incompressible among compressible ones): their chamber nets hold no pressure state
        rigid_node = {}  # node -> name of the rigid actuator whose chamber (or motor port) it is
        if network_fidelity != "incompressible":
            owner = {}  # node -> actuators with a port on it
            for c in circuit.by_kind("cylinder", "motor"):
                for port in c.ports:
                    owner.setdefault(node(c, port), []).append(c.name)
            for c, level in zip(circuit.by_kind("cylinder", "motor"), levels):
                if level != "incompressible":
                    continue
                for port, net in c.ports.items():
                    k = node(c, port)
                    if fixed[k]:
                        raise CircuitError(f"{circuit.source}: actuator '{c.name}' at fidelity 'incompressible': its port '{port}' "
                                           f"is on the tank net '{net}'; only actuators whose ports have their own nets can be rigid")
                    if len(owner[k]) > 1:
                        raise CircuitError(f"{circuit.source}: actuator '{c.name}' at fidelity 'incompressible': its net '{net}' is shared "
                                           f"with {[a for a in owner[k] if a != c.name]}; give actuators that share oil the same fidelity")
                    rigid_node[k] = c.name
                    fixed[k], fixed_p[k] = True, ref

        def keep(c, a, b):
            """Whether the branch of component ``c`` between nodes a and b is built: not when it lives on rigid
            chamber nets (and tanks) only; an error when it joins a rigid chamber net to a pressure state."""
            if a not in rigid_node and b not in rigid_node:
                return True
            if fixed[a] and fixed[b]:
                return False
            inner, outer = (a, b) if a in rigid_node else (b, a)
            raise CircuitError(
                f"{circuit.source}: component '{c.name}' joins net '{names[inner]}' of actuator '{rigid_node[inner]}' "
                f"(fidelity 'incompressible', no pressure state) to net '{names[outer]}', which has one; "
                f"give '{rigid_node[inner]}' the fidelity 'compressible' or 'lines'"
            )
        for c in circuit.by_kind("volume", "hose"):
            # a lumped hose puts its volume on its (merged) net; a line puts half at each end
            ends = ("port",) if c.kind == "volume" else (("a", "b") if c.name in line_set else ("a",))
            for end in ends:
                k = node(c, end)
                volume[k] += c.params.volume / len(ends)
                if math.isfinite(c.params.wall_bulk_modulus):
                    wall[k] += c.params.volume / len(ends) / c.params.wall_bulk_modulus

        acc = circuit.by_kind("accumulator")
        acc_node = np.array([node(c, "port") for c in acc], int)

        actuators = circuit.by_kind("cylinder", "motor")
        act_names = tuple(c.name for c in actuators)
        act_kind = np.array([ACTUATOR_CYLINDER if c.kind == "cylinder" else ACTUATOR_MOTOR for c in actuators], int)
        cyl = [c for c in actuators if c.kind == "cylinder"]
        mot = [c for c in actuators if c.kind == "motor"]
        for c in cyl:
            has_chamber[node(c, "cap")] = True
            has_chamber[node(c, "rod")] = True

        branch_names, b_from, b_to = [], [], []
        slices = {}

        def add_branch(name, a, b):
            branch_names.append(name)
            b_from.append(a)
            b_to.append(b)

        # orifice-law branches: the valves' passages (their kinds declare them: VALVE_KINDS, edges())
        start = len(branch_names)
        o_cd, o_base, o_max, o_centre, o_valve, o_sign, o_edge = [], [], [], [], [], [], []

        def add_orifice(name, a, b, cd, base, maxa=0.0, centre=0.0, valve=-1, sign=0, edge=(None, None)):
            add_branch(name, a, b)
            o_cd.append(cd)
            o_base.append(base)
            o_max.append(maxa)
            o_centre.append(centre)
            o_valve.append(valve)
            o_sign.append(sign)
            o_edge.append(edge)

        valves = circuit.by_kind(*VALVE_KINDS)
        for c in valves if network_fidelity == "incompressible" else ():
            if c.kind != "valve_4_3" or c.params.metering != "linear":
                what = f"field 'metering': {c.params.metering!r}" if c.kind == "valve_4_3" else f"type '{c.kind}'"
                raise CircuitError(
                    f"{circuit.source}: component '{c.name}', {what} at fidelity 'incompressible' (its rigid oil law "
                    "meters through linear 4/3 valves only); use a linear valve_4_3 or the fidelity 'compressible'")
        rigid_valve = {}  # rigid actuator name -> (valve index, +1 if port A feeds its cap / motor port a, else -1)
        for vi, c in enumerate(valves):
            p = c.params
            if any(node(c, q) in rigid_node for q in c.ports):
                actuator = circuit.component(rigid_node[next(node(c, q) for q in c.ports if node(c, q) in rigid_node)])
                if c.kind != "valve_4_3":
                    raise CircuitError(
                        f"{circuit.source}: {c.kind} '{c.name}' meters actuator '{actuator.name}' (fidelity "
                        f"'incompressible'), which only a valve_4_3's ports A and B can; give '{actuator.name}' the "
                        "fidelity 'compressible'")
                P, T, A, B = (node(c, q) for q in ("P", "T", "A", "B"))
                ports = [node(actuator, q) for q in actuator.ports]  # cap, rod / a, b
                if {A, B} != set(ports) or P in rigid_node or T in rigid_node:
                    raise CircuitError(
                        f"{circuit.source}: valve '{c.name}' meters actuator '{actuator.name}' (fidelity 'incompressible') "
                        f"but its ports A, B are not that actuator's two nets; give '{actuator.name}' the fidelity 'compressible'")
                if not fixed[T]:
                    raise CircuitError(
                        f"{circuit.source}: valve '{c.name}' of actuator '{actuator.name}' (fidelity 'incompressible'): its T net "
                        f"'{c.ports['T']}' must be a tank (the rigid actuator returns its oil there)")
                if actuator.name in rigid_valve:
                    raise CircuitError(f"{circuit.source}: actuator '{actuator.name}' (fidelity 'incompressible') is metered by two valves")
                if p.metering != "linear":
                    raise CircuitError(
                        f"{circuit.source}: valve '{c.name}', field 'metering': {p.metering!r} with actuator "
                        f"'{actuator.name}' of fidelity 'incompressible' (its rigid law meters linearly); use \"linear\" "
                        "or the fidelity 'compressible'")
                rigid_valve[actuator.name] = (vi, 1 if A == ports[0] else -1)
                passages = p.centre_passages()
            else:
                passages = p.edges(c.ports)
            for name, a, b, sign, base, full, centre, edge in passages:
                add_orifice(f"{c.name}.{name}", node(c, a), node(c, b), p.discharge_coefficient, base, full, centre,
                            vi, sign, (p, edge))
        slices["orifice"] = slice(start, len(branch_names))
        orifice_metering, metering_knots = metering_characteristics(o_edge)

        # law branches: from the component's first port to its second; a third port is a pilot terminal.  Their
        # states are numbered in circuit order; the branches are grouped by law (BRANCH_LAWS order).  First the
        # laminar resistances the network makes: actuator leaks (cylinders, then motors), hose lines.
        law_entries = []  # (law index, branch name, from node, to node, pilot node or -1, parameters, first state or -1,
        #                  first scheduled input or -1)
        laminar = BRANCH_LAWS.index(LaminarResistance)
        for c in cyl + mot:
            a, b = (node(c, "cap"), node(c, "rod")) if c.kind == "cylinder" else (node(c, "a"), node(c, "b"))
            if c.params.leakage_conductance > 0 and keep(c, a, b):
                law_entries.append((laminar, f"{c.name}.leakage", a, b, -1,
                                    LaminarResistance(conductance=c.params.leakage_conductance), -1, -1))
        viscosity = circuit.fluid.density * circuit.fluid.kinematic_viscosity
        for c in circuit.by_kind("hose"):
            if c.name in line_set:
                conductance = line_conductance(c.params.inner_diameter, c.params.length, viscosity)
                law_entries.append((laminar, f"{c.name}.line", node(c, "a"), node(c, "b"), -1,
                                    LaminarResistance(conductance=conductance), -1, -1))
        state_names = [v.name for v in valves]
        state_units = ["-"] * len(valves)
        state_start = [0.0] * len(valves)
        input_list, input_start = [], []  # the law components' scheduled inputs (pump speeds), in circuit order
        for c in circuit.components:
            law_class = COMPONENT_TYPES[c.kind]
            if law_class not in BRANCH_LAWS or not keep(c, node(c, law_class.PORTS[0]), node(c, law_class.PORTS[1])):
                continue  # (a rigid motor's flow is a rigid branch)
            own, driven = law_states(law_class), law_inputs(law_class)
            pilot = node(c, law_class.PORTS[2]) if len(law_class.PORTS) > 2 else -1
            first_input = act_names.index(c.name) if law_actuated(law_class) else len(input_list) if driven else -1
            law_entries.append((BRANCH_LAWS.index(law_class), c.name, node(c, law_class.PORTS[0]),
                                node(c, law_class.PORTS[1]), pilot, c.params, len(state_names) if own else -1,
                                first_input))
            input_list.extend(input_names(c.name, law_class) if driven else ())
            input_start.extend(c.params.input_start() if driven else ())
            state_names.extend(f"{c.name}.{name}" for name in own)
            state_units.extend(law_class.STATE_UNITS if own else ())
            state_start.extend(c.params.state_start() if own else ())
            if own and network_fidelity == "incompressible":
                raise CircuitError(f"{circuit.source}: component '{c.name}' (type '{c.kind}') has states of its own "
                                   f"{list(own)}, which the 'incompressible' level does not step; use 'compressible'")
        law_entries.sort(key=lambda entry: entry[0])
        start = len(branch_names)
        law_pilot, law_kind, law_rows, law_state_offset, law_input_offset = [], [], [], [], []
        for kind, name, a, b, pilot, params, offset, first_input in law_entries:
            add_branch(name, a, b)
            law_pilot.append(pilot)
            law_kind.append(kind)
            law_state_offset.append(offset)
            law_input_offset.append(first_input)
            row = np.zeros(LAW_WIDTH)
            values = params.law_row(circuit.fluid)
            row[:len(values)] = values
            law_rows.append(row)
        slices["law"] = slice(start, len(branch_names))

        valve_rate_offset = []
        for v in valves:
            second = v.params.dynamics == "second_order"
            valve_rate_offset.append(len(state_names) if second else -1)
            if second:
                state_names.append(f"{v.name}.spool_rate")
                state_units.append("1/s")
                state_start.append(0.0)

        # rigid branches: valve P -> T, carrying the flow a rigid actuator's rod (shaft) displaces
        start = len(branch_names)
        rigid = [c for c in actuators if c.name in rigid_valve]
        rigid_valves = [valves[rigid_valve[c.name][0]] for c in rigid]
        for c, v in zip(rigid, rigid_valves):
            add_branch(f"{c.name}.rigid", node(v, "P"), node(v, "T"))
        slices["rigid"] = slice(start, len(branch_names))

        def rate(c, side):
            """Displaced volume per unit rod travel [m²] (per radian for a motor) of the cap/a (0) or rod/b (1) side."""
            if c.kind == "motor":
                return c.params.displacement / (2.0 * np.pi)
            return (c.params.cap_area, c.params.rod_area)[side]

        nb = len(branch_names)
        b_from = np.array(b_from, int)
        b_to = np.array(b_to, int)
        b_pilot = np.full(nb, -1, int)
        b_pilot[slices["law"]] = law_pilot
        incidence = np.zeros((n, nb))
        incidence[b_to, np.arange(nb)] += 1.0
        incidence[b_from, np.arange(nb)] -= 1.0

        # every free node needs a volume to hold a pressure state
        acc_nodes = set(acc_node.tolist())
        for k in range(n):
            if not fixed[k] and volume[k] <= 0 and not has_chamber[k] and k not in acc_nodes:
                raise CircuitError(
                    f"{circuit.source}: net '{names[k]}' has no volume (no hose, volume, accumulator or cylinder chamber "
                    f"on it) and no tank: add a 'volume' or 'hose' component, or connect it"
                )

        f = np.array

        def column(comps, field, *default):
            """Parameter ``field`` of each component in ``comps`` as a float array (the field's SI unit);
            ``default`` stands in for a component type without the field."""
            return np.array([getattr(c.params, field, *default) for c in comps], float)

        model = cls(
            circuit=circuit,
            node_names=tuple(names),
            node_fixed=fixed,
            node_fixed_pressure=fixed_p,
            node_volume=volume,
            node_wall_compliance=wall,
            net_node=net_node,
            accumulator_node=acc_node,
            accumulator_gas_volume=column(acc, "gas_volume"),
            accumulator_precharge=column(acc, "precharge_pressure"),
            accumulator_index=column(acc, "polytropic_index"),
            actuator_names=act_names,
            actuator_kind=act_kind,
            cylinder_actuator=f([act_names.index(c.name) for c in cyl], int),
            cylinder_cap_node=f([node(c, "cap") for c in cyl], int),
            cylinder_rod_node=f([node(c, "rod") for c in cyl], int),
            cylinder_cap_area=column(cyl, "cap_area"),
            cylinder_rod_area=column(cyl, "rod_area"),
            cylinder_stroke=column(cyl, "stroke"),
            cylinder_dead_cap=column(cyl, "dead_volume_cap"),
            cylinder_dead_rod=column(cyl, "dead_volume_rod"),
            cylinder_coulomb=column(cyl, "coulomb_friction"),
            cylinder_static=column(cyl, "static_friction"),
            cylinder_stribeck=column(cyl, "stribeck_velocity"),
            cylinder_viscous=column(cyl, "viscous_friction"),
            cylinder_pressure_friction=column(cyl, "friction_pressure_coefficient"),
            cylinder_cushion_length_cap=column(cyl, "cushion_length_cap"),
            cylinder_cushion_length_rod=column(cyl, "cushion_length_rod"),
            cylinder_cushion_area_cap=column(cyl, "cushion_area_cap"),
            cylinder_cushion_area_rod=column(cyl, "cushion_area_rod"),
            cylinder_cushion_cd=column(cyl, "cushion_discharge_coefficient"),
            cylinder_cushion_check=f([1.0 if c.params.cushion_return == "check" else 0.0 for c in cyl], float),
            motor_actuator=f([act_names.index(c.name) for c in mot], int),
            motor_a_node=f([node(c, "a") for c in mot], int),
            motor_b_node=f([node(c, "b") for c in mot], int),
            motor_displacement=column(mot, "displacement"),
            valve_names=tuple(c.name for c in valves),
            valve_time_constant=column(valves, "time_constant"),
            valve_overlap=column(valves, "overlap"),
            pump_names=tuple(input_list),
            pump_nominal_speed=np.array(input_start, float),
            branch_names=tuple(branch_names),
            branch_from=b_from,
            branch_to=b_to,
            branch_slices=slices,
            orifice_cd=f(o_cd, float),
            orifice_base_area=f(o_base, float),
            orifice_max_area=f(o_max, float),
            orifice_centre_area=f(o_centre, float),
            orifice_valve=f(o_valve, int),
            orifice_sign=f(o_sign, float),
            fidelity=network_fidelity,
            pruned=pruned,
            incidence=incidence,
            actuator_fidelity=levels,
            hose_lines=tuple(c.name for c in circuit.by_kind("hose") if c.name in line_set),
            actuator_rigid=f([c.name in rigid_node.values() for c in actuators], bool),
            rigid_branch_actuator=f([act_names.index(c.name) for c in rigid], int),
            rigid_valve=f([rigid_valve[c.name][0] for c in rigid], int),
            rigid_sign=f([rigid_valve[c.name][1] for c in rigid], float),
            rigid_extend_area=f([rate(c, 0) for c in rigid], float),
            rigid_retract_area=f([rate(c, 1) for c in rigid], float),
            rigid_cd=column(rigid_valves, "discharge_coefficient"),
            rigid_base_area=column(rigid_valves, "leakage_area"),
            rigid_max_area=column(rigid_valves, "max_area"),
            branch_pilot=b_pilot,
            law_kind=f(law_kind, int),
            law_table=np.array(law_rows, float).reshape(len(law_rows), LAW_WIDTH),
            law_state_offset=f(law_state_offset, int),
            law_input_offset=f(law_input_offset, int),
            valve_rate_offset=f(valve_rate_offset, int),
            valve_omega=column(valves, "natural_frequency"),
            valve_zeta=column(valves, "damping_ratio"),
            component_state_names=tuple(state_names),
            component_state_units=tuple(state_units),
            component_state_start=np.array(state_start, float),
            valve_command_low=f([COMPONENT_TYPES[c.kind].COMMAND_RANGE[0] for c in valves], float),
            orifice_metering=orifice_metering,
            metering_knots=metering_knots,
        )
        return model

    # ------------------------------------------------------------- sizes
    @property
    def fluid(self):
        """The circuit's :class:`~hydraulics.fluid.Fluid`."""
        return self.circuit.fluid

    @property
    def node_count(self) -> int:
        return len(self.node_names)

    @property
    def actuator_count(self) -> int:
        return len(self.actuator_names)

    @property
    def component_state_count(self) -> int:
        """Entries of the component-state vector (``NetworkState.valve_spool``): the valves' spools, then the
        stateful law components' states (:attr:`component_state_names`)."""
        return len(self.component_state_names)

    @property
    def free_nodes(self) -> np.ndarray:
        """Indices of the nodes that carry a pressure state."""
        return np.flatnonzero(~self.node_fixed)

    @property
    def state_count(self) -> int:
        """Number of continuous hydraulic states (node pressures and spools)."""
        return int((~self.node_fixed).sum()) + len(self.valve_names)

    def node(self, net: str) -> int:
        """Node index of a circuit net (or of a node name)."""
        if net in self.net_node:
            return self.net_node[net]
        raise KeyError(f"no net called {net!r}; nets: {sorted(self.net_node)}")

    def actuator(self, name: str) -> int:
        """Index of the cylinder or motor called ``name``."""
        try:
            return self.actuator_names.index(name)
        except ValueError:
            raise KeyError(f"no cylinder or motor called {name!r}; actuators: {list(self.actuator_names)}") from None

    def law_branches(self, kind) -> slice:
        """The branches of the law components of circuit type ``kind`` (e.g. ``"relief_valve"``, or a class of
        :data:`~hydraulics.components.BRANCH_LAWS`): a slice of the branches (the law branches are grouped by
        law), empty when the circuit has none."""
        law = self.branch_slices["law"]
        index = BRANCH_LAWS.index(kind if isinstance(kind, type) else COMPONENT_TYPES[kind])
        first, last = np.searchsorted(self.law_kind, (index, index + 1))
        return slice(law.start + int(first), law.start + int(last))

    def law_parameter(self, kind, column: str) -> np.ndarray:
        """Column ``column`` of the law rows of every component of circuit type ``kind`` (in the order of
        :meth:`law_branches`), e.g. ``law_parameter("relief_valve", "cracking")`` [Pa]."""
        rows = self.law_branches(kind)
        law = self.branch_slices["law"]
        table = self.law_table[rows.start - law.start:rows.stop - law.start]
        cls = kind if isinstance(kind, type) else COMPONENT_TYPES[kind]
        return table[:, cls.LAW_COLUMNS.index(column)].copy()

    @property
    def pump_branches(self) -> np.ndarray:
        """The branch each entry of :attr:`pump_names` drives (int array): the branch of each law component with
        scheduled inputs, once per input."""
        law = self.branch_slices["law"]
        out = np.zeros(len(self.pump_names), int)
        scheduled = np.array([bool(law_inputs(cls)) for cls in BRANCH_LAWS], bool)[self.law_kind]
        for i in np.flatnonzero(scheduled & (self.law_input_offset >= 0)):
            first = self.law_input_offset[i]
            out[first:first + len(law_inputs(BRANCH_LAWS[self.law_kind[i]]))] = law.start + i
        return out

    def _fixed_and_compensated(self) -> slice:
        """The branches of the fixed-displacement and compensated pumps (adjacent: the last laws)."""
        fixed, compensated = self.law_branches("pump_fixed"), self.law_branches("pump_compensated")
        return slice(fixed.start, compensated.stop)

    def _pump_column(self, column: str) -> np.ndarray:
        rows = self._fixed_and_compensated()
        law = self.branch_slices["law"]
        return self.law_table[rows.start - law.start:rows.stop - law.start, PumpFixed.LAW_COLUMNS.index(column)].copy()

    @property
    def pump_index(self) -> np.ndarray:
        """Per fixed-displacement or compensated pump (branches in network order): its index into
        :attr:`pump_names`."""
        law = self.branch_slices["law"]
        rows = self._fixed_and_compensated()
        return self.law_input_offset[rows.start - law.start:rows.stop - law.start].copy()

    @property
    def pump_displacement(self) -> np.ndarray:
        """(Maximum) displacement [m³/rev] of each pump of :attr:`pump_index`."""
        return self._pump_column("displacement")

    @property
    def pump_efficiency(self) -> np.ndarray:
        """Volumetric efficiency η_v [-] of each pump of :attr:`pump_index` (1 for a compensated pump)."""
        return self._pump_column("efficiency")

    @property
    def pump_compensator(self) -> np.ndarray:
        """Compensator setting [Pa, absolute] of each pump of :attr:`pump_index` (inf for a fixed pump)."""
        return self._pump_column("compensator")

    @property
    def pump_band(self) -> np.ndarray:
        """Compensator band [Pa] of each pump of :attr:`pump_index`."""
        return self._pump_column("band")

    @property
    def relief_branches(self) -> slice:
        """The branches of the relief valves (``relief_valve``; a slice, see :meth:`law_branches`)."""
        return self.law_branches("relief_valve")

    @property
    def relief_cracking(self) -> np.ndarray:
        """Cracking pressure [Pa] of every relief valve (branches :attr:`relief_branches`)."""
        return self.law_parameter("relief_valve", "cracking")

    @property
    def relief_gradient(self) -> np.ndarray:
        """Pressure–flow gradient G [m³/(s·Pa)] of every relief valve (branches :attr:`relief_branches`)."""
        return self.law_parameter("relief_valve", "gradient")

    # ------------------------------------------------------- factories
    def control(self, **values) -> NetworkControl:
        """Controls with spools closed and pumps at nominal speed; keywords set valves [-] or pumps [rev/s] by name."""
        control = NetworkControl(np.zeros(len(self.valve_names)), self.pump_nominal_speed.copy())
        for name, value in values.items():
            self.set_control(control, name, value)
        return control

    def set_control(self, control: NetworkControl, name: str, value: float) -> None:
        """Set one named input: a valve's spool command [-] or a pump's speed [rev/s]."""
        if name in self.valve_names:
            control.valve_command[self.valve_names.index(name)] = value
        elif name in self.pump_names:
            control.pump_speed[self.pump_names.index(name)] = value
        else:
            raise KeyError(f"no valve or pump called {name!r}; inputs: {list(self.valve_names + self.pump_names)}")

    def state(self, *, actuator_position=None, node_pressure=None, actuator_velocity=None) -> NetworkState:
        """A state at the given actuator positions with the given absolute node pressures [Pa].

        ``node_pressure`` defaults to the reference pressure; ``actuator_position``
        defaults to mid-stroke for cylinders and 0 for motors.  Node oil content
        is computed from the pressures so that the state is consistent.
        """
        na = self.actuator_count
        x = np.zeros(na)
        x[self.cylinder_actuator] = 0.5 * self.cylinder_stroke
        if actuator_position is not None:
            x = np.array(actuator_position, float).reshape(na)
        v = np.zeros(na) if actuator_velocity is None else np.array(actuator_velocity, float).reshape(na)
        p = np.full(self.node_count, self.fluid.reference_pressure)
        if node_pressure is not None:
            p = np.array(node_pressure, float).reshape(self.node_count)
        p = np.where(self.node_fixed, self.node_fixed_pressure, p)
        oil = self.oil_from_pressure(p, x)
        state = NetworkState(oil, p, self.component_state_start.copy(), x, v, 0.0)
        state.node_pressure = self.pressure(oil, x)[0]
        return state

    # ---------------------------------------------------- node relations
    # The node relations below broadcast over leading axes: ``position`` of shape
    # (..., actuator_count) and ``pressure`` of shape (..., node_count) give results
    # of shape (..., node_count), one row per sample (the run logger derives whole
    # batches this way).  Each is one call of a compiled kernel on the packed model
    # (:func:`hydraulics._compiled.evaluation_entries`), looping over the samples.
    @cached_property
    def _packed(self):
        """(entries, F, I): the compiled evaluation kernels and this model packed for them
        (:func:`hydraulics._compiled.pack_network`), made on first use."""
        from . import _compiled

        return (_compiled.evaluation_entries(),) + _compiled.pack_network(self)

    @cached_property
    def ledger_branches(self) -> tuple:
        """(supplying, shaft, dissipative): indices of the branches the energy ledger
        (:func:`hydraulics.energy.branch_powers`) counts as supplied work (law branches whose law is a power source,
        ``SOURCE``: the pumps), as work on actuators (laws driven by their actuator, ``ACTUATOR_INPUT``: the motors)
        and as dissipation (the orifice-law branches, then the other law branches, in branch order); made on first
        use."""
        branch = np.arange(len(self.branch_from))
        law = branch[self.branch_slices["law"]] if "law" in self.branch_slices else branch[:0]
        source = np.array(law_sources(), bool)[self.law_kind] if len(law) else np.zeros(0, bool)
        shaft = np.array([law_actuated(cls) for cls in BRANCH_LAWS], bool)[self.law_kind] if len(law) else source
        return law[source], law[shaft], np.concatenate([branch[self.branch_slices["orifice"]], law[~(source | shaft)]])

    @cached_property
    def source_potential_ends(self):
        """(μ at each branch's from node, μ at its to node) [Pa], μ the pressure potential of the fixed nodes off the
        reference pressure (the pressure sources) and 0 at every other node; None when there is no such node
        (:func:`hydraulics.energy.source_power`); made on first use."""
        fluid = self.fluid
        fixed = np.asarray(self.node_fixed, bool) & (self.node_fixed_pressure != fluid.reference_pressure)
        if not fixed.any():
            return None
        mu = np.where(fixed, fluid.pressure_potential(np.where(fixed, self.node_fixed_pressure,
                                                               fluid.reference_pressure)), 0.0)
        return mu[self.branch_from], mu[self.branch_to]

    def _kernel(self, name, *args):
        """The evaluation kernel ``name`` on this model's packed arrays followed by ``args``."""
        entries, F, I = self._packed[:3]
        return entries[name]((F, I) + args)

    def geometric_volume(self, position):
        """Node volumes at the reference pressure [m³]: fixed volumes plus cylinder chambers at ``position``."""
        X, lead = _rows(position, self.actuator_count)
        return self._kernel("geometric_volume", X).reshape(lead + (self.node_count,))

    def extra_volume(self, pressure):
        """Pressure-dependent node volume [m³] (hose walls, accumulator liquid) and its derivative [m³/Pa]."""
        P, lead = _rows(pressure, self.node_count)
        extra, dextra = self._kernel("extra_volume", P)
        return extra.reshape(lead + (self.node_count,)), dextra.reshape(lead + (self.node_count,))

    def accumulator_liquid_volume(self, pressure):
        """Liquid volume [m³] in every accumulator and its derivative [m³/Pa] at its own pressure ``pressure`` [Pa],
        shape (..., accumulator_count) (:func:`hydraulics.components.accumulator.liquid_volume_with_derivative`)."""
        count = len(self.accumulator_node)
        P, lead = _rows(pressure, count)
        liquid, dliquid = self._kernel("accumulator_liquid", P)
        return liquid.reshape(lead + (count,)), dliquid.reshape(lead + (count,))

    @property
    def compliant_nodes(self) -> np.ndarray:
        """Free nodes whose volume depends on pressure (elastic walls or accumulators)."""
        mask = self.node_wall_compliance > 0
        mask[self.accumulator_node] = True
        return np.flatnonzero(mask & ~self.node_fixed)

    def node_volume_at(self, position, pressure):
        """Node volumes V(x, p) [m³] and ∂V/∂p [m³/Pa] (chambers, walls, accumulators), each of shape (..., node_count)."""
        (X, P), lead = _broadcast_rows((position, self.actuator_count), (pressure, self.node_count))
        extra, dextra = self._kernel("extra_volume", P)
        shape = lead + (self.node_count,)
        return (self._kernel("geometric_volume", X) + extra).reshape(shape), dextra.reshape(shape)

    def chamber_volumes(self, position):
        """Cap and rod chamber volumes [m³] and dV/dx [m²] of every cylinder at actuator ``position``, each of shape
        (..., cylinder_count) (:func:`hydraulics.components.cylinder.chamber_volumes`)."""
        X, lead = _rows(position, self.actuator_count)
        out = self._kernel("chamber_volumes", X)
        return tuple(out[j].reshape(lead + (len(self.cylinder_actuator),)) for j in range(4))

    def volume_position_gradient(self, position) -> np.ndarray:
        """∂V_node/∂x_actuator [m²], shape (node_count, actuator_count)."""
        return self._kernel("volume_position_gradient", _vector(position, self.actuator_count))

    def oil_from_pressure(self, pressure, position):
        """Oil content m = V(x, p)·φ(p) [m³] of every node (NaN for fixed nodes)."""
        (P, X), lead = _broadcast_rows((pressure, self.node_count), (position, self.actuator_count))
        return self._kernel("oil", P, X).reshape(lead + (self.node_count,))

    def pressure(self, oil, position):
        """Absolute node pressures [Pa] from oil content and actuator positions.

        Returns
        -------
        pressure : ndarray, shape (..., node_count)
            Solves m = V(x, p)·φ(p), floored at the cavitation pressure; fixed
            nodes at their set pressure.  Compliant nodes (elastic walls,
            accumulators) by a safeguarded Newton iteration on ln(V·φ/m) to
            ``PRESSURE_INVERSION_TOLERANCE``.
        dp_doil : ndarray, shape (..., node_count)
            ∂p/∂m [Pa/m³] = 1/(∂V/∂p·φ + V·φ'); 0 for fixed and cavitating nodes.
        """
        (M, X), lead = _broadcast_rows((oil, self.node_count), (position, self.actuator_count))
        p, dpdm = self._kernel("pressure", M, X)
        return p.reshape(lead + (self.node_count,)), dpdm.reshape(lead + (self.node_count,))

    def effective_bulk_modulus(self, pressure, position, volumes=None):
        """Effective bulk modulus of each node [Pa]: V·φ/(∂V/∂p·φ + V·φ'), including walls and accumulators
        (tanks: the oil's own modulus φ/φ').

        ``volumes`` may pass :meth:`node_volume_at` of the same state to save recomputing it.
        """
        volume, dvdp = self.node_volume_at(position, pressure) if volumes is None else volumes
        n = self.node_count
        (P, V, D), lead = _broadcast_rows((pressure, n), (volume, n), (dvdp, n))
        return self._kernel("bulk_modulus", P, V, D).reshape(lead + (n,))

    # ------------------------------------------------------------ flows
    def valve_commands(self, command) -> np.ndarray:
        """The valves' commands [-] held to their kinds' ranges (``COMMAND_RANGE``: [−1, 1] for a 4/3 valve, [0, 1]
        for a variable orifice), as the kernels hold them."""
        return np.clip(np.asarray(command, float), self.valve_command_low, 1.0)

    def valve_areas(self, spool):
        """Open area [m²] of every orifice-law branch for the given spool positions, followed (when the
        network has rigid actuators) by the displacement rate of every rigid branch (:meth:`rigid_rates`)."""
        return self._kernel("valve_areas", self._spools(spool))

    def _spools(self, spool):
        """The valves' spools [-] of ``spool`` (the valves' spools, or the whole component-state vector)."""
        return _vector(np.asarray(spool, float)[:len(self.valve_names)], len(self.valve_names))

    def _rigid(self, spool):
        return self._kernel("rigid", self._spools(spool))

    def rigid_direction(self, spool):
        """Metering direction of every rigid branch [-]: +1 when the spool feeds the cap (motor port a) from P,
        −1 the rod (port b), 0 while the spool is inside its overlap (closed)."""
        return self._rigid(spool)[0]

    def rigid_rates(self, spool):
        """Flow drawn from P per unit actuator velocity [m² or m³/rad] of every rigid branch: the cap area
        (D/2π) feeding the extension, −rod area feeding the retraction, 0 closed.  With rigid oil the
        flow P → actuator is this rate times the velocity, whatever its sign (an overrunning load pushes
        oil back into P)."""
        return self._rigid(spool)[1]

    def rigid_metering_area(self, spool):
        """Open area [m²] of each rigid branch's metering edges (P → inlet, outlet → T) at ``spool``:
        leakage area + full area·opening(|s|) (:func:`hydraulics.components.valve_4_3.metering_opening`)."""
        return self._rigid(spool)[2]

    def law_pieces(self, pressure, state=None, h=0.0) -> np.ndarray:
        """Which piece of its piecewise law every law branch is on at ``pressure`` [Pa] (int array: relief ramps,
        check-valve openings, pump compensators, …), by its component's ``LAW_PIECE`` over a step of ``h`` [s] from
        the component states ``state``, default :attr:`component_state_start`; 0 for a law without kinks).

        A step whose start and end differ here crosses a kink of the flow laws (a relief cracking, a check
        valve opening fully, a compensator engaging, a poppet reaching its seat): one Jacobian of the start does
        not describe it.
        """
        start = self.component_state_start if state is None else state
        return self._kernel("law_pieces", _vector(pressure, self.node_count),
                            _vector(start, self.component_state_count), float(h))

    def branch_flows(self, pressure, orifice_area, pump_speed, actuator_velocity, state=None, h=0.0) -> BranchFlows:
        """Flow [m³/s] of every branch and its pressure derivatives (the component laws of
        :mod:`hydraulics.components`: orifices, leaks, reliefs, check valves, pumps, motors, law branches; rigid
        branches carry their rate times the actuator velocity).

        Parameters
        ----------
        pressure : ndarray, shape (node_count,)
            Absolute node pressures [Pa].
        orifice_area : ndarray, shape (orifice branches [+ rigid branches],)
            From :meth:`valve_areas`.
        pump_speed : ndarray, shape (pump_count,)
            [rev/s].
        actuator_velocity : ndarray, shape (actuator_count,)
            The motors' shaft speeds [rad/s] (and rigid actuators' velocities) are read from it.
        state : ndarray, shape (component_state_count,), optional
            Component states at the start of a step of ``h`` [s] (default: :attr:`component_state_start`); a
            stateful component's flow is that at the end of the step (with ``h`` = 0: at these states).
        """
        area = _vector(orifice_area, self.branch_slices["orifice"].stop + len(self.rigid_branch_actuator))
        flow, dflow = self._kernel("branch_flows", _vector(pressure, self.node_count), area,
                                   _vector(pump_speed, len(self.pump_names)), _vector(actuator_velocity, self.actuator_count),
                                   _vector(self.component_state_start if state is None else state,
                                           self.component_state_count), float(h))
        sl = self.branch_slices.get("law", slice(0, 0))
        pilot = dflow[:, 2].copy() if sl.stop > sl.start else None
        return BranchFlows(flow, dflow[:, 0].copy(), dflow[:, 1].copy(), pilot)

    def flow_jacobian(self, flows: BranchFlows) -> np.ndarray:
        """∂(net inflow)/∂p, shape (node_count, node_count) [m³/(s·Pa)]."""
        pilot = np.zeros(len(self.branch_names)) if flows.dflow_dpilot is None else flows.dflow_dpilot
        dflow = np.column_stack((flows.dflow_dfrom, flows.dflow_dto, pilot)).astype(float).reshape(len(self.branch_names), 3)
        return self._kernel("flow_jacobian", np.ascontiguousarray(dflow))

    def flow_velocity_gradient(self, orifice_area=None) -> np.ndarray:
        """∂(net inflow)/∂v_actuator [m² or m³/rad], shape (node_count, actuator_count): motor branches and,
        given ``orifice_area`` from :meth:`valve_areas`, rigid branches."""
        count = len(self.rigid_branch_actuator)
        rates = np.zeros(count)
        if orifice_area is not None:
            rates = _vector(np.asarray(orifice_area, float)[self.branch_slices["orifice"].stop:], count)
        return self._kernel("flow_velocity_gradient", rates)

    # ----------------------------------------------------------- efforts
    def pressure_effort(self, pressure):
        """Effort of the pressures on every actuator, shape (..., actuator_count).

        Cylinders: p_cap·A_cap − p_rod·A_rod − p_amb·(A_cap − A_rod) [N], with
        the ambient pressure = the fluid's reference pressure.  Motors:
        τ = D·(p_a − p_b)/(2π) [N·m].
        """
        P, lead = _rows(pressure, self.node_count)
        return self._kernel("pressure_effort", P).reshape(lead + (self.actuator_count,))

    def friction_effort(self, velocity, pressure=None, position=None):
        """Seal friction and end cushions acting on every actuator (−F_f(v, p) − F_k(x, v), opposing motion) and
        their velocity derivative at the node ``pressure`` [Pa] (the seal load,
        :func:`hydraulics.components.cylinder.seal_load`) and the actuator ``position`` [m] (the cushions,
        :func:`hydraulics.components.cylinder.cushion_force_with_derivative`); ``None``: without that part, as
        for the rigid actuators, which have neither)."""
        P = np.zeros(0) if pressure is None else pressure
        X = np.zeros(0) if position is None else position
        (V, P, X), lead = _broadcast_rows((velocity, self.actuator_count),
                                          (P, 0 if pressure is None else self.node_count),
                                          (X, 0 if position is None else self.actuator_count))
        effort, slope = self._kernel("friction_effort", V, P, X)
        return effort.reshape(lead + (self.actuator_count,)), slope.reshape(lead + (self.actuator_count,))

    def actuator_effort(self, pressure, velocity, position=None):
        """Total effort (pressure + friction, + end cushions at the actuator ``position`` if given) on every actuator
        and its derivative with respect to its own velocity.

        The derivative is the friction slope only (the pressure part depends on
        v through the network; see :meth:`StepperImplicitEuler.linearize`).
        """
        friction, slope = self.friction_effort(velocity, pressure, position)
        return self.pressure_effort(pressure) + friction, slope

    def effort_pressure_gradient(self) -> np.ndarray:
        """∂effort/∂p_node, shape (actuator_count, node_count) [m² or m³/rad]."""
        return self._kernel("effort_pressure_gradient")

    def chamber_stiffness(self, pressure, position, volumes=None):
        """Hydraulic stiffness β_eff·A²/V [N/m] of every cylinder's cap and rod chamber, shape (..., 2, cylinder_count)
        (:func:`hydraulics.components.cylinder.hydraulic_stiffness`).

        ``volumes`` may pass :meth:`node_volume_at` of the same state to save recomputing it.
        """
        volumes = self.node_volume_at(position, pressure) if volumes is None else volumes
        beta = self.effective_bulk_modulus(pressure, position, volumes)
        n = self.node_count
        (B, V), lead = _broadcast_rows((beta, n), (volumes[0], n))
        return self._kernel("chamber_stiffness", B, V).reshape(lead + (2, len(self.cylinder_actuator)))
