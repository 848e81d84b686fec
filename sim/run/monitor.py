"""Plausibility monitor of a run: physical bounds a correct simulation never leaves.

A run can stay finite and still be wrong: a cylinder pushed through its end
stop, a circuit without a relief valve pumping its chambers to thousands of
bar, a start velocity that hands the machine more energy than the pumps ever
deliver, a loop closure pulled apart, a leftover MJCF actuator braking the
machine.  :class:`RunMonitor` checks, against bounds stated below as named
constants with units:

stroke
    every cylinder's rod extension x [m] within [−tol, stroke + tol], with
    tol = max(``STROKE_TOLERANCE``, ``STROKE_TOLERANCE_FRACTION``·stroke): the end
    stops (MJCF tendon limits) are soft and give a little, never a tenth of the stroke.
pressure
    every free node's absolute pressure p [Pa] within [p_low, p_high], at every
    fidelity level (at the ``incompressible`` level the pressures derived from the efforts):
    p_low = ``PRESSURE_FLOOR_FACTOR``·p_cavitation (the network floors its
    pressures at the cavitation pressure; no lower bound without cavitation), and
    p_high = ``PRESSURE_BOUND_FACTOR``·(1 + ``RELIEF_OVERRIDE_FRACTION``)·Δp_crack,max + p_ref,
    with Δp_crack,max the highest relief cracking pressure of the circuit and p_ref
    its reference (ambient) pressure.  The factor covers what a correct run can
    reach above the relief setting: intensification in a differential cylinder whose
    annulus is blocked (p_rod = p_cap·A_cap/A_rod, area ratios up to ≈ 2) and
    load-induced peaks behind a closed valve.  A circuit without a relief valve
    gets the absolute bound ``NO_RELIEF_PRESSURE_LIMIT``.  A start pressure the
    scenario states (``[initial] pressures``) raises p_high to
    ``PRESSURE_BOUND_FACTOR`` times the highest of them when that is more (the
    closed-cylinder benchmark starts its oil at 22 kbar on purpose), and so does a
    pressure source (a fixed node off the reference pressure, :func:`pressure_sources`).
energy residual
    |residual| ≤ ``ENERGY_RESIDUAL_FRACTION``·T + E_floor, with
    E_floor = max(``ENERGY_RESIDUAL_FLOOR``, ``ENERGY_RESIDUAL_FLOOR_PER_KG``·m_moving)
    (m_moving: the MJCF bodies not welded to the world),
    where residual = W − ΔE_stored − E_dissipated (:class:`sim.plants.base.EnergyLedger`),
    W the supplied work (pumps and pressure sources), ΔE_stored the change of kinetic +
    potential + oil energy since t = 0, and T the energy turnover: Σ over the logged
    samples so far of |δW| + |δE_stored| between one sample and the next.  T is at
    least W + |ΔE_stored| and grows with the work each step moves, also where it only
    swings between the load and the oil (a load bouncing on its oil column, whose
    backward-Euler damping is a residual of about the energy exchanged per step once
    the step is longer than the column's period, ω·dt ≳ 1): the bound follows the
    step's work.  Energy lost (residual > 0) may be the larger fraction
    :func:`energy_loss_fraction` max(0.5, min(1, dt/``ENERGY_LOSS_TIME``)) of T: a step
    as long as a soft constraint's time constant removes what the constraint exchanges
    within it (the bucket hitting the ground at a 30 Hz frame stops within one step,
    an inelastic impact no modelled loss meters), so the bound scales with dt; energy
    made (residual < 0) stays within 0.5·T at every dt.  An unaccounted force (a leftover MJCF velocity actuator
    acting as a brake) or an unstable coupling shows up here.  Checked at every
    fidelity: at the ``incompressible`` level W is the work of the forces the plant
    applied to the actuators (the oil stores nothing), so the residual is the bodies'
    integration error against those forces.  Not checked where the ledger is no
    balance (:func:`energy_unmetered`, the reason kept as ``energy_off``): with rigid
    actuators in a compressible network (their trackers brake without metering what
    they take).  A fixed node at a pressure other than the reference (a
    ``pressure_source``) is metered: its work μ(p)·(net outflow) is supplied work
    with the pumps' (:func:`hydraulics.energy.source_power`).
equality constraints
    MuJoCo mode: the length of each equality constraint's gap vector, its rows of
    ``efc_pos`` taken together (loop closures: ``connect``, ``weld``, ``joint``)
    [m or rad] (:class:`ConstraintErrors`); PBD mode: the XPBD
    solver's own pin errors |p₂ − p₁| [m] of its hinge joints and its connect /
    weld equalities; each within ``EQUALITY_TOLERANCE``.
joint range
    every limited hinge [rad] or slide [m] within its MJCF range widened by
    ``JOINT_RANGE_TOLERANCE_HINGE`` for a hinge and, for a slide, by the stroke's
    rule applied to its range width (:func:`end_stop_tolerance`: a cylinder's slide and
    its tendon are the same soft end stop).

Where the checks run (the runner's :class:`sim.run.runner._Loop`), so that the
compiled fast paths pay no Python call per step:

* pressure and stroke: per step on the per-step paths (:meth:`RunMonitor.check_state`);
  per block on the block paths from the per-step extremes the plants keep in their
  compiled loops (``node_pressure_max``/``node_pressure_min``,
  ``actuator_position_max``/``actuator_position_min``: :meth:`RunMonitor.extremes_within`);
  a block whose extremes leave a bound is replayed step by step to name the step;
* energy residual, joint range and stroke: per logged sample, on each batch the
  recorder derives (:meth:`RunMonitor.check_batch`);
* equality constraints: per logged sample on the per-step paths, per block end on
  the block paths (:meth:`RunMonitor.check_constraints`; MuJoCo's ``efc_pos`` of the
  block's last step, so no extra MuJoCo call).

A violation is a :class:`Violation` whose :attr:`~Violation.message` is one line:
the time, the component (its circuit or MJCF name), the quantity, its value and
its bound.  With ``enforce`` (the default) the runner stops the run there (exit
status 3; the log is finished and marked ``diverged`` with ``check =
"plausibility"``); ``enforce=False`` (``hydroplant run --no-monitor``, scenario
``[monitor] enabled = false``) logs each new violation as a warning event and
lets the run go on.

Example::

    monitor = RunMonitor(plant)
    bad = monitor.check_state(plant.time, plant.net_state.node_pressure, plant.net_state.actuator_position)
    if bad is not None:
        print(bad.message)

Limitations: the pressure bound is one number for the whole circuit (the highest
relief), not per relief-protected node; on the block paths joint ranges and the
energy residual are checked at the logged samples only (a transient between two
samples is not seen); MuJoCo's equality violation is read at the start of a
block's last step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

# Stroke: tolerance beyond either end [m], at least this much ...
STROKE_TOLERANCE = 0.01  # [m]
# ... or this fraction of the stroke when that is more [-] (the end stops are soft: the excavator's dig at 1 kHz
# goes 0.2 % past the bucket cylinder's stroke; at a 30 Hz frame the incompressible level holds it within 0.03 %)
STROKE_TOLERANCE_FRACTION = 0.05  # [-]
# Pressure: a relief valve's pressure rise above its cracking pressure at full flow, as a fraction of it [-]
RELIEF_OVERRIDE_FRACTION = 0.1  # [-] (direct-acting reliefs: 5-15 %)
# Pressure: factor on the highest relief setting + override [-] (intensification, load-induced peaks; see module docstring)
PRESSURE_BOUND_FACTOR = 2.0  # [-]
# Pressure: upper bound of a circuit with no relief valve [Pa absolute]
NO_RELIEF_PRESSURE_LIMIT = 5.0e7  # [Pa] (500 bar, above the rating of mobile hydraulic components)
# Pressure: lower bound as a fraction of the cavitation pressure [-]
PRESSURE_FLOOR_FACTOR = 0.5  # [-]
# Energy residual: fraction of the energy turnover Σ |δW| + |δE_stored| over the logged samples [-] ...
ENERGY_RESIDUAL_FRACTION = 0.5  # [-]
# ... plus a floor, so that round-off and the ledger's transients at a throughput near zero are not flagged: this
# much per kg of the machine's moving mass (about the work of lifting it by 1 cm) [J/kg], at least ENERGY_RESIDUAL_FLOOR
ENERGY_RESIDUAL_FLOOR_PER_KG = 0.1  # [J/kg]
ENERGY_RESIDUAL_FLOOR = 10.0  # [J]
# Energy residual, loss side: a step this long or longer may lose all the energy turnover it moves (MuJoCo's default
# soft-constraint time constant, solref 0.02 s: a contact impact within one such step is perfectly inelastic) [s]
ENERGY_LOSS_TIME = 0.02  # [s]
# Equality constraints: largest violation [m for positions, rad for rotations]
EQUALITY_TOLERANCE = 0.01  # [m | rad]
# Joint range: tolerance beyond a limited hinge's range [rad] and a limited slide's range [m] (MJCF limits are soft:
# the excavator's dig at 1 kHz goes 0.007 rad past its bucket's range; at a 30 Hz frame, where MuJoCo's soft limits
# have a time constant of at least 2·dt, the incompressible level's end stops hold the bucket within 0.4 mrad of it)
JOINT_RANGE_TOLERANCE_HINGE = 0.05  # [rad] (≈ 2.9°)

PA_PER_BAR = 1e5
# Pressure: a fixed node (a tank, a pressure_source) whose pressure differs from the reference pressure by more than
# this is a pressure source: its pressure enters the pressure bound (its work is supplied work in the ledger) [Pa]
SOURCE_PRESSURE_TOLERANCE = 1.0e3  # [Pa]


def end_stop_tolerance(travel):
    """How far past an end stop a right run may go [m]:
    max(``STROKE_TOLERANCE``, ``STROKE_TOLERANCE_FRACTION``·travel), for a cylinder's stroke and a limited slide
    joint's range width [m] alike (the same soft end stop, seen on the tendon or on the joint)."""
    return np.maximum(STROKE_TOLERANCE, STROKE_TOLERANCE_FRACTION * np.asarray(travel, float))


