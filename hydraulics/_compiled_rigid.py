"""Compiled (numba) kernels of the explicit, incompressible and rigid-actuator couplings.

The one implementation of the equations of :class:`~hydraulics.steppers.StepperExplicitEuler`,
:class:`~hydraulics.coupling.CouplingIncompressible`, :class:`~hydraulics.coupling.CouplingMixed` and
:func:`~hydraulics.coupling.derive_chamber_pressures`; the per-step classes call the cached entry points below,
and ``sim.plants.mujoco_fast``'s control callback calls the allocation-free kernels directly.  They work on the
packed network of :mod:`hydraulics._compiled` (``pnet``) plus the per-actuator constants packed here as named
layouts (:class:`IncompressibleTable`, :class:`RigidTable`, scalar columns :data:`INCOMPRESSIBLE_SCALARS`,
:data:`RIGID_SCALARS`).

Equations (SI units; a motor's "area" is its displacement per radian D/2π [m³/rad]):

* **Explicit Euler** (forward Euler on the oil, zero-order hold, :func:`explicit_substep`):
  m⁺ = m + h·ΣQ(p(m, x), s, v) on the free nodes, with the start spools s, the start positions x and the
  held velocities v; p⁺ = p(m⁺, x⁺); the spools advance exactly (``valve_4_3.spool_step``).  A rigid branch
  (P → T of a rigid actuator's valve) carries Q = r(s)·v (:func:`hydraulics.components.valve_4_3.displaced_rate`).
* **Metered rigid-oil force** (Merritt §5.2, quasi-static, :func:`hydraulics.components.valve_4_3.metered_actuator_force`):
  F(v) = F_d − R·v·|v|, F_d = d·((p_s − p_a)·A_in − (p_t − p_a)·A_out),
  R = (ρ/2)·(A_in³/(C_d·a_in)² + A_out³/(C_d·a_out)²) (inf where an edge is shut), linearised at the start
  speed (:func:`quadratic_damper`).
* **Velocity tracker** (:func:`bounded_tracker`): F = K·(v_t − v⁺), K = G·m_eff/h (:func:`tracking_gain`,
  G = ``INCOMPRESSIBLE_TRACKING_GAIN``) lowered so that F at the start speed stays within the effort bounds.
* **Incompressible law** (:func:`incompressible_law`): the metered damper per actuator with supply p_s (the
  highest compensator setting, else the highest relief setting), a lock (tracker to v = 0) for a closed valve,
  the pumps' delivery shared among the demands A_in·√(|F_d|/R), trackers where the share is slower, bounds
  ±p_relief·A.  End stops (:func:`stroke_speeds`): a cylinder within reach of an end of its stroke
  (``STOP_REACH``·max(v, v_t, 0)·h ≥ the distance left to the extended end, likewise retracting) tracks v_t
  clipped to [−x/h, (stroke − x)/h] within the same bounds, so x⁺ = x + h·v⁺ stays in [0, stroke] to the
  tracker's residual while the load stays within the bounds.  MuJoCo mode holds the end against any load
  (:func:`end_stop_hold`: the end cap takes what pushes past it, the bound on that side dropped).
  **Limitation**: in PBD mode a load beyond the relief force still drives the rod past its end, where the solver's
  own joint and tendon limits act; the stop knows the stroke only, not a narrower joint range of the link it drives.
* **Rigid actuators in a compressible network** (:func:`mixed_law`): the metered damper at the live supply
  pressure p_P(v⁺) = p_P,lin + (∂p_P/∂v)·(v⁺ − v_g), plus seal friction; the bounds are the forces at p_P on
  [cavitation floor, highest relief].
* **Chamber pressures of rigid oil** (:func:`chamber_pressures`): p_loaded = p_ref + |F|/A, the other side p_ref.

Under ``NUMBA_DISABLE_JIT=1`` everything runs as Python.  **Limitations**: as the couplings (see
:mod:`hydraulics.coupling`); the tables are built once per model (:func:`pack_incompressible`,
:func:`pack_rigid`).

Example
-------
>>> round(bounded_tracker(0.1, 0.0, 1e6, -1e3, 1e3)[1])  # the gain lowered so that F(v = 0) stays within 1 kN
-10000
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from . import _compiled as C
from ._jit import FINGERPRINT, clip, inline, kernel, matrix, maximum, minimum
from .components import valve_4_3 as _valve
from .components.cylinder import CI_ACT, CI_CAP, CI_ROD
from .components.motor import MI_A, MI_ACT, MI_B
from .components.parameters import table
from .components.valve_4_3 import V_OVERLAP
from .layout import Layout, table_carver

# Incompressible fidelity: the rod follows its metered flow with this stiffness relative to
# m_eff/h (the velocity error left after one step is about 1/(1 + gain) of the demand change).
INCOMPRESSIBLE_TRACKING_GAIN = 100.0  # [-]
# End stops at the incompressible level: a cylinder whose start or target speed, times this factor, would take it
# past an end of its stroke within the step tracks a speed that ends the step at that end at most (room for a load
# that speeds it up within the step).
STOP_REACH = 2.0  # [-]
# End stops in MuJoCo mode (:func:`end_stop_hold`): a tracker's target within this relative tolerance (at least this
# many m/s) of an end speed is a tracker of that end speed (the target read back as −const/slope differs by round-off)
END_SPEED_MATCH = 1e-9  # [-]
# Velocity tracker: a gain lowered to keep the force at the start velocity within its bound keeps it this factor inside
# (MuJoCo counts a force at its bound as clamped: no implicit term for the step) [-]
TRACKER_BOUND_MARGIN = 1.0 - 1e-9  # [-]
# Force bound of an incompressible actuator in a circuit without relief valves, as a pressure.
INCOMPRESSIBLE_UNBOUNDED_PRESSURE = 1e12  # Pa

# ----------------------------------------------------------------------------
# Named layouts
# ----------------------------------------------------------------------------
EDGE_COLUMNS = ("extend_supply", "extend_return", "retract_supply", "retract_return")
"""Metering edges of an incompressible actuator's valve (orifice-branch index, −1: none): P → inlet and outlet → T
opening with spool > 0 (extend), P → outlet and inlet → T opening with spool < 0 (retract)."""
E_EXTEND_SUPPLY, E_EXTEND_RETURN, E_RETRACT_SUPPLY, E_RETRACT_RETURN = range(len(EDGE_COLUMNS))
INCOMPRESSIBLE_SCALARS = ("supply_pressure", "density", "tracking_gain")
"""Scalars of :class:`IncompressibleTable`: supply pressure p_s [Pa] (absolute), oil density ρ [kg/m³], G [-]."""
IS_SUPPLY, IS_DENSITY, IS_GAIN = range(len(INCOMPRESSIBLE_SCALARS))
RIGID_SCALARS = ("supply_top", "density", "tracking_gain")
"""Scalars of :class:`RigidTable`: highest supply pressure the reliefs allow [Pa] (absolute), ρ [kg/m³], G [-]."""
RS_TOP, RS_DENSITY, RS_GAIN = range(len(RIGID_SCALARS))

IncompressibleTable = namedtuple("IncompressibleTable", ("edges", "edge_cd", "extend_area", "retract_area",
                                                         "force_lower", "force_upper", "scalars"))
IncompressibleTable.__doc__ = """Per-actuator constants of the incompressible law: metering edges (actuators × :data:`EDGE_COLUMNS`,
int64) and their discharge coefficients, areas A extending / retracting [m² | m³/rad], effort bounds [N | N·m],
scalars (:data:`INCOMPRESSIBLE_SCALARS`)."""
RigidTable = namedtuple("RigidTable", ("rigid", "force_lower", "force_upper", "actuator", "valve", "sign", "extend_area",
                                       "retract_area", "cd", "base_area", "max_area", "supply", "tank", "scalars"))
RigidTable.__doc__ = """Rigid actuators of a compressible network: per actuator the rigid flag (int64) and effort bounds
(±inf for compressible ones); per rigid branch (in the model's order) its actuator, valve, sign (+1: spool > 0 feeds the
cap), areas extending / retracting, C_d, leakage and full metering area [m²], supply and tank nodes; scalars
(:data:`RIGID_SCALARS`)."""


def _relief_pressure(model) -> float:
    """Highest relief setting [Pa] (gauge), or INCOMPRESSIBLE_UNBOUNDED_PRESSURE without relief valves."""
    return float(np.max(model.relief_cracking)) if len(model.relief_cracking) else INCOMPRESSIBLE_UNBOUNDED_PRESSURE


def _actuator_areas(model):
    """Areas A extending / retracting of every actuator [m² | m³/rad]: cap / rod, D/2π for motors."""
    n = model.actuator_count
    extend, retract = np.zeros(n), np.zeros(n)
    extend[model.cylinder_actuator] = model.cylinder_cap_area
    retract[model.cylinder_actuator] = model.cylinder_rod_area
    extend[model.motor_actuator] = retract[model.motor_actuator] = model.motor_displacement / (2.0 * np.pi)
    return extend, retract


def pack_incompressible(model) -> IncompressibleTable:
    """The :class:`IncompressibleTable` of an incompressible network: each actuator's metering edges found from the
    orifice branches that reach its chambers (motor ports)."""
    n = model.actuator_count
    edges = np.full((n, len(EDGE_COLUMNS)), -1, np.int64)
    cylinders, motors = list(model.cylinder_actuator), list(model.motor_actuator)
    for a in range(n):
        if a in cylinders:
            i = cylinders.index(a)
            inlet, outlet = model.cylinder_cap_node[i], model.cylinder_rod_node[i]
        else:
            i = motors.index(a)
            inlet, outlet = model.motor_a_node[i], model.motor_b_node[i]
        for b in range(model.branch_slices["orifice"].stop):
            sign = model.orifice_sign[b]
            if model.orifice_valve[b] < 0 or sign == 0:
                continue
            frm, to = model.branch_from[b], model.branch_to[b]
            if to == inlet:
                edges[a, E_EXTEND_SUPPLY if sign > 0 else E_RETRACT_SUPPLY] = b
            elif frm == outlet:
                edges[a, E_EXTEND_RETURN if sign > 0 else E_RETRACT_RETURN] = b
            elif to == outlet:
                edges[a, E_RETRACT_SUPPLY if sign < 0 else E_EXTEND_SUPPLY] = b
            elif frm == inlet:
                edges[a, E_RETRACT_RETURN if sign < 0 else E_EXTEND_RETURN] = b
    relief = _relief_pressure(model)
    compensators = model.pump_compensator[np.isfinite(model.pump_compensator)]
    supply = model.fluid.reference_pressure + (np.max(compensators) if len(compensators) else relief)
    extend, retract = _actuator_areas(model)
    cd = np.where(edges >= 0, np.asarray(model.orifice_cd, float)[np.maximum(edges, 0)] if len(model.orifice_cd) else 0.0, 0.0)
    scalars = table(INCOMPRESSIBLE_SCALARS, 1, supply_pressure=supply, density=model.fluid.density,
                    tracking_gain=INCOMPRESSIBLE_TRACKING_GAIN)[0]
    return IncompressibleTable(edges, np.ascontiguousarray(cd, float), extend, retract, -relief * retract, relief * extend,
                               scalars)


def pack_rigid(model) -> RigidTable:
    """The :class:`RigidTable` of a network (empty branch columns without rigid actuators)."""
    relief = _relief_pressure(model)
    extend, retract = _actuator_areas(model)
    rigid = np.asarray(model.actuator_rigid, bool)
    if rigid.size != model.actuator_count:
        rigid = np.zeros(model.actuator_count, bool)
    s = model.branch_slices.get("rigid", slice(0, 0))
    scalars = table(RIGID_SCALARS, 1, supply_top=model.fluid.reference_pressure + relief, density=model.fluid.density,
                    tracking_gain=INCOMPRESSIBLE_TRACKING_GAIN)[0]

    def f(a):
        return np.ascontiguousarray(a, float)

    def i(a):
        return np.ascontiguousarray(a, np.int64)

    return RigidTable(i(rigid), f(np.where(rigid, -relief * retract, -np.inf)), f(np.where(rigid, relief * extend, np.inf)),
                      i(model.rigid_branch_actuator), i(model.rigid_valve), f(model.rigid_sign), f(model.rigid_extend_area),
                      f(model.rigid_retract_area), f(model.rigid_cd), f(model.rigid_base_area), f(model.rigid_max_area),
                      i(model.branch_from[s]), i(model.branch_to[s]), scalars)


INCOMPRESSIBLE_FLOATS = Layout("incompressible_floats", ("na",), (
    ("edge_cd", "na", len(EDGE_COLUMNS)), ("extend_area", "na"), ("retract_area", "na"), ("force_lower", "na"),
    ("force_upper", "na"), ("scalars", len(INCOMPRESSIBLE_SCALARS))))
"""The float64 fields of an :class:`IncompressibleTable` of ``na`` actuators, flattened (:func:`flatten_incompressible`)."""
INCOMPRESSIBLE_INTS = Layout("incompressible_ints", ("na",), (("edges", "na", len(EDGE_COLUMNS)),))
"""The int64 fields of an :class:`IncompressibleTable`, flattened."""
RIGID_FLOATS = Layout("rigid_floats", ("na", "nr"), (
    ("force_lower", "na"), ("force_upper", "na"), ("sign", "nr"), ("extend_area", "nr"), ("retract_area", "nr"),
    ("cd", "nr"), ("base_area", "nr"), ("max_area", "nr"), ("scalars", len(RIGID_SCALARS))))
"""The float64 fields of a :class:`RigidTable` of ``na`` actuators and ``nr`` rigid branches, flattened
(:func:`flatten_rigid`): per actuator, then per rigid branch, then the scalars."""
RIGID_INTS = Layout("rigid_ints", ("na", "nr"), (("rigid", "na"), ("actuator", "nr"), ("valve", "nr"), ("supply", "nr"),
                                                 ("tank", "nr")))
"""The int64 fields of a :class:`RigidTable`, flattened."""


def table_sizes(na, nr) -> tuple[int, int]:
    """(float64, int64) lengths that hold either flattened table of ``na`` actuators and ``nr`` rigid branches: the
    larger of :data:`INCOMPRESSIBLE_FLOATS` and :data:`RIGID_FLOATS`, of :data:`INCOMPRESSIBLE_INTS` and
    :data:`RIGID_INTS` (a caller that views both tables in the same arrays, the fast MuJoCo plant)."""
    return (max(INCOMPRESSIBLE_FLOATS.size(na=na), RIGID_FLOATS.size(na=na, nr=nr)),
            max(INCOMPRESSIBLE_INTS.size(na=na), RIGID_INTS.size(na=na, nr=nr)))


def flatten_incompressible(T: IncompressibleTable, sizes: tuple[int, int] | None = None):
    """``T`` as one float64 and one int64 array (:data:`INCOMPRESSIBLE_FLOATS`, :data:`INCOMPRESSIBLE_INTS`; for a
    caller that passes addresses, the fast MuJoCo plant), of ``sizes`` entries when given (:func:`table_sizes`; padded
    with 0 and −1); :func:`unflatten_incompressible` rebuilds the table."""
    na = len(T.extend_area)
    nf, ni = sizes if sizes is not None else (None, None)
    return (INCOMPRESSIBLE_FLOATS.gather(T, np.float64, nf, 0.0, na=na),
            INCOMPRESSIBLE_INTS.gather(T, np.int64, ni, -1, na=na))


unflatten_incompressible = C._jit(table_carver(IncompressibleTable, ((INCOMPRESSIBLE_FLOATS, "TF"),
                                                                     (INCOMPRESSIBLE_INTS, "TI")), ("na",), matrix))


def flatten_rigid(T: RigidTable, sizes: tuple[int, int] | None = None):
    """``T`` as one float64 and one int64 array (:data:`RIGID_FLOATS`, :data:`RIGID_INTS`; see
    :func:`flatten_incompressible`); :func:`unflatten_rigid` rebuilds it."""
    na, nr = len(T.rigid), len(T.actuator)
    nf, ni = sizes if sizes is not None else (None, None)
    return RIGID_FLOATS.gather(T, np.float64, nf, 0.0, na=na, nr=nr), RIGID_INTS.gather(T, np.int64, ni, -1, na=na, nr=nr)


unflatten_rigid = C._jit(table_carver(RigidTable, ((RIGID_FLOATS, "TF"), (RIGID_INTS, "TI")), ("na", "nr"), matrix))


# ----------------------------------------------------------------------------
# Scalar laws
# ----------------------------------------------------------------------------
@kernel
def sign(x):
    """np.sign: −1, 0 or +1 (NaN stays NaN)."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x * 0.0


