"""numpy oracles of the explicit, incompressible and rigid-actuator couplings (test-only).

Independent formulations of the equations :mod:`hydraulics._compiled_rigid` compiles (see its module docstring
for the equations, units and references): whole-array numpy, written from the model's fields, used by the property
tests (kernel vs oracle on random inputs) and the scene tests (the per-step couplings against these to round-off).

Example
-------
>>> from reference.rigid_couplings import quadratic_damper
>>> quadratic_damper(np.array([10.0]), np.array([2.0]), np.array([-1.0]))
(array([12.]), array([-4.]))
"""

from __future__ import annotations

import numpy as np

TRACKING_GAIN = 100.0  # [-], hydraulics._compiled_rigid.INCOMPRESSIBLE_TRACKING_GAIN
UNBOUNDED_PRESSURE = 1e12  # Pa, hydraulics._compiled_rigid.INCOMPRESSIBLE_UNBOUNDED_PRESSURE


def spool_step(spool, command, time_constant, dt):
    """s⁺ = u + (s − u)·exp(−h/τ), τ = 0: s⁺ = u."""
    tau = np.asarray(time_constant, float)
    with np.errstate(divide="ignore"):
        decay = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    return command + (spool - command) * decay


def metering_opening(spool, overlap):
    """y = clip((s − ε)/(1 − ε), 0, 1)."""
    return np.clip((np.asarray(spool, float) - overlap) / (1.0 - overlap), 0.0, 1.0)


def metered_actuator_force(direction, area_in, area_out, orifice_in, orifice_out, supply, tank, density, ambient):
    """(F_d, R) of F(v) = F_d − R·v·|v| (Merritt §5.2)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        resistance = 0.5 * density * (area_in**3 / orifice_in**2 + area_out**3 / orifice_out**2)
    return direction * ((supply - ambient) * area_in - (tank - ambient) * area_out), resistance


def tracking_gain(effective_mass, like, dt):
    """G·m_eff/h (m_eff = 1 where unknown)."""
    mass = np.ones_like(like) if effective_mass is None else np.where(np.isfinite(effective_mass), effective_mass, 1.0)
    return TRACKING_GAIN * mass / dt


def free_speed(drive, resist):
    """√(|F_d|/R)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(np.abs(drive) / resist)


TRACKER_BOUND_MARGIN = 1.0 - 1e-9  # the lowered gain keeps F at ``velocity`` this factor inside its bound


def bounded_tracker(target, velocity, gain, lower, upper):
    """F = K·(target − v⁺), K lowered so F at ``velocity`` stays (a factor TRACKER_BOUND_MARGIN) inside [lower, upper]:
    (constant, slope)."""
    error = target - velocity
    bound = np.where(error >= 0, upper, -lower)
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(np.abs(error) > 0, np.clip(TRACKER_BOUND_MARGIN * bound / np.abs(error), 0.0, gain), gain)
    return gain * target, -gain


def quadratic_damper(drive, resist, velocity):
    """F_d − R·v⁺·|v⁺| linearised at ``velocity``: (constant, slope)."""
    return drive + resist * velocity * np.abs(velocity), -2.0 * resist * np.abs(velocity)


def areas(model):
    """Areas extending / retracting of every actuator (cap / rod, D/2π): model data, read as the package packs it."""
    from hydraulics._compiled_rigid import _actuator_areas

    return _actuator_areas(model)


def relief_pressure(model):
    return np.max(model.relief_cracking) if len(model.relief_cracking) else UNBOUNDED_PRESSURE


def valve_areas(model, spool):
    """Open area of every orifice branch (metering and centre passages)."""
    area = model.orifice_base_area.copy()
    if len(model.valve_names):
        has_valve = model.orifice_valve >= 0
        s = np.where(has_valve, spool[np.maximum(model.orifice_valve, 0)], 0.0)
        overlap = np.where(has_valve, model.valve_overlap[np.maximum(model.orifice_valve, 0)], 0.0)
        area = area + model.orifice_max_area * metering_opening(model.orifice_sign * s, overlap)
        area = area + model.orifice_centre_area * np.clip(1.0 - np.abs(s) / np.maximum(overlap, 0.1), 0.0, 1.0)
    return area


def rigid_rates(model, spool):
    """Flow per unit velocity of every rigid branch."""
    s = model.rigid_sign * spool[model.rigid_valve]
    direction = np.sign(s) * (metering_opening(np.abs(s), model.valve_overlap[model.rigid_valve]) > 0)
    return np.where(direction > 0, model.rigid_extend_area, np.where(direction < 0, -model.rigid_retract_area, 0.0))