def energy_loss_fraction(dt: float) -> float:
    """Fraction of the energy turnover a right run may lose to the scheme in steps of ``dt`` [s]:
    max(``ENERGY_RESIDUAL_FRACTION``, min(1, dt/``ENERGY_LOSS_TIME``)).  A backward-Euler step removes the energy a
    soft constraint or an oil column exchanges within it once the step reaches the constraint's time constant (an
    impact on a contact at a 30 Hz frame is perfectly inelastic); energy made is never allowed more than
    ``ENERGY_RESIDUAL_FRACTION`` of the turnover."""
    return max(ENERGY_RESIDUAL_FRACTION, min(1.0, float(dt) / ENERGY_LOSS_TIME))


def pressure_sources(plant) -> list[str]:
    """Names of the fixed nodes whose pressure differs from the reference pressure by more than
    ``SOURCE_PRESSURE_TOLERANCE`` (pressure sources: their work is supplied work in the ledger, and a free node may
    reach their pressure)."""
    net = plant.network
    fixed = np.flatnonzero(np.asarray(net.node_fixed, bool) & ~_rigid_chambers(net))
    pressure = np.asarray(plant.net_state.node_pressure, float)[fixed]
    return [str(net.node_names[i]) for i, p in zip(fixed, pressure)
            if abs(p - net.fluid.reference_pressure) > SOURCE_PRESSURE_TOLERANCE]