@kernel
def quadratic_damper(drive, resist, velocity):
    """F_d − R·v⁺·|v⁺| linearised at ``velocity``: (constant, slope) of constant + slope·v⁺."""
    return drive + resist * velocity * abs(velocity), -2.0 * resist * abs(velocity)


@kernel
def free_speed(drive, resist):
    """Speed [m/s | rad/s] of a metered rigid actuator without load: √(|F_d|/R)."""
    return math.sqrt(abs(drive) / resist)


@kernel
def tracking_gain(gain, effective_mass, dt):
    """Stiffness [N·s/m | N·m·s/rad] of a velocity tracker: gain·m_eff/h (m_eff = 1 where it is not finite)."""
    mass = effective_mass if math.isfinite(effective_mass) else 1.0
    return gain * mass / dt


@kernel
def bounded_tracker(target, velocity, gain, lower, upper):
    """Velocity tracker F = K·(target − v⁺) as (constant, slope), K = ``gain`` lowered so that F at the start
    ``velocity`` stays within [``lower``, ``upper``]: MuJoCo applies a force clamped at the start of its step
    explicitly, and the bound force over a long step would throw a light link far past its target.  The lowered gain
    keeps F at the start velocity a factor ``TRACKER_BOUND_MARGIN`` inside the bound: MuJoCo counts a force at its
    bound as clamped and drops the implicit term, which would hand the load the whole bound force for the step."""
    error = target - velocity
    bound = upper if error >= 0 else -lower
    if abs(error) > 0:
        gain = clip(TRACKER_BOUND_MARGIN * bound / abs(error), 0.0, gain)
    return gain * target, -gain