def explicit_substep(model, oil, spool, command, pump_speed, position, position_end, velocity, h):
    """Forward Euler m⁺ = m + h·N·Q(p(m, x), s, v): returns (oil⁺, p(m⁺, x_end), spool⁺, flows)."""
    pressure, _ = model.pressure(oil, position)
    area = valve_areas(model, spool)
    if len(model.rigid_branch_actuator):
        area = np.concatenate([area, rigid_rates(model, spool)])
    flows = model.branch_flows(pressure, area, pump_speed, velocity)
    new = oil.copy()
    free = model.free_nodes
    new[free] += h * (model.incidence @ flows.flow)[free]
    spool_end = spool_step(spool, np.clip(command, -1.0, 1.0), model.valve_time_constant, h)
    end_pressure, _ = model.pressure(new, position_end)
    return new, end_pressure, spool_end, flows.flow


def incompressible_edges(model):
    """Per actuator: orifice branches P→in, out→T (extend), P→out, in→T (retract); −1 none."""
    n = model.actuator_count
    edges = np.full((n, 4), -1)
    for a in range(n):
        if a in list(model.cylinder_actuator):
            i = list(model.cylinder_actuator).index(a)
            inlet, outlet = model.cylinder_cap_node[i], model.cylinder_rod_node[i]
        else:
            i = list(model.motor_actuator).index(a)
            inlet, outlet = model.motor_a_node[i], model.motor_b_node[i]
        for b in range(model.branch_slices["orifice"].stop):
            if model.orifice_valve[b] < 0 or model.orifice_sign[b] == 0:
                continue
            frm, to = model.branch_from[b], model.branch_to[b]
            if to == inlet:
                edges[a, 0 if model.orifice_sign[b] > 0 else 2] = b
            elif frm == outlet:
                edges[a, 1 if model.orifice_sign[b] > 0 else 3] = b
            elif to == outlet:
                edges[a, 2 if model.orifice_sign[b] < 0 else 0] = b
            elif frm == inlet:
                edges[a, 3 if model.orifice_sign[b] < 0 else 1] = b
    return edges


STOP_REACH = 2.0  # the start or target speed times this reaching an end of the stroke within the step engages the stop


def stroke_window(model, position, dt):
    """Per actuator the end speeds (v_lo, v_hi) that keep x + dt·v⁺ inside [0, stroke] (±inf for motors)."""
    lo, hi = np.full(model.actuator_count, -np.inf), np.full(model.actuator_count, np.inf)
    x = np.asarray(position, float)[model.cylinder_actuator]
    lo[model.cylinder_actuator] = -x / dt
    hi[model.cylinder_actuator] = (model.cylinder_stroke - x) / dt
    return lo, hi


def incompressible_law(model, spool, pump_speed, position, velocity, effective_mass, dt):
    """(constant, slope, lower, upper) of the incompressible effort law at the end spools ``spool``, from the start
    positions and velocities."""
    m = model
    edges = incompressible_edges(m)
    relief = relief_pressure(m)
    compensators = m.pump_compensator[np.isfinite(m.pump_compensator)]
    p_s = m.fluid.reference_pressure + (np.max(compensators) if len(compensators) else relief)
    p_t, rho = m.fluid.reference_pressure, m.fluid.density
    extend, retract = areas(m)
    force_upper, force_lower = relief * extend, -relief * retract
    gain = tracking_gain(effective_mass, velocity, dt)
    if not np.any(edges >= 0):
        return np.zeros_like(velocity), -gain, force_lower, force_upper
    area = valve_areas(m, spool)
    edge = np.maximum(edges, 0)
    coefficient = np.where(edges >= 0, m.orifice_cd[edge] * area[edge], 0.0)
    valve = m.orifice_valve[edge[:, 0]]
    opening = np.where(edges[:, 0] >= 0, spool[np.maximum(valve, 0)] if len(spool) else 0.0, 0.0)
    direction = np.sign(opening) * (metering_opening(np.abs(opening), m.valve_overlap[np.maximum(valve, 0)]) > 0)
    a_in = np.where(direction >= 0, extend, retract)
    a_out = np.where(direction >= 0, retract, extend)
    c_in = np.where(direction >= 0, coefficient[:, 0], coefficient[:, 2])
    c_out = np.where(direction >= 0, coefficient[:, 1], coefficient[:, 3])
    drive, resist = metered_actuator_force(direction, a_in, a_out, c_in, c_out, p_s, p_t, rho, p_t)
    constant, slope = quadratic_damper(drive, resist, velocity)
    free = free_speed(drive, resist)
    demand = np.where(direction != 0, free * a_in, 0.0)
    supply = float(np.sum(m.pump_efficiency * m.pump_displacement * pump_speed))
    ratio = min(1.0, supply / demand.sum()) if demand.sum() > 0 else 1.0  # the demands scaled down together
    with np.errstate(invalid="ignore"):
        cap = np.where((direction != 0) & (a_in > 0), free * ratio, 0.0)  # each share / A_in
    pump_limited = (direction != 0) & np.isfinite(resist) & (cap < free)
    track = (direction == 0) | ~np.isfinite(resist) | pump_limited | (np.abs(velocity) >= cap)
    target = direction * np.where(direction == 0, 0.0, cap)
    damper_now = constant + slope * velocity
    lower, upper = force_lower.copy(), force_upper.copy()
    upper = np.where(pump_limited & (direction > 0), np.maximum(np.minimum(upper, damper_now), lower), upper)
    lower = np.where(pump_limited & (direction < 0), np.minimum(np.maximum(lower, damper_now), upper), lower)
    v_lo, v_hi = stroke_window(m, position, dt)
    stop = ((v_hi <= STOP_REACH * np.maximum(np.maximum(velocity, target), 0.0))
            | (v_lo >= -STOP_REACH * np.maximum(np.maximum(-velocity, -target), 0.0)))
    track = track | stop
    target = np.where(stop, np.clip(target, v_lo, v_hi), target)
    tracker_constant, tracker_slope = bounded_tracker(target, velocity, gain, lower, upper)
    return np.where(track, tracker_constant, constant), np.where(track, tracker_slope, slope), lower, upper