def _rigid_chambers(net) -> np.ndarray:
    """Mask of the nodes that are chambers of rigid actuators (fixed nodes of the packed network, not sources)."""
    mask = np.zeros(net.node_count, bool)
    rigid = np.asarray(net.actuator_rigid, bool)
    if rigid.any():
        for i, a in enumerate(np.asarray(net.cylinder_actuator, int)):
            if rigid[a]:
                mask[[int(net.cylinder_cap_node[i]), int(net.cylinder_rod_node[i])]] = True
    return mask


def energy_unmetered(plant) -> str:
    """Why the energy residual of ``plant``'s run is not checked ("" when it is).

    The ledger (:class:`sim.plants.base.EnergyLedger`) meters the work of pumps, the stored oil energy of the free
    nodes and the branch losses; at the ``incompressible`` level the work the rigid oil does on the actuators
    (Σ effort·v·h) is the supplied work, so the residual checks the bodies' integration against the applied efforts.
    It is not a balance when rigid actuators sit in a compressible network: their trackers take kinetic energy
    unmetered (the energy-growth check still covers them).

    A fixed node at a pressure other than the reference (a ``pressure_source``, a tank set off the reference) is
    metered: its work μ(p)·(net outflow) counts as supplied work (:func:`hydraulics.energy.source_power`).
    """
    net = plant.network
    incompressible = net.fidelity == "incompressible" or getattr(plant.coupling, "name", "") == "incompressible"
    if not incompressible and np.any(np.asarray(net.actuator_rigid, bool)):
        return "rigid actuators take kinetic energy through their trackers unmetered"
    return ""