# ----------------------------------------------------------------------------
# Network kernels (allocation-free, on the packed network)
# ----------------------------------------------------------------------------
# Scratch layouts (hydraulics.layout): n nodes, na actuators, nr rigid branches, narea valve-area entries
# (_compiled._area_count, at most the branch count), nmixed: the length of mixed_law's scratch.
EXPLICIT_SCRATCH = Layout("explicit_scratch", ("n", "narea"),
                          (("geo", "n"), ("dpdm", "n"), ("inflow", "n"), ("area", "narea")))
"""Scratch of :func:`explicit_substep`: geometric volumes [m³], ∂p/∂m [Pa/m³], net inflow [m³/s], valve areas [m²]."""
MIXED_LAW_SCRATCH = Layout("mixed_law_scratch", ("na",),
                           (("friction", "na"), ("fslope", "na"), ("target", "na"), ("tracking", "na")))
"""Scratch of :func:`mixed_law`."""
EXPLICIT_LAW_SCRATCH = Layout("explicit_law_scratch", ("na",), (("friction", "na"), ("damping", "na")))
"""Scratch of :func:`explicit_law`."""
RIGID_LAW_SCRATCH = Layout("rigid_law_scratch", ("nr", "n", "nmixed"), (
    ("p_supply", "nr"), ("gradient", "nr"), ("v_guess", "nr"), ("geo", "n"), ("p", "n"), ("dpdm", "n"),
    ("mixed", "nmixed")))