def mixed_law(model, constant, slope, spool0, command, velocity, effective_mass, dt, p_supply, dp_dv, v_guess):
    """(constant, slope, lower, upper) of the rigid actuators' law over the inner law (constant, slope)."""
    m = model
    rigid = np.asarray(m.actuator_rigid, bool)
    relief = relief_pressure(m)
    extend, retract = areas(m)
    supply_top = m.fluid.reference_pressure + relief
    lower = np.where(rigid, -relief * retract, -np.inf)
    upper = np.where(rigid, relief * extend, np.inf)
    constant, slope = np.array(constant, float), np.array(slope, float)
    tracking = rigid.copy()
    target = np.zeros(m.actuator_count)
    if len(m.rigid_branch_actuator):
        spool = spool_step(spool0, np.clip(command, -1.0, 1.0), m.valve_time_constant, dt)
        a = m.rigid_branch_actuator
        s = m.rigid_sign * spool[m.rigid_valve]
        overlap = m.valve_overlap[m.rigid_valve]
        direction = np.sign(s) * (metering_opening(np.abs(s), overlap) > 0)
        a_in = np.where(direction >= 0, m.rigid_extend_area, m.rigid_retract_area)
        a_out = np.where(direction >= 0, m.rigid_retract_area, m.rigid_extend_area)
        edge = m.rigid_cd * (m.rigid_base_area + m.rigid_max_area * metering_opening(np.abs(spool[m.rigid_valve]), overlap))
        s_ = m.branch_slices["rigid"]
        p_tank = m.node_fixed_pressure[m.branch_to[s_]]

        def metered(p):
            return metered_actuator_force(direction, a_in, a_out, edge, edge, p, p_tank, m.fluid.density,
                                          m.fluid.reference_pressure)

        drive, resist = metered(p_supply)
        c, k = quadratic_damper(drive, resist, velocity[a])
        supply_slope = direction * a_in * dp_dv
        friction, friction_slope = m.friction_effort(velocity)
        friction_slope = np.minimum(friction_slope, 0.0)
        c = c - supply_slope * v_guess + friction[a] - friction_slope[a] * velocity[a]
        k = k + supply_slope + friction_slope[a]
        free = free_speed(drive, resist)
        damper = (direction != 0) & np.isfinite(resist) & (np.abs(velocity[a]) < free)
        constant[a], slope[a] = np.where(damper, c, 0.0), np.where(damper, k, 0.0)
        tracking[a] = ~damper
        target[a] = np.where(direction != 0, direction * np.nan_to_num(free), 0.0)
        ends = [metered(p)[0] for p in (m.fluid.pressure_floor, supply_top)]
        offset = c + k * velocity[a] - drive
        lower[a] = np.where(damper, np.minimum(*ends) + offset, lower[a])
        upper[a] = np.where(damper, np.maximum(*ends) + offset, upper[a])
    tracker_constant, tracker_slope = bounded_tracker(target, velocity, tracking_gain(effective_mass, velocity, dt),
                                                      lower, upper)
    return np.where(tracking, tracker_constant, constant), np.where(tracking, tracker_slope, slope), lower, upper


