"""The numpy evaluation of a :class:`~hydraulics.network.NetworkModel`, element-wise on arrays: the oracle of its
compiled methods.

Each function takes the model first and mirrors the method of the same name (:meth:`NetworkModel.pressure` →
:func:`pressure`, …), broadcasting over leading axes where the method does.  It is written from the numpy laws of
:mod:`reference.laws`, independently of the compiled kernels (:mod:`hydraulics._compiled`, the component modules),
so that the property tests (``tests/test_network_oracle.py``) compare two formulations of every equation.

Example
-------
>>> from hydraulics.files import load_circuit  # doctest: +SKIP
>>> model = NetworkModel.from_circuit(load_circuit("models/excavator/excavator.circuit.toml"))  # doctest: +SKIP
>>> state = model.state()  # doctest: +SKIP
>>> p, dpdm = pressure(model, state.node_oil, state.actuator_position)  # doctest: +SKIP
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from hydraulics.components import (BRANCH_LAWS, CheckValve, LaminarResistance, Motor, Orifice, PumpCompensated,
                                   PumpFixed, ReliefValve, law_inputs, law_states)
from hydraulics.components.relief import REGULARISATION as RELIEF_REGULARISATION
from hydraulics.network import PRESSURE_INVERSION_MAX_ITERATIONS, PRESSURE_INVERSION_TOLERANCE, BranchFlows

from . import laws


def _per_sample(values, like):
    """A fresh copy of the per-node ``values`` for every sample of the array ``like`` (shape like.shape[:-1] + values.shape)."""
    if like.ndim <= 1:
        return values.copy()
    out = np.empty(np.shape(like)[:-1] + values.shape)
    out[...] = values
    return out


def geometric_volume(model, position):
    """Node volumes at the reference pressure [m³]: fixed volumes plus cylinder chambers at ``position``."""
    volume = _per_sample(model.node_volume, position)
    if len(model.cylinder_cap_node):
        vc, vr, _, _ = chamber_volumes(model, position)
        np.add.at(volume, (..., model.cylinder_cap_node), vc)
        np.add.at(volume, (..., model.cylinder_rod_node), vr)
    return volume


def extra_volume(model, pressure):
    """Pressure-dependent node volume [m³] (hose walls, accumulator liquid) and its derivative [m³/Pa]."""
    extra = model.node_wall_compliance * (pressure - model.fluid.reference_pressure)
    dextra = _per_sample(model.node_wall_compliance, pressure)
    if len(model.accumulator_node):
        liquid, dliquid = laws.accumulator_liquid_volume_with_derivative(
            pressure.take(model.accumulator_node, axis=-1), model.accumulator_gas_volume, model.accumulator_precharge,
            model.accumulator_index,
        )
        np.add.at(extra, (..., model.accumulator_node), liquid)
        np.add.at(dextra, (..., model.accumulator_node), dliquid)
    return extra, dextra


def node_volume_at(model, position, pressure):
    """Node volumes V(x, p) [m³] and ∂V/∂p [m³/Pa] (chambers, walls, accumulators), each of shape (..., node_count)."""
    extra, dextra = extra_volume(model, pressure)
    return geometric_volume(model, position) + extra, dextra


def chamber_volumes(model, position):
    """Cap and rod chamber volumes [m³] and dV/dx [m²] of every cylinder at actuator ``position``."""
    return laws.chamber_volumes(
        position.take(model.cylinder_actuator, axis=-1),
        model.cylinder_stroke,
        model.cylinder_cap_area,
        model.cylinder_rod_area,
        model.cylinder_dead_cap,
        model.cylinder_dead_rod,
    )


def volume_position_gradient(model, position) -> np.ndarray:
    """∂V_node/∂x_actuator [m²], shape (node_count, actuator_count)."""
    grad = np.zeros((model.node_count, model.actuator_count))
    if len(model.cylinder_cap_node):
        _, _, dvc, dvr = chamber_volumes(model, position)
        np.add.at(grad, (model.cylinder_cap_node, model.cylinder_actuator), dvc)
        np.add.at(grad, (model.cylinder_rod_node, model.cylinder_actuator), dvr)
    return grad


def oil_from_pressure(model, pressure, position):
    """Oil content m = V(x, p)·φ(p) [m³] of every node (NaN for fixed nodes)."""
    volume, _ = node_volume_at(model, position, pressure)
    phi, _ = model.fluid.fill_ratio(pressure)
    return np.where(model.node_fixed, np.nan, volume * phi)


def pressure(model, oil, position):
    """Absolute node pressures [Pa] from oil content and actuator positions.

    Returns
    -------
    pressure : ndarray, shape (node_count,)
        Solves m = V(x, p)·φ(p), floored at the cavitation pressure; fixed
        nodes at their set pressure.
    dp_doil : ndarray, shape (node_count,)
        ∂p/∂m [Pa/m³] = 1/(∂V/∂p·φ + V·φ'); 0 for fixed and cavitating nodes.
    """
    fluid = model.fluid
    fixed = model.node_fixed
    geometric = geometric_volume(model, position)
    safe = np.where(fixed, 1.0, geometric)  # fixed nodes hold no oil state
    p = fluid.pressure_from_fill_ratio(np.where(fixed, 1.0, oil / safe))
    compliant = model.compliant_nodes
    if len(compliant):
        p = invert_compliant(model, oil, geometric, p, compliant)
    floor = fluid.pressure_floor
    cavitating = (p < floor) & ~fixed
    p = np.where(cavitating, floor, p)
    p = np.where(fixed, model.node_fixed_pressure, p)
    extra, dvdp = extra_volume(model, p)
    phi, dphi = fluid.fill_ratio(p)
    dp_doil = np.where(fixed | cavitating, 0.0, 1.0 / np.where(fixed, 1.0, dvdp * phi + (geometric + extra) * dphi))
    return p, dp_doil


def invert_compliant(model, oil, geometric, rigid, nodes):
    """Solve ln((V_g + V_e(p))·φ(p)) = ln m on the compliant ``nodes``; other entries of ``rigid`` are kept.

    Safeguarded Newton from the rigid-volume pressure, bracketing the root
    (the function is increasing in p) and bisecting when a Newton step
    leaves the bracket; converged entries are frozen.
    """
    fluid = model.fluid
    log_oil = np.log(oil[nodes])
    p_full = rigid.copy()

    def f(p):
        p_full[nodes] = p
        extra, dextra = extra_volume(model, p_full)
        volume = geometric[nodes] + extra[nodes]
        phi, dphi = fluid.fill_ratio(p)
        return np.log(volume * phi) - log_oil, dextra[nodes] / volume + dphi / phi

    p = rigid[nodes].copy()
    value, slope = f(p)
    lo = np.where(value <= 0, p, -np.inf)
    hi = np.where(value > 0, p, np.inf)
    for _ in range(PRESSURE_INVERSION_MAX_ITERATIONS):
        done = np.abs(value) < PRESSURE_INVERSION_TOLERANCE
        if np.all(done):
            break
        newton = p - value / slope
        # without a lower bracket, at most halve the pressure (stays in the law's domain)
        newton = np.where(np.isfinite(lo), newton, np.maximum(newton, np.where(p > 0, 0.5 * p, p - 1e6)))
        bracketed = np.isfinite(lo) & np.isfinite(hi)
        outside = (newton <= lo) | (newton >= hi)
        p = np.where(done, p, np.where(bracketed & outside, 0.5 * (lo + hi), newton))
        value, slope = f(p)
        lo = np.where(value <= 0, np.maximum(lo, p), lo)
        hi = np.where(value > 0, np.minimum(hi, p), hi)
    p_full[nodes] = p
    return p_full


def effective_bulk_modulus(model, pressure, position, volumes=None):
    """Effective bulk modulus of each node [Pa]: V·φ/(∂V/∂p·φ + V·φ'), including walls and accumulators.

    ``volumes`` may pass :meth:`node_volume_at` of the same state to save recomputing it.
    """
    volume, dvdp = node_volume_at(model, position, pressure) if volumes is None else volumes
    volume = np.where(model.node_fixed, 1.0, volume)  # tanks: report the oil's own modulus
    phi, dphi = model.fluid.fill_ratio(pressure)
    return volume * phi / (dvdp * phi + volume * dphi)


# ------------------------------------------------------------ flows
def valve_areas(model, spool):
    """Open area [m²] of every orifice-law branch for the given spool positions, followed (when the
    network has rigid actuators) by the displacement rate of every rigid branch (:meth:`rigid_rates`)."""
    area = model.orifice_base_area.copy()
    if len(model.valve_names):
        has_valve = model.orifice_valve >= 0
        s = np.where(has_valve, spool[np.maximum(model.orifice_valve, 0)], 0.0)
        overlap = np.where(has_valve, model.valve_overlap[np.maximum(model.orifice_valve, 0)], 0.0)
        travel = model.orifice_sign * s
        opening = laws.metering_opening(travel, overlap)
        area = area + np.array([metered_area(model, b, travel[b], opening[b]) for b in range(len(area))])
        area = area + model.orifice_centre_area * laws.centre_opening(s, overlap)
    if len(model.rigid_branch_actuator):
        area = np.concatenate([area, rigid_rates(model, spool)])
    return area


def metered_area(model, branch, travel, opening):
    """Area above leakage [m²] of orifice branch ``branch`` at spool travel ``travel`` and linear opening ``opening``,
    read from its valve's circuit parameters: A_max·y (linear), A_max·expm1(a·y)/expm1(a) (exponential), or scipy's
    PCHIP through the edge's table held at its end values (tabulated)."""
    valve = model.orifice_valve[branch]
    if valve < 0:
        return 0.0
    params = model.circuit.component(model.valve_names[valve]).params
    edge = model.branch_names[branch].split(".", 1)[1]
    kind = getattr(params, "metering", "linear") if edge in type(params).METERING_EDGES else "linear"
    full = model.orifice_max_area[branch]
    if kind == "exponential":
        return full * np.expm1(params.metering_exponent * opening) / np.expm1(params.metering_exponent)
    tables = dict(getattr(params, "area_table", ()))
    if kind == "table" and edge in tables:
        knots = np.array(tables[edge], float).T
        return float(PchipInterpolator(*knots)(np.clip(travel, knots[0, 0], knots[0, -1])))
    return full * opening


def rigid_direction(model, spool):
    """Metering direction of every rigid branch [-]: +1 when the spool feeds the cap (motor port a) from P,
    −1 the rod (port b), 0 while the spool is inside its overlap (closed)."""
    s = model.rigid_sign * spool[model.rigid_valve]
    return np.sign(s) * (laws.metering_opening(np.abs(s), model.valve_overlap[model.rigid_valve]) > 0)


def rigid_rates(model, spool):
    """Flow drawn from P per unit actuator velocity [m² or m³/rad] of every rigid branch: the cap area
    (D/2π) feeding the extension, −rod area feeding the retraction, 0 closed.  With rigid oil the
    flow P → actuator is this rate times the velocity, whatever its sign (an overrunning load pushes
    oil back into P)."""
    direction = rigid_direction(model, spool)
    return np.where(direction > 0, model.rigid_extend_area, np.where(direction < 0, -model.rigid_retract_area, 0.0))


def rigid_metering_area(model, spool):
    """Open area [m²] of each rigid branch's metering edges (P → inlet, outlet → T) at ``spool``."""
    s = np.abs(spool[model.rigid_valve])
    return model.rigid_base_area + model.rigid_max_area * laws.metering_opening(s, model.valve_overlap[model.rigid_valve])


def law_pieces(model, pressure) -> np.ndarray:
    """Which piece of its piecewise law every switching branch is on at ``pressure`` [Pa] (int array: pump
    compensators, then every law branch: relief ramps and check-valve openings by their own formulas here, the
    other law components by their kink hook; see :func:`laws.ramp_piece`).

    A step whose start and end differ here crosses a kink of the flow laws (a relief cracking, a check
    valve opening fully, a compensator engaging): one Jacobian of the start does not describe it.
    """
    dp = pressure[model.branch_from] - pressure[model.branch_to]
    sl = model.branch_slices
    relief = laws.ramp_piece(dp[model.relief_branches] - model.relief_cracking,
                             RELIEF_REGULARISATION * model.relief_cracking)
    check = _check_parameters(model)
    check = laws.clip_piece((dp[model.law_branches("check_valve")] - check["cracking"]) / (check["full_open"] - check["cracking"]))
    outlet = pressure[model.branch_to[_pump_branches(model)]]
    pumps = iter(laws.clip_piece((model.pump_compensator + model.pump_band - outlet) / model.pump_band))
    own = {ReliefValve: iter(relief), CheckValve: iter(check), PumpFixed: pumps, PumpCompensated: pumps}
    law = []  # the law branches: the component's own kink hook at its states at rest over a zero step, 0 without one
    for i, b in enumerate(range(*sl["law"].indices(len(model.branch_names))) if "law" in sl else ()):
        cls = BRANCH_LAWS[model.law_kind[i]]
        if cls in own:
            law.append(next(own[cls]))
            continue
        piece = getattr(cls, "LAW_PIECE", None)
        first = model.law_state_offset[i]
        start = model.component_state_start[first:first + len(law_states(cls))].copy()
        pilot = model.branch_pilot[b]
        law.append(0 if piece is None else piece(model.law_table[i], start, 0.0, pressure[model.branch_from[b]],
                                                  pressure[model.branch_to[b]], pressure[pilot] if pilot >= 0 else 0.0))
    return np.array(law, int)


def _pump_branches(model) -> slice:
    """The branches of the fixed-displacement and compensated pumps (the last two laws, adjacent)."""
    return slice(model.law_branches("pump_fixed").start, model.law_branches("pump_compensated").stop)


def _check_parameters(model) -> dict:
    """The check valves' parameters by name (cracking, full_open [Pa], area, leakage [m²], cd [-]), from the
    components of the circuit in the order of ``model.law_branches("check_valve")``."""
    names = model.branch_names[model.law_branches("check_valve")]
    params = [model.circuit.component(name).params for name in names]
    return {key: np.array([getattr(p, field) for p in params], float) for key, field in
            (("cracking", "cracking_pressure"), ("full_open", "full_open_pressure"), ("area", "area"),
             ("leakage", "leakage_area"), ("cd", "discharge_coefficient"))}


def branch_flows(model, pressure, orifice_area, pump_speed, actuator_velocity) -> BranchFlows:
    """Flow [m³/s] of every branch and its pressure derivatives (arguments as ``NetworkModel.branch_flows``)."""
    fluid = model.fluid
    dp = pressure[model.branch_from] - pressure[model.branch_to]
    nb = len(model.branch_names)
    flow = np.zeros(nb)
    dfrom = np.zeros(nb)
    dto = np.zeros(nb)
    sl = model.branch_slices

    s = sl["orifice"]
    q, g = laws.orifice_flow_with_derivative(orifice_area[s], model.orifice_cd, dp[s], fluid.density, fluid.kinematic_viscosity)
    flow[s], dfrom[s], dto[s] = q, g, -g

    s, conductance = model.law_branches(LaminarResistance), model.law_parameter(LaminarResistance, "conductance")
    flow[s] = conductance * dp[s]
    dfrom[s], dto[s] = conductance, -conductance

    s = model.law_branches("orifice")  # the fixed orifices, from the circuit's parameters
    params = [model.circuit.component(name).params for name in model.branch_names[s]]
    q, g = laws.orifice_flow_with_derivative(np.array([p.area for p in params], float),
                                             np.array([p.discharge_coefficient for p in params], float),
                                             dp[s], fluid.density, fluid.kinematic_viscosity)
    flow[s], dfrom[s], dto[s] = q, g, -g

    s = model.relief_branches
    q, g = laws.relief_flow_with_derivative(
        dp[s], model.relief_cracking, model.relief_gradient, RELIEF_REGULARISATION * model.relief_cracking
    )
    flow[s], dfrom[s], dto[s] = q, g, -g

    s, check = model.law_branches("check_valve"), _check_parameters(model)
    area, darea = laws.check_valve_area_with_derivative(dp[s], check["cracking"], check["full_open"], check["area"], check["leakage"])
    q, g = laws.orifice_flow_with_derivative(area, check["cd"], dp[s], fluid.density, fluid.kinematic_viscosity)
    g = g + laws.orifice_flow_area_derivative(area, check["cd"], dp[s], fluid.density, fluid.kinematic_viscosity) * darea
    flow[s], dfrom[s], dto[s] = q, g, -g

    s = _pump_branches(model)
    outlet = pressure[model.branch_to[s]]
    displacement, ddisp = laws.compensated_displacement_with_derivative(
        model.pump_displacement, outlet, model.pump_compensator, model.pump_band
    )
    speed = pump_speed[model.pump_index]
    flow[s] = laws.pump_flow(displacement, speed, model.pump_efficiency)
    dto[s] = laws.pump_flow(ddisp, speed, model.pump_efficiency)

    s, shaft, displacement = _motor_branches(model)
    flow[s] = laws.motor_flow(displacement, actuator_velocity[shaft])

    s = sl["rigid"]
    if s.stop > s.start:
        flow[s] = orifice_area[sl["orifice"].stop:] * actuator_velocity[model.rigid_branch_actuator]

    s = sl.get("law", slice(0, 0))
    if s.stop == s.start:
        return BranchFlows(flow, dfrom, dto)
    dpilot = np.zeros(nb)
    for i, b in enumerate(range(s.start, s.stop)):  # the compiled law of each other component, called from Python
        pilot = model.branch_pilot[b]
        cls = BRANCH_LAWS[model.law_kind[i]]
        if cls in (LaminarResistance, Orifice, ReliefValve, CheckValve, PumpFixed, PumpCompensated, Motor):  # above, by the
            # formulas of reference.laws
            continue
        ports = (pressure[model.branch_from[b]], pressure[model.branch_to[b]], pressure[pilot] if pilot >= 0 else 0.0)
        first = model.law_input_offset[i]  # its scheduled inputs, read from the pump-speed vector
        inputs = (pump_speed[first:first + len(law_inputs(cls))].copy(),) if law_inputs(cls) else ()
        if law_states(cls):  # at the component's states at rest, over a step of zero length
            first = model.law_state_offset[i]
            start = model.component_state_start[first:first + len(law_states(cls))].copy()
            flow[b], dfrom[b], dto[b], dpilot[b] = cls.BRANCH_LAW(model.law_table[i], start, 0.0, *ports, *inputs)
        else:
            flow[b], dfrom[b], dto[b], dpilot[b] = cls.BRANCH_LAW(model.law_table[i], *ports, *inputs)
    return BranchFlows(flow, dfrom, dto, dpilot)


def flow_jacobian(model, flows: BranchFlows) -> np.ndarray:
    """∂(net inflow)/∂p, shape (node_count, node_count) [m³/(s·Pa)]."""
    n = model.node_count
    d = np.zeros((len(model.branch_names), n))
    idx = np.arange(len(model.branch_names))
    np.add.at(d, (idx, model.branch_from), flows.dflow_dfrom)
    np.add.at(d, (idx, model.branch_to), flows.dflow_dto)
    if flows.dflow_dpilot is not None:
        piloted = model.branch_pilot >= 0
        np.add.at(d, (idx[piloted], model.branch_pilot[piloted]), flows.dflow_dpilot[piloted])
    return model.incidence @ d


def _motor_branches(model) -> tuple:
    """The motors' flow branches (a slice; rigid motors have none), each one's actuator (its shaft speed's index into
    the actuator velocities) and displacement [m³/rev], from the circuit's components of those names."""
    s = model.law_branches("motor")
    names = model.branch_names[s]
    displacement = np.array([model.circuit.component(name).params.displacement for name in names], float)
    return s, np.array([model.actuator(name) for name in names], int), displacement


def flow_velocity_gradient(model, orifice_area=None) -> np.ndarray:
    """∂(net inflow)/∂v_actuator [m² or m³/rad], shape (node_count, actuator_count): motor branches and,
    given ``orifice_area`` from :meth:`valve_areas`, rigid branches."""
    grad = np.zeros((model.node_count, model.actuator_count))
    s, shaft, displacement = _motor_branches(model)
    rate = displacement / (2.0 * np.pi)
    np.add.at(grad, (model.branch_from[s], shaft), -rate)
    np.add.at(grad, (model.branch_to[s], shaft), rate)
    s = model.branch_slices.get("rigid", slice(0, 0))
    if s.stop > s.start:
        rate = orifice_area[model.branch_slices["orifice"].stop:]
        np.add.at(grad, (model.branch_from[s], model.rigid_branch_actuator), -rate)
        np.add.at(grad, (model.branch_to[s], model.rigid_branch_actuator), rate)
    return grad


# ----------------------------------------------------------- efforts
def pressure_effort(model, pressure):
    """Effort of the pressures on every actuator, shape (actuator_count,).

    Cylinders: p_cap·A_cap − p_rod·A_rod − p_amb·(A_cap − A_rod) [N], with
    the ambient pressure = the fluid's reference pressure.  Motors:
    τ = D·(p_a − p_b)/(2π) [N·m].
    """
    effort = np.zeros(model.actuator_count)
    if len(model.cylinder_actuator):
        effort[model.cylinder_actuator] = laws.cylinder_pressure_force(
            pressure[model.cylinder_cap_node], pressure[model.cylinder_rod_node],
            model.cylinder_cap_area, model.cylinder_rod_area, model.fluid.reference_pressure,
        )
    if len(model.motor_actuator):
        effort[model.motor_actuator] = laws.pump_torque(
            model.motor_displacement, pressure[model.motor_a_node] - pressure[model.motor_b_node]
        )
    return effort


def friction_effort(model, velocity, pressure=None, position=None):
    """Seal friction and end cushions acting on every actuator (−F_f(v) − F_k(x, v), opposing motion) and its
    velocity derivative (a central difference for the cushions), with the seal load of the node ``pressure`` and
    the cushions at the actuator ``position`` (None: none)."""
    effort = np.zeros(model.actuator_count)
    slope = np.zeros(model.actuator_count)
    for c, a in enumerate(model.cylinder_actuator):
        seal = 0.0 if pressure is None else laws.seal_load(
            pressure[model.cylinder_cap_node[c]], pressure[model.cylinder_rod_node[c]], model.cylinder_cap_area[c],
            model.cylinder_rod_area[c], model.fluid.reference_pressure, model.cylinder_pressure_friction[c])
        friction, dfriction, _ = laws.friction_force_with_derivative(
            velocity[a], model.cylinder_coulomb[c], model.cylinder_static[c],
            model.cylinder_stribeck[c], model.cylinder_viscous[c], seal,
        )
        effort[a] = -friction
        slope[a] = -dfriction
        if position is not None:
            def cushion(v):
                return laws.cushion_force(
                    position[a], v, model.cylinder_stroke[c], model.cylinder_cap_area[c], model.cylinder_rod_area[c],
                    model.cylinder_cushion_length_cap[c], model.cylinder_cushion_length_rod[c],
                    model.cylinder_cushion_area_cap[c], model.cylinder_cushion_area_rod[c], model.cylinder_cushion_cd[c],
                    model.fluid.density, model.cylinder_cushion_check[c] == 1.0)
            h = 1e-7 * max(abs(velocity[a]), 1e-6)
            effort[a] -= cushion(velocity[a])
            slope[a] -= (cushion(velocity[a] + h) - cushion(velocity[a] - h)) / (2 * h)
    return effort, slope


def actuator_effort(model, pressure, velocity, position=None):
    """Total effort (pressure + friction) on every actuator and its derivative with respect to its own velocity.

    The derivative is the friction slope only (the pressure part depends on
    v through the network; see :meth:`StepperImplicitEuler.linearize`).
    """
    friction, slope = friction_effort(model, velocity, pressure, position)
    return pressure_effort(model, pressure) + friction, slope


def effort_pressure_gradient(model) -> np.ndarray:
    """∂effort/∂p_node, shape (actuator_count, node_count) [m² or m³/rad]."""
    grad = np.zeros((model.actuator_count, model.node_count))
    np.add.at(grad, (model.cylinder_actuator, model.cylinder_cap_node), model.cylinder_cap_area)
    np.add.at(grad, (model.cylinder_actuator, model.cylinder_rod_node), -model.cylinder_rod_area)
    rate = model.motor_displacement / (2.0 * np.pi)
    np.add.at(grad, (model.motor_actuator, model.motor_a_node), rate)
    np.add.at(grad, (model.motor_actuator, model.motor_b_node), -rate)
    return grad


def chamber_stiffness(model, pressure, position, volumes=None):
    """Hydraulic stiffness β_eff·A²/V [N/m] of every cylinder's cap and rod chamber, shape (..., 2, cylinder_count).

    ``volumes`` may pass :meth:`node_volume_at` of the same state to save recomputing it.
    """
    volumes = node_volume_at(model, position, pressure) if volumes is None else volumes
    beta = effective_bulk_modulus(model, pressure, position, volumes)
    chambers = np.concatenate([model.cylinder_cap_node, model.cylinder_rod_node])  # cap row, then rod row
    area = np.concatenate([model.cylinder_cap_area, model.cylinder_rod_area])
    stiffness = laws.hydraulic_stiffness(beta.take(chambers, axis=-1), area, volumes[0].take(chambers, axis=-1))
    return stiffness.reshape(stiffness.shape[:-1] + (2, len(model.cylinder_cap_node)))