"""Scratch of :func:`rigid_law`: the supply terms per rigid branch, the pressure law's outputs, then
:data:`MIXED_LAW_SCRATCH`."""
RIGID_FINISH_SCRATCH = Layout("rigid_finish_scratch", ("na",), (("friction", "na"), ("fslope", "na"),
                                                                 ("hydraulic", "na")))
"""Scratch of :func:`rigid_finish`."""

_explicit_scratch = inline(EXPLICIT_SCRATCH.carver(matrix))
_mixed_law_scratch = inline(MIXED_LAW_SCRATCH.carver(matrix))
_explicit_law_scratch = inline(EXPLICIT_LAW_SCRATCH.carver(matrix))
_rigid_law_scratch = inline(RIGID_LAW_SCRATCH.carver(matrix))
_rigid_finish_scratch = inline(RIGID_FINISH_SCRATCH.carver(matrix))
_explicit_scratch_size = kernel(EXPLICIT_SCRATCH.sizer())
_mixed_law_scratch_size = kernel(MIXED_LAW_SCRATCH.sizer())


@kernel
def explicit_work_size(ic):
    """Scratch entries :func:`explicit_substep` takes (:data:`EXPLICIT_SCRATCH`)."""
    return _explicit_scratch_size(ic[C.IC_N], C._area_count(ic))


def coupled_work_size(newton, n, na, nb, nr) -> int:
    """Length of a plant's float64 scratch ``W`` for its compiled steps: the longest of the Newton kernels'
    ``newton`` (``_compiled.work_size``) and this module's layouts for ``n`` nodes, ``na`` actuators, ``nb`` branches
    (an upper bound of the valve-area entries) and ``nr`` rigid branches: :data:`EXPLICIT_SCRATCH`, the
    incompressible finish's volumes (n), :data:`EXPLICIT_LAW_SCRATCH`, :data:`RIGID_LAW_SCRATCH`,
    :data:`RIGID_FINISH_SCRATCH`."""
    return max(int(newton), EXPLICIT_SCRATCH.size(n=n, narea=nb), n, EXPLICIT_LAW_SCRATCH.size(na=na),
               RIGID_LAW_SCRATCH.size(nr=nr, n=n, nmixed=MIXED_LAW_SCRATCH.size(na=na)),
               RIGID_FINISH_SCRATCH.size(na=na))


@kernel
def explicit_substep(pnet, W, start, x_end, h, out):
    """One forward-Euler substep of ``h`` [s] from ``start`` (:class:`hydraulics._compiled.StepStart`; its
    velocities held over the substep) into ``out`` (:class:`hydraulics._compiled.StepOut`): end spools, oil
    m⁺ = m + h·ΣQ(p(m, x), s, v), flows at the start, pressures p(m⁺, ``x_end``).  ``W``: scratch of
    :func:`explicit_work_size` entries; ``istats`` counts one right-hand side."""
    oil0, spool0, command, speed, x, v = start
    oil, p, spool, flow, dflow, istats = out
    net = C._deref(pnet)
    n = net.ic[C.IC_N]
    ws, _ = _explicit_scratch(W, 0, n, C._area_count(net.ic))
    geo, dpdm, inflow, area = ws.geo, ws.dpdm, ws.inflow, ws.area
    C._spool_end(pnet, spool0, command, h, spool)
    C._pressure(pnet, oil0, x, geo, p, dpdm)
    C._valve_areas(pnet, spool0, area)
    C._branch_flows(pnet, p, area, speed, v, flow, dflow, spool0, h)
    C._net_inflow(pnet, flow, inflow)
    C._copy(oil, oil0)
    free = net.free
    for j in range(free.size):
        k = free[j]
        oil[k] = oil0[k] + h * inflow[k]
    C._pressure(pnet, oil, x_end, geo, p, dpdm)
    C._law_states_end(pnet, spool, h, p)
    istats[:] = 0
    istats[C.IS_RHS] = 1


@kernel
def chamber_pressures(pnet, effort, pressure, actuators, every):
    """Write into ``pressure`` [Pa] the chamber (motor port) pressures of the actuators flagged in ``actuators``
    (all of them if ``every``) that carry ``effort`` [N | N·m] with rigid oil: the loaded side at p_ref + |effort|/A,
    the other at p_ref."""
    net = C._deref(pnet)
    ref = net.sc[C.S_PREF]
    cyl, ci, mi = net.cyl, net.cyl_i, net.mot_i
    for c in range(ci.shape[0]):
        a = ci[c, CI_ACT]
        if every or actuators[a]:
            pressure[ci[c, CI_CAP]] = ref + maximum(effort[a], 0.0) / cyl[c, C.CYL_CAP_AREA]
            pressure[ci[c, CI_ROD]] = ref + maximum(-effort[a], 0.0) / cyl[c, C.CYL_ROD_AREA]
    for i in range(mi.shape[0]):
        a = mi[i, MI_ACT]
        if every or actuators[a]:
            rate = net.mot[i] / (2.0 * np.pi)
            pressure[mi[i, MI_A]] = ref + maximum(effort[a], 0.0) / rate
            pressure[mi[i, MI_B]] = ref + maximum(-effort[a], 0.0) / rate


@kernel
def oil_from_pressure(pnet, pressure, x, geo, oil):
    """Oil content m = V(x, p)·φ(p) [m³] of every node into ``oil`` (NaN for fixed nodes); ``geo``: scratch (n)."""
    net = C._deref(pnet)
    C._geometric_volume(pnet, x, geo)
    for k in range(oil.size):
        if net.fixed[k]:
            oil[k] = math.nan
            continue
        extra, _ = C._node_extra(pnet, k, pressure[k])
        phi, _ = C._fill(pnet, pressure[k])
        oil[k] = (geo[k] + extra) * phi