def chamber_pressures(model, effort, pressure, actuators):
    """Chamber pressures of rigid oil carrying ``effort``, written into ``pressure`` for the masked actuators."""
    ref = model.fluid.reference_pressure
    for i, a in enumerate(model.cylinder_actuator):
        if actuators[a]:
            pressure[model.cylinder_cap_node[i]] = ref + max(effort[a], 0.0) / model.cylinder_cap_area[i]
            pressure[model.cylinder_rod_node[i]] = ref + max(-effort[a], 0.0) / model.cylinder_rod_area[i]
    for i, a in enumerate(model.motor_actuator):
        if actuators[a]:
            rate = model.motor_displacement[i] / (2.0 * np.pi)
            pressure[model.motor_a_node[i]] = ref + max(effort[a], 0.0) / rate
            pressure[model.motor_b_node[i]] = ref + max(-effort[a], 0.0) / rate
    return pressure


# ----------------------------------------------------------------------------
# The couplings on the oracles (for scene tests: a plant stepped with these against the package's)
# ----------------------------------------------------------------------------
def oracle_coupling(coupling):
    """A coupling equal to ``coupling`` whose explicit stepper, incompressible law and rigid-actuator law are the
    oracles above (the inner coupling of a mixed one is wrapped too)."""
    from hydraulics.coupling import CouplingIncompressible, CouplingMixed, EffortLaw
    from hydraulics.network import NetworkState
    from hydraulics.steppers import StepperExplicitEuler, StepReport

    class ExplicitEuler(StepperExplicitEuler):
        def _substep(self, state, control, motion, h, oil_guess=None):
            oil, pressure, spool, flow = explicit_substep(
                self.model, state.node_oil, state.valve_spool, control.valve_command, control.pump_speed,
                np.asarray(motion.position_start, float), np.asarray(motion.position_end, float),
                np.asarray(motion.velocity_start, float), h)
            self.rhs_count += 1
            return (NetworkState(oil, pressure, spool, np.array(motion.position_end, float),
                                 np.array(motion.velocity_start, float), state.time + h),
                    StepReport(rhs_evaluations=1, branch_flow=flow))

    class Incompressible(CouplingIncompressible):
        def law(self, spool0, command, pump_speed, position, velocity, effective_mass, dt):
            m = self.model
            spool = spool_step(spool0, np.clip(command, -1.0, 1.0), m.valve_time_constant, dt)
            return spool, EffortLaw(*incompressible_law(m, spool, pump_speed, position, np.asarray(velocity, float),
                                                        effective_mass, dt))

        def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
            m, law = self.model, self._law
            effort = np.clip(law(np.asarray(velocity_end, float)), law.lower, law.upper)
            pressure = np.full(m.node_count, m.fluid.reference_pressure)
            pressure[m.node_fixed] = m.node_fixed_pressure[m.node_fixed]
            chamber_pressures(m, effort, pressure, np.ones(m.actuator_count, bool))
            x = np.asarray(position_end, float)
            return (NetworkState(m.oil_from_pressure(pressure, x), pressure, self._spool, x.copy(),
                                 np.asarray(velocity_end, float).copy(), state.time + dt),
                    StepReport(branch_flow=np.zeros(len(m.branch_names))))

    class Mixed(CouplingMixed):
        def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
            from hydraulics.coupling import start_velocity_guess

            m = self.model
            if velocity_guess is None:
                velocity_guess = start_velocity_guess(m, position, velocity, dt)
            law = self.inner.begin(state, control, position, velocity, dt,
                                   effective_mass=effective_mass if self.blend else None, velocity_guess=velocity_guess)
            self.last_theta = np.where(self.rigid, 1.0, getattr(self.inner, "last_theta", np.ones(m.actuator_count)))
            p_supply, dp_dv, v_guess = self._supply(state, control, dt)
            self._law = EffortLaw(*mixed_law(m, law.constant, law.slope, state.valve_spool, control.valve_command,
                                             np.asarray(velocity, float), effective_mass, dt, p_supply, dp_dv, v_guess))
            return self._law

        def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
            new, report = self.inner.finish(state, control, position_start, position_end, velocity_start,
                                            velocity_end, dt)
            v = np.asarray(velocity_end, float)
            effort = np.clip(self._law(v), self._law.lower, self._law.upper)
            new = new.copy()
            chamber_pressures(self.model, effort - self.model.friction_effort(v)[0], new.node_pressure, self.rigid)
            return new, report

    def stepper(s):
        if isinstance(s, StepperExplicitEuler):
            return ExplicitEuler(s.model, substeps=s.substeps)
        return s

    if isinstance(coupling, CouplingMixed):
        inner = oracle_coupling(coupling.inner)
        out = Mixed(coupling.model, inner)
        out.blend = coupling.blend
        return out
    if isinstance(coupling, CouplingIncompressible):
        return Incompressible(coupling.model, coupling.stepper)
    out = type(coupling)(coupling.model, stepper(coupling.stepper))
    return out