@dataclass(frozen=True)
class Violation:
    """One bound left: where, what, how far."""

    time: float
    """Simulated time [s] of the step (or logged sample, or block end) where it was found."""
    component: str
    """``node 'name'``, ``cylinder 'name'``, ``joint 'name'``, ``equality 'name'`` or ``energy balance``."""
    quantity: str
    """``pressure``, ``stroke``, ``position``, ``violation`` or ``residual``."""
    value: float
    """The value found, SI units (Pa, m, rad, J)."""
    bound: float
    """The bound it left, same units."""
    text: str
    """Value and bound in readable units, with the bound's basis."""
    key: tuple = ()
    """(component, quantity, side): one warning per key when the monitor only warns."""

    @property
    def message(self) -> str:
        """One line: time, component, quantity, value, bound."""
        return f"t = {self.time:.6g} s, {self.component}: {self.quantity} {self.text}"


def _bar(p: float) -> str:
    return f"{p / PA_PER_BAR:.6g} bar"


class RunMonitor:
    """Bounds of one plant (MuJoCo or PBD) and the checks against them (see module docstring).

    Parameters
    ----------
    plant : sim.plants.mujoco.MujocoPlant or sim.plants.pbd.PbdPlant
        A freshly built plant (its network, its MjModel, its scalar joints).
    enforce : bool
        True: a violation stops the run; False: it is logged as a warning and the run goes on.

    Attributes
    ----------
    pressure_high, pressure_low : ndarray, shape (node_count,)
        Per-node bounds [Pa]; ±inf on fixed nodes (tank) and, for rigid actuators, on their derived chamber nodes.
    stroke_high, stroke_low : ndarray, shape (actuator_count,)
        Per-actuator bounds on the coordinate [m]; ±inf for motors.
    """

    def __init__(self, plant, *, enforce: bool = True):
        self.plant = plant
        self.enforce = bool(enforce)
        self.warned: set = set()
        self.new_warning: Violation | None = None  # set by accept()
        net = plant.network
        self.network = net
        fluid = net.fluid
        free = ~np.asarray(net.node_fixed, bool)  # (at the incompressible level too: pressures derived from the efforts)
        relief = np.asarray(net.relief_cracking, float)
        if len(relief):
            worst = int(np.argmax(relief))
            s = net.relief_branches
            name = net.branch_names[s.start + worst]
            high = PRESSURE_BOUND_FACTOR * (1.0 + RELIEF_OVERRIDE_FRACTION) * float(relief[worst]) + fluid.reference_pressure
            self.pressure_basis = (f"{PRESSURE_BOUND_FACTOR:g} x (highest relief setting, '{name}' {_bar(float(relief[worst]))}, "
                                   f"+ {RELIEF_OVERRIDE_FRACTION:.0%} override) + ambient")
        else:
            high = NO_RELIEF_PRESSURE_LIMIT
            self.pressure_basis = "the bound of a circuit with no relief valve"
        given = [float(v) for v in plant.scene.scenario.pressures.values()]
        if given and PRESSURE_BOUND_FACTOR * max(given) > high:  # a start pressure the scenario states raises it
            high = PRESSURE_BOUND_FACTOR * max(given)
            self.pressure_basis = f"{PRESSURE_BOUND_FACTOR:g} x the highest start pressure of the scenario's initial.pressures"
        self.sources = pressure_sources(plant)
        if self.sources:  # a pressure source: a free node may reach its pressure (no relief protects against it)
            source = {str(name): float(p) for name, p, fixed in zip(net.node_names, plant.net_state.node_pressure,
                                                                    net.node_fixed) if fixed}
            name = max(self.sources, key=source.get)
            if PRESSURE_BOUND_FACTOR * source[name] > high:
                high = PRESSURE_BOUND_FACTOR * source[name]
                self.pressure_basis = f"{PRESSURE_BOUND_FACTOR:g} x the highest pressure source, '{name}' {_bar(source[name])}"
        floor = fluid.pressure_floor
        low = PRESSURE_FLOOR_FACTOR * floor if math.isfinite(floor) else -math.inf
        self.pressure_high = np.where(free, high, np.inf)
        self.pressure_low = np.where(free, low, -np.inf)
        self.floor_basis = f"{PRESSURE_FLOOR_FACTOR:g} x the cavitation pressure {floor:g} Pa"
        na = net.actuator_count
        self.stroke_high, self.stroke_low = np.full(na, np.inf), np.full(na, -np.inf)
        cyl = np.asarray(net.cylinder_actuator, int)
        stroke = np.asarray(net.cylinder_stroke, float)
        tolerance = end_stop_tolerance(stroke)
        self.stroke_low[cyl] = -tolerance
        self.stroke_high[cyl] = stroke + tolerance
        self.stroke = np.zeros(na)
        self.stroke[cyl] = stroke
        # limited scalar joints, in the plant's joint order (plant.joint_names, plant.scalar_joints)
        m = plant.model
        joints = np.asarray(plant.scalar_joints, int)
        limited = np.array([bool(m.jnt_limited[j]) for j in joints], bool) if len(joints) else np.zeros(0, bool)
        hinge = np.array([int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE) for j in joints], bool)
        rng = np.array(m.jnt_range[joints]) if len(joints) else np.zeros((0, 2))
        tol = np.where(hinge, JOINT_RANGE_TOLERANCE_HINGE, end_stop_tolerance(rng[:, 1] - rng[:, 0]))
        self.joint_low = np.where(limited, rng[:, 0] - tol, -np.inf) if len(joints) else np.zeros(0)
        self.joint_high = np.where(limited, rng[:, 1] + tol, np.inf) if len(joints) else np.zeros(0)
        self.joint_range = rng
        self.joint_unit = np.where(hinge, "rad", "m")
        self.checks_joints = bool(np.any(limited))
        self.energy_off = energy_unmetered(plant)  # why the residual is not checked ("" when it is)
        self.energy = not self.energy_off
        moving = float(np.sum(np.asarray(m.body_mass)[np.asarray(m.body_weldid) != 0]))
        self.energy_floor = max(ENERGY_RESIDUAL_FLOOR, ENERGY_RESIDUAL_FLOOR_PER_KG * moving)  # [J]
        self._turnover, self._last = 0.0, (0.0, 0.0)  # energy turnover so far [J]; (supplied work, Δ stored) last checked
        self._constraints = ConstraintErrors(plant)

    # ------------------------------------------------------------ verdicts
    def accept(self, violation: Violation | None) -> bool:
        """True when the run may go on: no violation, or the monitor only warns (then ``new_warning`` is set
        for a violation whose key was not warned about before)."""
        self.new_warning = None
        if violation is None:
            return True
        if self.enforce:
            return False
        if violation.key not in self.warned:
            self.warned.add(violation.key)
            self.new_warning = violation
        return True

    # ---------------------------------------------------------------- checks
    def check_start(self, plant) -> Violation | None:
        """The energy at t = 0 must be finite: a start velocity of 1e300 rad/s gives an infinite kinetic energy
        (and every later energy term NaN); names the scalar joint with the largest start speed."""
        total = plant.energy.initial_total
        if math.isfinite(total):
            return None
        _, qd = plant.joint_state()
        i = int(np.nanargmax(np.where(np.isnan(qd), np.inf, np.abs(qd)))) if len(qd) else -1
        name = f"joint '{plant.joint_names[i]}'" if i >= 0 else "initial state"
        speed = f" (start speed {qd[i]:.4g} rad/s or m/s)" if i >= 0 else ""
        return Violation(plant.time, name, "start energy", total, math.inf,
                         f"{total} J is not finite{speed}: check the scenario's initial.qvel", (name, "start energy", ""))

    def check_state(self, time: float, pressure, position) -> Violation | None:
        """Pressures [Pa] and actuator coordinates [m | rad] of one instant against their bounds."""
        if (pressure > self.pressure_high).any() or (pressure < self.pressure_low).any():
            return self._pressure(time, pressure, pressure)
        if (position > self.stroke_high).any() or (position < self.stroke_low).any():
            return self._stroke(time, position, position)
        return None

    def extremes_within(self, plant) -> bool:
        """Whether the per-step extremes the plant keeps (pressures, actuator coordinates) are all within bounds."""
        return not ((plant.node_pressure_max > self.pressure_high).any() or (plant.node_pressure_min < self.pressure_low).any()
                    or (plant.actuator_position_max > self.stroke_high).any()
                    or (plant.actuator_position_min < self.stroke_low).any())

    def check_extremes(self, time: float, plant) -> Violation | None:
        """The plant's per-step extremes against the bounds (found "by" ``time``, a block end)."""
        pmax, pmin = plant.node_pressure_max, plant.node_pressure_min
        if (pmax > self.pressure_high).any() or (pmin < self.pressure_low).any():
            return self._pressure(time, pmax, pmin)
        xmax, xmin = plant.actuator_position_max, plant.actuator_position_min
        if (xmax > self.stroke_high).any() or (xmin < self.stroke_low).any():
            return self._stroke(time, xmax, xmin)
        return None

    def check_batch(self, batch: dict, dt: float, initial_total: float):
        """The logged samples of a batch (:meth:`sim.run.recorder.RunRecorder.derive`'s arrays): energy residual,
        strokes and joint ranges.  Returns (index of the first sample with a violation, :class:`Violation`) or None."""
        first, found = None, None
        x = batch.get("actuator_position")
        if x is not None and len(x):
            bad = np.flatnonzero(((x > self.stroke_high) | (x < self.stroke_low)).any(axis=1))
            if len(bad):
                i = int(bad[0])
                first, found = i, self._stroke(batch["step"][i] * dt, x[i], x[i])
        q = batch.get("joint_position")
        if self.checks_joints and q is not None and len(q):
            bad = np.flatnonzero(((q > self.joint_high) | (q < self.joint_low)).any(axis=1))
            if len(bad) and (first is None or bad[0] < first):
                i = int(bad[0])
                first, found = i, self._joint(batch["step"][i] * dt, q[i])
        if self.energy and len(batch["residual"]):
            stored = batch["kinetic"] + batch["potential"] + batch["oil"] - initial_total
            work = batch["pump_work"]
            turnover = self._turnover + np.cumsum(np.abs(np.diff(work, prepend=self._last[0]))
                                                  + np.abs(np.diff(stored, prepend=self._last[1])))
            self._turnover, self._last = float(turnover[-1]), (float(work[-1]), float(stored[-1]))
            lost = energy_loss_fraction(dt)
            residual = batch["residual"]
            fraction = np.where(residual > 0, lost, ENERGY_RESIDUAL_FRACTION)
            allowed = fraction * turnover + self.energy_floor
            bad = np.flatnonzero(~(np.abs(residual) <= allowed))  # (NaN counts as a violation)
            if len(bad) and (first is None or bad[0] < first):
                i = int(bad[0])
                r, a = float(residual[i]), float(allowed[i])
                text = (f"{r:.4g} J beyond the bound +-{a:.4g} J ({float(fraction[i]):.3g} x energy turnover "
                        f"{float(turnover[i]):.4g} J + {self.energy_floor:.4g} J): energy is lost or made "
                        "outside the modelled losses (an MJCF actuator the circuit does not drive, or an unstable coupling)")
                first, found = i, Violation(batch["step"][i] * dt, "energy balance", "residual", r, a, text,
                                            ("energy balance", "residual", ""))
        return None if found is None else (first, found)

    def check_constraints(self, time: float) -> Violation | None:
        """Equality constraints (and PBD joint pins) at the plant's current state against ``EQUALITY_TOLERANCE``."""
        worst = self._constraints.worst()
        if worst is None:
            return None
        name, value = worst
        if value <= EQUALITY_TOLERANCE:
            return None
        return Violation(time, name, "violation", value, EQUALITY_TOLERANCE,
                         f"{value:.4g} m beyond the tolerance {EQUALITY_TOLERANCE:g} m: the constraint is pulled apart",
                         (name, "violation", ""))

    # --------------------------------------------------------------- details
    def _pressure(self, time, high, low) -> Violation:
        names = self.network.node_names
        over = high - self.pressure_high
        under = self.pressure_low - low
        with np.errstate(invalid="ignore"):
            i, j = int(np.nanargmax(over)) if np.isfinite(over).any() else -1, int(np.nanargmax(under)) if np.isfinite(under).any() else -1
        if i >= 0 and over[i] > 0:
            v, b = float(high[i]), float(self.pressure_high[i])
            return Violation(time, f"node '{names[i]}'", "pressure", v, b,
                             f"{_bar(v)} above its bound {_bar(b)} ({self.pressure_basis})", (names[i], "pressure", "high"))
        v, b = float(low[j]), float(self.pressure_low[j])
        return Violation(time, f"node '{names[j]}'", "pressure", v, b,
                         f"{v:.6g} Pa below its bound {b:.6g} Pa ({self.floor_basis})", (names[j], "pressure", "low"))

    def _stroke(self, time, high, low) -> Violation:
        names = self.network.actuator_names
        over = high - self.stroke_high
        under = self.stroke_low - low
        i, j = int(np.argmax(over)), int(np.argmax(under))
        if over[i] >= under[j]:
            a, v, side, b = i, float(high[i]), "beyond its extended end", float(self.stroke_high[i])
        else:
            a, v, side, b = j, float(low[j]), "beyond its retracted end", float(self.stroke_low[j])
        text = (f"{v:.4g} m {side} (stroke 0 .. {self.stroke[a]:.4g} m, bound {b:.4g} m: tolerance "
                f"max({STROKE_TOLERANCE:g} m, {STROKE_TOLERANCE_FRACTION:.0%} of the stroke))")
        return Violation(time, f"cylinder '{names[a]}'", "stroke", v, b, text, (names[a], "stroke", side))

    def _joint(self, time, q) -> Violation:
        names = self.plant.joint_names
        over = np.maximum(q - self.joint_high, self.joint_low - q)
        i = int(np.argmax(over))
        v = float(q[i])
        high = v > self.joint_high[i]
        b = float(self.joint_high[i] if high else self.joint_low[i])
        unit = str(self.joint_unit[i])
        lo, hi = self.joint_range[i]
        rule = (f"{JOINT_RANGE_TOLERANCE_HINGE:g} rad" if unit == "rad" else
                f"max({STROKE_TOLERANCE:g} m, {STROKE_TOLERANCE_FRACTION:.0%} of the range)")
        text = f"{v:.6g} {unit} outside its range {lo:.6g} .. {hi:.6g} {unit} (bound {b:.6g} {unit}: tolerance {rule})"
        return Violation(time, f"joint '{names[i]}'", "position", v, b, text, (names[i], "position", "high" if high else "low"))