@kernel
def incompressible_finish(pnet, const, slope, lower, upper, v_end, x_end, geo, effort, pressure, oil):
    """End of an incompressible step: the applied ``effort`` = clip(law(v⁺), lower, upper), the node pressures
    (fixed nodes at their pressure, chambers from the effort, others at p_ref) and the oil they hold at ``x_end``."""
    net = C._deref(pnet)
    for i in range(effort.size):
        effort[i] = clip(const[i] + slope[i] * v_end[i], lower[i], upper[i])
    ref = net.sc[C.S_PREF]
    for k in range(pressure.size):
        pressure[k] = net.node[k, C.NODE_FIXED_P] if net.fixed[k] else ref
    chamber_pressures(pnet, effort, pressure, effort, True)
    oil_from_pressure(pnet, pressure, x_end, geo, oil)


@kernel
def _incompressible_metering(pnet, T, a, spool, area):
    """Direction [-], inlet area A_in and the metered force (F_d, R) of incompressible actuator ``a`` (:func:`hydraulics.components.valve_4_3.metered_actuator_force`)."""
    net = C._deref(pnet)
    edges = T.edges
    supply_edge = edges[a, E_EXTEND_SUPPLY]
    direction = 0.0
    if supply_edge >= 0:
        valve = net.or_valve[supply_edge]
        direction = _valve.metering_direction(spool[valve], net.valve[valve, V_OVERLAP])
    extend = direction >= 0
    a_in = T.extend_area[a] if extend else T.retract_area[a]
    a_out = T.retract_area[a] if extend else T.extend_area[a]
    e_in = edges[a, E_EXTEND_SUPPLY] if extend else edges[a, E_RETRACT_SUPPLY]
    e_out = edges[a, E_EXTEND_RETURN] if extend else edges[a, E_RETRACT_RETURN]
    j_in = E_EXTEND_SUPPLY if extend else E_RETRACT_SUPPLY
    j_out = E_EXTEND_RETURN if extend else E_RETRACT_RETURN
    c_in = T.edge_cd[a, j_in] * area[e_in] if e_in >= 0 else 0.0
    c_out = T.edge_cd[a, j_out] * area[e_out] if e_out >= 0 else 0.0
    p_t = net.sc[C.S_PREF]
    drive, resist = _valve.metered_actuator_force(direction, a_in, a_out, c_in, c_out, T.scalars[IS_SUPPLY], p_t, T.scalars[IS_DENSITY], p_t)
    return direction, a_in, drive, resist


@kernel
def stroke_speeds(pnet, a, position, dt):
    """End-stop window (v_lo, v_hi) [m/s] of actuator ``a`` over a step of ``dt`` [s] from the start ``position``
    [m]: the end speeds v⁺ that keep x + dt·v⁺ inside [0, stroke]; (−inf, inf) for a motor."""
    net = C._deref(pnet)
    cyl, ci = net.cyl, net.cyl_i
    for c in range(ci.shape[0]):
        if ci[c, CI_ACT] == a:
            x = position[a]
            return -x / dt, (cyl[c, C.CYL_STROKE] - x) / dt
    return -math.inf, math.inf


@kernel
def end_stop_hold(pnet, T, a, state, effective_mass, dt, law, bounds):
    """The effort law of actuator ``a`` as MuJoCo mode applies it at an end stop: (const, slope, lower, upper).

    Where :func:`incompressible_law` made ``a`` a tracker of an end speed (its target clipped to
    v_hi = (stroke − x)/h or v_lo = −x/h of :func:`stroke_speeds`, so that the step ends at that end of the
    stroke), the end cap takes whatever force pushes the rod further: the bound on that side is dropped
    (−inf at the extended end, +inf at the retracted end) and the tracker keeps its full gain K = G·m_eff/h,
    so a load beyond the relief force (the ground pushing the curled bucket) is held at the end too; the other
    side keeps its hydraulic bound (a load pulling the rod off the end beyond it moves it).  Every other law is
    returned unchanged.  ``law`` = (const, slope) and ``bounds`` = (lower, upper) of the actuator as
    :func:`incompressible_law` wrote them, ``state`` = (start positions, start velocities).  The hydraulic effort
    (and so the chamber pressures) stays ``law`` clipped to ``bounds``; the difference is the end cap's reaction.
    A tracker's target is read back as −const/slope and counts as the end speed within ``END_SPEED_MATCH``
    (relative, at least that many m/s).  **Limitation**: a rod whose hydraulic target lies inside the stroke while a
    load beyond the relief force drives it to its end passes the end by at most one step's excess motion, then is
    pulled back to it in the next step."""
    position, velocity = state
    const, slope = law
    lower, upper = bounds
    if not slope < 0.0:
        return const, slope, lower, upper
    v_lo, v_hi = stroke_speeds(pnet, a, position, dt)
    if not math.isfinite(v_lo):
        return const, slope, lower, upper
    target = -const / slope
    gain = tracking_gain(T.scalars[IS_GAIN], effective_mass[a], dt)
    if abs(target - v_hi) <= END_SPEED_MATCH * maximum(1.0, abs(v_hi)):
        c, k = bounded_tracker(v_hi, velocity[a], gain, -math.inf, upper)
        return c, k, -math.inf, upper
    if abs(target - v_lo) <= END_SPEED_MATCH * maximum(1.0, abs(v_lo)):
        c, k = bounded_tracker(v_lo, velocity[a], gain, lower, math.inf)
        return c, k, lower, math.inf
    return const, slope, lower, upper


@kernel
def incompressible_law(pnet, T, spool, speed, state, effective_mass, dt, area, law, bounds):
    """The incompressible effort law of a step (CouplingIncompressible; see the module docstring) into ``law`` =
    (const, slope) (effort = const + slope·v⁺) and ``bounds`` = (lower, upper) [N | N·m], at the step's end spools
    ``spool``, pump speeds ``speed`` [rev/s], start ``state`` = (positions [m | rad], velocities) and effective
    masses (NaN or inf: unknown); ``area``: scratch (orifice branches)."""
    position, velocity = state
    const, slope = law
    lower, upper = bounds
    na = velocity.size
    edges = T.edges
    metered = False
    for a in range(na):
        for j in range(edges.shape[1]):
            if edges[a, j] >= 0:
                metered = True
    for a in range(na):
        lower[a], upper[a] = T.force_lower[a], T.force_upper[a]
    gain0 = T.scalars[IS_GAIN]
    if not metered:  # no metering valve reaches any actuator: rigid oil locks them all
        for a in range(na):
            const[a] = 0.0
            slope[a] = -tracking_gain(gain0, effective_mass[a], dt)
        return
    C._valve_areas(pnet, spool, area)
    demand = 0.0
    for a in range(na):
        direction, a_in, drive, resist = _incompressible_metering(pnet, T, a, spool, area)
        if direction != 0:
            demand += free_speed(drive, resist) * a_in
    supply = C._source_delivery(pnet, speed)
    scale = minimum(1.0, supply / demand) if demand > 0 else 1.0
    for a in range(na):
        direction, a_in, drive, resist = _incompressible_metering(pnet, T, a, spool, area)
        c, k = quadratic_damper(drive, resist, velocity[a])
        free = free_speed(drive, resist)
        # its share of the delivery as a speed: the free speed scaled with the others (exactly the free speed
        # when the pumps deliver enough, so that the pump limit below never engages on round-off)
        cap = free * scale if direction != 0 and a_in > 0 else 0.0
        # pump-limited (its share is slower than its valve would let it run unloaded): track the share speed with
        # at most the force the metering edges pass at the current speed, so a load the valve cannot carry at that
        # speed slows it to the valve's speed (a damper below the share would overshoot it within one step)
        pump_limited = direction != 0 and math.isfinite(resist) and cap < free
        track = direction == 0 or not math.isfinite(resist) or pump_limited or abs(velocity[a]) >= cap
        target = 0.0 if direction == 0 else direction * cap
        damper_now = c + k * velocity[a]  # F_d − R·v·|v| at the start speed
        if pump_limited and direction > 0:
            upper[a] = maximum(minimum(upper[a], damper_now), lower[a])
        if pump_limited and direction < 0:
            lower[a] = minimum(maximum(lower[a], damper_now), upper[a])
        # end stops: a cylinder that could reach an end of its stroke within the step tracks a target clipped to
        # the speeds that end the step inside [0, stroke], so rigid oil holds the rod at its end (within the bounds)
        v_lo, v_hi = stroke_speeds(pnet, a, position, dt)
        reach_up = STOP_REACH * maximum(maximum(velocity[a], target), 0.0)
        reach_down = STOP_REACH * maximum(maximum(-velocity[a], -target), 0.0)
        if v_hi <= reach_up or v_lo >= -reach_down:
            track = True
            target = clip(target, v_lo, v_hi)
        if track:
            c, k = bounded_tracker(target, velocity[a], tracking_gain(gain0, effective_mass[a], dt), lower[a], upper[a])
        const[a], slope[a] = c, k


@kernel
def mixed_law(pnet, R, spool0, command, velocity, effective_mass, dt, supply, law, bounds, scratch):
    """The law of CouplingMixed for its rigid actuators, written over the inner coupling's law ``law`` = (const,
    slope) (compressible actuators unchanged), with the bounds ``bounds`` = (lower, upper) [N | N·m].

    ``supply`` = (p_P [Pa], ∂p_P/∂v [Pa·s/m], v_g [m/s]) per rigid branch: the supply pressure at the
    linearisation's velocities v_g, its gradient with respect to the branch's own actuator velocity (zero for an
    explicit inner coupling).  ``spool0``, ``command``: start spools and commands (the law takes the end spools);
    ``scratch``: :data:`MIXED_LAW_SCRATCH`."""
    net = C._deref(pnet)
    const, slope = law
    lower, upper = bounds
    p_supply, dp_dv, v_guess = supply
    na = velocity.size
    ws, _ = _mixed_law_scratch(scratch, 0, na)
    friction, fslope, target, tracking = ws.friction, ws.fslope, ws.target, ws.tracking
    for a in range(na):
        lower[a], upper[a] = R.force_lower[a], R.force_upper[a]
        tracking[a] = 1.0 if R.rigid[a] else 0.0
        target[a] = 0.0
    C._friction_effort(pnet, velocity[:0], velocity[:0], velocity, friction, fslope)  # (rigid: no seal load, no cushion)
    rho, pref, floor, top = R.scalars[RS_DENSITY], net.sc[C.S_PREF], net.sc[C.S_FLOOR], R.scalars[RS_TOP]
    for k in range(R.actuator.size):
        a, valve = R.actuator[k], R.valve[k]
        overlap = net.valve[valve, V_OVERLAP]
        r = net.valve_rate[valve]
        s = _valve.valve_step(net.valve[valve], spool0[valve], spool0[r] if r >= 0 else 0.0,
                              clip(command[valve], -1.0, 1.0), dt)[0]
        direction = _valve.metering_direction(R.sign[k] * s, overlap)
        extend = direction >= 0
        a_in = R.extend_area[k] if extend else R.retract_area[k]
        a_out = R.retract_area[k] if extend else R.extend_area[k]
        edge = R.cd[k] * (R.base_area[k] + R.max_area[k] * _valve.metering_opening(abs(s), overlap))
        p_tank = net.node[R.tank[k], C.NODE_FIXED_P]
        drive, resist = _valve.metered_actuator_force(direction, a_in, a_out, edge, edge, p_supply[k], p_tank, rho, pref)
        c, kk = quadratic_damper(drive, resist, velocity[a])
        # live supply: + d·A_in·∂p_P/∂v·(v⁺ − v_g), a (negative) stiffness of the supply's oil column
        supply_slope = direction * a_in * dp_dv[k]
        fs = minimum(fslope[a], 0.0)
        c = c - supply_slope * v_guess[k] + friction[a] - fs * velocity[a]
        kk = kk + supply_slope + fs
        # beyond its free speed (e.g. a spool just past its overlap) the actuator tracks that speed
        free = free_speed(drive, resist)
        damper = direction != 0 and math.isfinite(resist) and abs(velocity[a]) < free
        const[a], slope[a] = (c, kk) if damper else (0.0, 0.0)
        tracking[a] = 0.0 if damper else 1.0
        if direction != 0:  # direction·nan_to_num(free)
            target[a] = direction * (0.0 if free != free else (free if free < np.inf else 1.7976931348623157e308))
        else:
            target[a] = 0.0
        if damper:  # an open valve: the force the supply can give, F at p_P in [cavitation floor, highest relief]
            low_end = _valve.metered_actuator_force(direction, a_in, a_out, edge, edge, floor, p_tank, rho, pref)[0]
            high_end = _valve.metered_actuator_force(direction, a_in, a_out, edge, edge, top, p_tank, rho, pref)[0]
            offset = c + kk * velocity[a] - drive  # damper and friction at the start velocity
            lower[a] = minimum(low_end, high_end) + offset
            upper[a] = maximum(low_end, high_end) + offset
    gain0 = R.scalars[RS_GAIN]
    for a in range(na):
        if tracking[a] != 0.0:
            const[a], slope[a] = bounded_tracker(target[a], velocity[a], tracking_gain(gain0, effective_mass[a], dt),
                                                 lower[a], upper[a])