class ConstraintErrors:
    """Largest equality-constraint violation of a plant's current state, with the constraint's name.

    MuJoCo plants: the rows of ``efc_pos`` whose ``efc_type`` is an equality (the state MuJoCo's last
    ``mj_step``/``mj_forward`` saw), grouped per equality (``efc_id``): the violation is the length of the
    gap vector, ``|efc_pos|`` over a ``connect``'s three rows, the larger of the position and the rotation
    lengths of a ``weld``'s six, ``|efc_pos|`` of a ``joint`` or ``tendon`` equality's one row.  PBD plants: the pin errors
    |p₂ − p₁| [m] of the XPBD hinge joints and connect / weld equalities at the current body state.
    """

    def __init__(self, plant):
        self.plant = plant
        m = plant.model
        self.eq_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_EQUALITY, e) or f"equality {e}" for e in range(m.neq)]
        self.xmodel = getattr(plant, "xmodel", None)
        self.active = m.neq > 0
        if self.xmodel is not None:
            xm = self.xmodel
            from sim.xpbd.model import JNT_HINGE

            self.hinges = np.flatnonzero(np.asarray(xm.jnt_type) == JNT_HINGE)
            self.eq_pbd_names = self._pbd_equality_names(m, len(xm.eq_type))
            self.active = len(self.hinges) > 0 or len(xm.eq_type) > 0

    def _pbd_equality_names(self, m, count):
        """Names of the equalities the XPBD model kept (active connect, and weld between bodies, in MJCF order)."""
        kept = []
        for e in range(m.neq):
            if not m.eq_active0[e]:
                continue
            et, site = int(m.eq_type[e]), int(m.eq_objtype[e]) == int(mujoco.mjtObj.mjOBJ_SITE)
            if et == int(mujoco.mjtEq.mjEQ_CONNECT) or (et == int(mujoco.mjtEq.mjEQ_WELD) and not site):
                kept.append(f"equality '{self.eq_names[e]}'")
        return kept if len(kept) == count else [f"equality {i}" for i in range(count)]

    def worst(self):
        """(component name, violation [m | rad]) of the worst constraint, or None when there is none."""
        if not self.active:
            return None
        if self.xmodel is None:
            d = self.plant.data
            n = d.nefc
            if n == 0:
                return None
            rows = np.flatnonzero(d.efc_type[:n] == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY))
            if not len(rows):
                return None
            ids = d.efc_id[rows]
            best = None
            for e in np.unique(ids):
                gap = d.efc_pos[rows[ids == e]]
                size = max(float(np.linalg.norm(gap[:3])), float(np.linalg.norm(gap[3:]))) if len(gap) == 6 else \
                    float(np.linalg.norm(gap))
                if best is None or size > best[1]:
                    best = (f"equality '{self.eq_names[int(e)]}'", size)
            return best
        return self._pbd_worst()

    def _pbd_worst(self):
        from sim.xpbd.quat import np_quat_rotate

        xm, plant = self.xmodel, self.plant
        X, Q, _, _ = plant.solver._gather(plant.state)
        best = None
        if len(self.hinges):
            h = self.hinges
            g1, g2 = xm.jnt_g1[h], xm.jnt_g2[h]
            gap = X[g2] + np_quat_rotate(Q[g2], xm.jnt_r2[h]) - X[g1] - np_quat_rotate(Q[g1], xm.jnt_r1[h])
            err = np.sqrt((gap * gap).sum(axis=1))
            k = int(np.argmax(err))
            best = (f"joint '{xm.jnt_names[h[k]]}'", float(err[k]))
        if len(xm.eq_type):
            g1, g2 = xm.eq_g1, xm.eq_g2
            gap = X[g2] + np_quat_rotate(Q[g2], xm.eq_r2) - X[g1] - np_quat_rotate(Q[g1], xm.eq_r1)
            err = np.sqrt((gap * gap).sum(axis=1))
            k = int(np.argmax(err))
            if best is None or err[k] > best[1]:
                best = (self.eq_pbd_names[k], float(err[k]))
        return best


__all__ = [
    "ENERGY_RESIDUAL_FLOOR", "ENERGY_RESIDUAL_FLOOR_PER_KG", "ENERGY_RESIDUAL_FRACTION", "EQUALITY_TOLERANCE", "JOINT_RANGE_TOLERANCE_HINGE",
    "ENERGY_LOSS_TIME", "NO_RELIEF_PRESSURE_LIMIT", "PRESSURE_BOUND_FACTOR", "PRESSURE_FLOOR_FACTOR",
    "RELIEF_OVERRIDE_FRACTION", "ConstraintErrors", "RunMonitor", "STROKE_TOLERANCE", "STROKE_TOLERANCE_FRACTION", "Violation",
    "end_stop_tolerance", "energy_loss_fraction", "energy_unmetered", "pressure_sources",
]