# ----------------------------------------------------------------------------
# The coupled steps' pieces (the plants' compiled steps call these between their own motion updates)
# ----------------------------------------------------------------------------
@kernel
def explicit_law(pnet, pressure, position, velocity, law, scratch):
    """CouplingExplicit.begin: the effort of the start ``pressure`` [Pa] plus the seal friction and end cushions at
    the start ``position`` and ``velocity`` into ``law`` = (const, slope), slope 0 (the effort is held over the
    step); ``scratch``: :data:`EXPLICIT_LAW_SCRATCH`."""
    const, slope = law
    na = velocity.size
    ws, _ = _explicit_law_scratch(scratch, 0, na)
    friction, damping = ws.friction, ws.damping
    C._pressure_effort(pnet, pressure, const)
    C._friction_effort(pnet, pressure, position, velocity, friction, damping)
    for a in range(na):
        const[a] += friction[a]
        slope[a] = 0.0


@kernel
def explicit_finish(pnet, W, state, flow, v_start, control, dt, substeps, out):
    """CouplingExplicit.finish: ``substeps`` forward-Euler substeps of dt/substeps [s] from the network's own
    actuator positions with the start velocities ``v_start`` held (``ActuatorMotion.linear``), committed substep by
    substep into ``state`` = (oil, pressures, spools, positions, velocities) while the pressures stay finite.
    ``control`` = (valve commands, pump speeds); ``flow``: the last substep's branch flows [m³/s]; ``out`` = (end
    oil, pressures, spools, flows, their derivatives, counters, and three actuator scratch arrays).  Returns (the
    first node whose pressure is not finite or −1, right-hand sides evaluated)."""
    oil, pres, spool, pos, vel = state
    o2, p2, sp2, fl, dfl, istats, x_start, xb, xe = out
    h = dt / substeps
    C._copy(x_start, pos)
    for s in range(substeps):
        for i in range(x_start.size):  # ActuatorMotion.at(s/S), at((s+1)/S) of x → x + dt·v
            x_end = x_start[i] + dt * v_start[i]
            xb[i] = x_start[i] + (s / substeps) * (x_end - x_start[i]) if substeps > 1 else x_start[i]
            xe[i] = x_start[i] + ((s + 1) / substeps) * (x_end - x_start[i]) if substeps > 1 else x_end
        explicit_substep(pnet, W, C.StepStart(oil, spool, control[0], control[1], xb, v_start), xe, h,
                         C.StepOut(o2, p2, sp2, fl, dfl, istats))
        C._copy(flow, fl)
        bad = C._commit_if_finite(oil, pres, spool, pos, vel, o2, p2, sp2, xe, v_start)
        if bad >= 0:
            return bad, s + 1
    return -1, substeps


@kernel
def rigid_law(pnet, R, spool0, command, velocity, effective_mass, dt, lin, implicit, law, bounds, theta, W):
    """CouplingMixed.begin around the inner coupling's law ``law`` = (const, slope): the rigid actuators' law
    (:func:`mixed_law`) written over it, ``bounds`` = (lower, upper) [N | N·m] and θ = 1 on the rigid actuators.

    ``lin`` = (pressures [Pa], oil [m³], positions [m | rad], ∂m⁺/∂v, velocities [m/s | rad/s]) of the inner
    coupling's linearisation: with ``implicit`` the supply pressure p_P is its end pressure, with the gradient
    ∂p_P/∂v = (∂p/∂m)·(∂m⁺/∂v) at its oil and positions, about its velocities; otherwise (the explicit coupling)
    the start pressure, held (the other members are not read).  ``W``: scratch (:data:`RIGID_LAW_SCRATCH`)."""
    nr, n, na = R.actuator.size, lin[0].size, velocity.size
    ws, _ = _rigid_law_scratch(W, 0, nr, n, _mixed_law_scratch_size(na))
    p_supply, gradient, v_guess, geo, p, dpdm = ws.p_supply, ws.gradient, ws.v_guess, ws.geo, ws.p, ws.dpdm
    pressure, oil, position, doil, guess = lin
    if implicit:
        C._pressure(pnet, oil, position, geo, p, dpdm)
    for k in range(nr):
        node, a = R.supply[k], R.actuator[k]
        p_supply[k] = pressure[node]
        gradient[k] = dpdm[node] * doil[node, a] if implicit else 0.0
        v_guess[k] = guess[a] if implicit else 0.0
    mixed_law(pnet, R, spool0, command, velocity, effective_mass, dt, (p_supply, gradient, v_guess), law, bounds,
              ws.mixed)
    for a in range(na):
        if R.rigid[a]:
            theta[a] = 1.0


@kernel
def rigid_finish(pnet, R, law, bounds, v_end, pressure, scratch):
    """CouplingMixed.finish after a successful inner finish: the rigid actuators' chamber pressures [Pa] carry the
    applied effort clip(const + slope·v⁺, lower, upper) less the seal friction at ``v_end``; ``scratch``:
    :data:`RIGID_FINISH_SCRATCH`."""
    const, slope = law
    lower, upper = bounds
    na = v_end.size
    ws, _ = _rigid_finish_scratch(scratch, 0, na)
    friction, fslope, hydraulic = ws.friction, ws.fslope, ws.hydraulic
    C._friction_effort(pnet, v_end[:0], v_end[:0], v_end, friction, fslope)  # (rigid: no seal load, no cushion)
    for a in range(na):
        hydraulic[a] = clip(const[a] + slope[a] * v_end[a], lower[a], upper[a]) - friction[a]
    chamber_pressures(pnet, hydraulic, pressure, R.rigid, False)


@kernel
def rigid_account(pnet, R, ledger, at, h, flow, potential, effort, friction, velocity):
    """PlantBase._account's rigid term over a step ``h`` [s]: what the rigid branches deliver (flow × the drop of
    ``potential``, the node potentials :func:`hydraulics._compiled._account` leaves) is motor work ``ledger[at + 1]``,
    and less the work of the rigid actuators' hydraulic force (``effort`` − ``friction``)·``velocity`` it is
    hydraulic dissipation ``ledger[at + 2]`` [J]."""
    nr = R.actuator.size
    br = C._deref(pnet).br
    nb = flow.size
    delivered = 0.0
    for j in range(nr):
        b = nb - nr + j
        delivered += flow[b] * (potential[br[b, 0]] - potential[br[b, 1]])
    if delivered == 0.0:
        return
    work = 0.0
    for a in range(velocity.size):
        if R.rigid[a]:
            work += (effort[a] - friction[a]) * velocity[a]
    ledger[at + 1] += h * delivered
    ledger[at + 2] += h * (delivered - work)


# ----------------------------------------------------------------------------
# Entry points called from Python (allocate their outputs), cached on disk under the sources' fingerprint
# ----------------------------------------------------------------------------
@C._jit
def _explicit_step_python(F, I, start, x_end, h):
    net = C._unpack(F, I)
    pnet = C._ref(net)
    n, nb = net.ic[C.IC_N], net.ic[C.IC_NB]
    W = np.empty(explicit_work_size(net.ic))
    oil, p, spool, flow = np.empty(n), np.empty(n), np.empty(start[1].size), np.empty(nb)
    dflow = np.empty((nb, C._W_BR))
    istats = np.zeros(C.NIS, np.int64)
    explicit_substep(pnet, W, start, x_end, h, C.StepOut(oil, p, spool, flow, dflow, istats))
    return oil, p, spool, flow


@C._jit
def _incompressible_law_python(F, I, T, spool0, command, speed, position, velocity, effective_mass, dt):
    net = C._unpack(F, I)
    pnet = C._ref(net)
    na = velocity.size
    const, slope, lower, upper = np.empty(na), np.empty(na), np.empty(na), np.empty(na)
    area, spool = np.empty(C._area_count(net.ic)), np.empty(spool0.size)
    C._spool_end(pnet, spool0, command, dt, spool)
    incompressible_law(pnet, T, spool, speed, (position, velocity), effective_mass, dt, area, (const, slope),
                       (lower, upper))
    return spool, const, slope, lower, upper


@C._jit
def _end_stop_hold_python(F, I, T, position, velocity, effective_mass, dt, const, slope, lower, upper):
    net = C._unpack(F, I)
    pnet = C._ref(net)
    na = velocity.size
    c, k, lo, hi = np.empty(na), np.empty(na), np.empty(na), np.empty(na)
    for a in range(na):
        c[a], k[a], lo[a], hi[a] = end_stop_hold(pnet, T, a, (position, velocity), effective_mass, dt,
                                                 (const[a], slope[a]), (lower[a], upper[a]))
    return c, k, lo, hi


@C._jit
def _mixed_law_python(F, I, R, spool0, command, velocity, effective_mass, dt, supply, const, slope):
    net = C._unpack(F, I)
    pnet = C._ref(net)
    na = velocity.size
    lower, upper = np.empty(na), np.empty(na)
    mixed_law(pnet, R, spool0, command, velocity, effective_mass, dt, supply, (const, slope), (lower, upper),
              np.empty(4 * na))
    return const, slope, lower, upper


@C._jit
def _incompressible_finish_python(F, I, const, slope, lower, upper, v_end, x_end):
    net = C._unpack(F, I)
    pnet = C._ref(net)
    n, na = net.ic[C.IC_N], v_end.size
    effort, pressure, oil = np.empty(na), np.empty(n), np.empty(n)
    incompressible_finish(pnet, const, slope, lower, upper, v_end, x_end, np.empty(n), effort, pressure, oil)
    return effort, pressure, oil


@C._jit
def _chamber_pressures_python(F, I, effort, pressure, actuators):
    net = C._unpack(F, I)
    chamber_pressures(C._ref(net), effort, pressure, actuators, False)


def _cached(fingerprint):
    """The entry points above behind numba's disk cache, keyed (through the closure variable ``fingerprint``,
    :data:`hydraulics._jit.FINGERPRINT`) by every kernel source they compile in."""

    def explicit_step(F, I, start, x_end, h):
        if fingerprint is None:  # never: only makes the fingerprint a closure variable (numba's cache key)
            raise ValueError("no fingerprint")
        return _explicit_step_python(F, I, start, x_end, h)

    def incompressible_law_entry(F, I, T, spool0, command, speed, position, velocity, effective_mass, dt):
        if fingerprint is None:  # never (see explicit_step)
            raise ValueError("no fingerprint")
        return _incompressible_law_python(F, I, T, spool0, command, speed, position, velocity, effective_mass, dt)

    def end_stop_hold_entry(F, I, T, position, velocity, effective_mass, dt, const, slope, lower, upper):
        if fingerprint is None:  # never (see explicit_step)
            raise ValueError("no fingerprint")
        return _end_stop_hold_python(F, I, T, position, velocity, effective_mass, dt, const, slope, lower, upper)

    def mixed_law_entry(F, I, R, spool0, command, velocity, effective_mass, dt, supply, const, slope):
        if fingerprint is None:  # never (see explicit_step)
            raise ValueError("no fingerprint")
        return _mixed_law_python(F, I, R, spool0, command, velocity, effective_mass, dt, supply, const, slope)

    def incompressible_finish_entry(F, I, const, slope, lower, upper, v_end, x_end):
        if fingerprint is None:  # never (see explicit_step)
            raise ValueError("no fingerprint")
        return _incompressible_finish_python(F, I, const, slope, lower, upper, v_end, x_end)

    def chamber_pressures_entry(F, I, effort, pressure, actuators):
        if fingerprint is None:  # never (see explicit_step)
            raise ValueError("no fingerprint")
        _chamber_pressures_python(F, I, effort, pressure, actuators)

    entries = (explicit_step, incompressible_law_entry, mixed_law_entry, incompressible_finish_entry,
               chamber_pressures_entry, end_stop_hold_entry)
    if not C.JIT_ENABLED:  # NUMBA_DISABLE_JIT=1: plain Python
        return entries
    return tuple(C._numba_cached(f) for f in entries)


(explicit_step_entry, incompressible_law_entry, mixed_law_entry, incompressible_finish_entry,
 chamber_pressures_entry, end_stop_hold_entry) = _cached(FINGERPRINT)

__all__ = ["IncompressibleTable", "RigidTable", "pack_incompressible", "pack_rigid",
           "flatten_incompressible", "unflatten_incompressible", "flatten_rigid", "unflatten_rigid", "explicit_substep",
           "incompressible_law", "mixed_law", "chamber_pressures", "incompressible_finish", "explicit_law",
           "explicit_finish", "rigid_law", "rigid_finish", "rigid_account",
           "quadratic_damper", "bounded_tracker", "free_speed", "tracking_gain", "stroke_speeds", "end_stop_hold"]
