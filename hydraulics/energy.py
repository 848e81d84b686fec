"""Energy bookkeeping of a network: oil stored energy and branch powers.

With the oil content m as state, the energy stored in a node of geometric
volume V_g and pressure-dependent extra volume V_e(p) (hose walls,
accumulators) is

    U = m·μ(p) − V_g·(p − p_ref) − ∫_{p_ref}^{p} V_e(p') dp',

with μ the pressure potential of :meth:`hydraulics.fluid.Fluid.pressure_potential`
(∂U/∂m = μ, ∂U/∂V_g = −(p − p_ref)).  A branch carrying Q from node i to node j
exchanges Q·(μ_i − μ_j): dissipated in orifices, valves and leaks, supplied by
pumps, passed to the shaft of motors.  The sum closes exactly in continuous
time; a stepper's residual is its numerical dissipation.
"""

from __future__ import annotations

import numpy as np

from . import laws

from .network import NetworkModel, NetworkState

ACCUMULATOR_QUADRATURE_POINTS = 16  # Gauss–Legendre points for ∫ V_liquid dp


def stored_energy(model: NetworkModel, state: NetworkState) -> float:
    """Elastic energy in the oil of all free nodes [J], relative to the reference pressure."""
    fluid = model.fluid
    p = state.node_pressure
    free = ~model.node_fixed
    dp = p - fluid.reference_pressure
    volume, _ = model.node_volume_at(state.actuator_position, p)
    extra_integral = 0.5 * model.node_wall_compliance * dp**2
    wall = model.node_wall_compliance * dp
    geometric = volume - wall
    if len(model.accumulator_node):
        nodes, weights = np.polynomial.legendre.leggauss(ACCUMULATOR_QUADRATURE_POINTS)
        pa = p[model.accumulator_node]
        p0 = np.minimum(model.accumulator_precharge, pa)
        half, mid = 0.5 * (pa - p0), 0.5 * (pa + p0)
        liquid = laws.accumulator_liquid_volume_with_derivative(
            mid[:, None] + half[:, None] * nodes, model.accumulator_gas_volume[:, None],
            model.accumulator_precharge[:, None], model.accumulator_index[:, None],
        )[0]
        np.add.at(extra_integral, model.accumulator_node, half * (liquid @ weights))
        current = laws.accumulator_liquid_volume_with_derivative(
            pa, model.accumulator_gas_volume, model.accumulator_precharge, model.accumulator_index
        )[0]
        np.add.at(geometric, model.accumulator_node, -current)
    energy = state.node_oil * fluid.pressure_potential(p) - geometric * dp - extra_integral
    return float(np.sum(energy[free]))


def branch_powers(model: NetworkModel, state: NetworkState, flow: np.ndarray) -> dict:
    """Power of each branch family [W] at the given pressures and branch flows.

    Returns ``{"pump": supplied by pumps, "motor": delivered to motor shafts,
    "dissipated": lost in orifices, valves, reliefs, checks and leaks}``.
    """
    mu = model.fluid.pressure_potential(state.node_pressure)
    power = flow * (mu[model.branch_from] - mu[model.branch_to])
    sl = model.branch_slices
    dissipative = np.concatenate([power[sl[k]] for k in ("orifice", "laminar", "relief", "check")])
    return {"pump": float(-np.sum(power[sl["pump"]])), "motor": float(np.sum(power[sl["motor"]])), "dissipated": float(np.sum(dissipative))}


# ------------------------------------------------------------------ batches of samples
# The same laws over many samples at once (rows = samples), for the run logger: one numpy
# expression per term for a whole batch instead of one per sample.  Each row equals the
# single-sample function of the same state to round-off.
def node_volumes_batch(model: NetworkModel, position, pressure):
    """Node volumes V(x, p) [m³] and ∂V/∂p [m³/Pa] of many samples.

    ``position`` has shape (samples, actuator_count) [m or rad], ``pressure``
    (samples, node_count) [Pa]; row i equals ``model.node_volume_at(position[i], pressure[i])``.
    """
    position = np.asarray(position, dtype=float)
    pressure = np.asarray(pressure, dtype=float)
    rows = np.s_[:]
    volume = np.repeat(model.node_volume[None, :], len(pressure), axis=0)
    if len(model.cylinder_cap_node):
        vc, vr, _, _ = laws.chamber_volumes(
            position[:, model.cylinder_actuator], model.cylinder_stroke, model.cylinder_cap_area,
            model.cylinder_rod_area, model.cylinder_dead_cap, model.cylinder_dead_rod,
        )
        np.add.at(volume, (rows, model.cylinder_cap_node), vc)
        np.add.at(volume, (rows, model.cylinder_rod_node), vr)
    extra = model.node_wall_compliance * (pressure - model.fluid.reference_pressure)
    dextra = np.repeat(model.node_wall_compliance[None, :], len(pressure), axis=0)
    if len(model.accumulator_node):
        liquid, dliquid = laws.accumulator_liquid_volume_with_derivative(
            pressure[:, model.accumulator_node], model.accumulator_gas_volume, model.accumulator_precharge,
            model.accumulator_index,
        )
        np.add.at(extra, (rows, model.accumulator_node), liquid)
        np.add.at(dextra, (rows, model.accumulator_node), dliquid)
    return volume + extra, dextra


def chamber_stiffness_batch(model: NetworkModel, pressure, position, volumes=None):
    """β_eff·A²/V [N/m] of every cylinder's cap and rod chamber for many samples, shape (samples, 2, cylinder_count).

    Row i equals ``model.chamber_stiffness(pressure[i], position[i])``; ``volumes``
    may pass :func:`node_volumes_batch` of the same samples to save recomputing them.
    """
    pressure = np.asarray(pressure, dtype=float)
    volume, dvdp = node_volumes_batch(model, position, pressure) if volumes is None else volumes
    safe = np.where(model.node_fixed, 1.0, volume)  # as NetworkModel.effective_bulk_modulus
    phi, dphi = model.fluid.fill_ratio(pressure)
    beta = safe * phi / (dvdp * phi + safe * dphi)
    cap, rod = model.cylinder_cap_node, model.cylinder_rod_node
    return np.stack(
        [
            laws.hydraulic_stiffness(beta[:, cap], model.cylinder_cap_area, volume[:, cap]),
            laws.hydraulic_stiffness(beta[:, rod], model.cylinder_rod_area, volume[:, rod]),
        ],
        axis=1,
    )


def stored_energy_batch(model: NetworkModel, oil, pressure, position, volumes=None) -> np.ndarray:
    """Elastic energy in the oil of all free nodes [J] for many samples, shape (samples,).

    ``oil`` and ``pressure`` have shape (samples, node_count) [m³, Pa], ``position``
    (samples, actuator_count); row i equals :func:`stored_energy` of that state.
    ``volumes`` may pass :func:`node_volumes_batch` of the same samples.
    """
    fluid = model.fluid
    p = np.asarray(pressure, dtype=float)
    oil = np.asarray(oil, dtype=float)
    rows = np.s_[:]
    dp = p - fluid.reference_pressure
    volume = (node_volumes_batch(model, position, p) if volumes is None else volumes)[0]
    extra_integral = 0.5 * model.node_wall_compliance * dp**2
    wall = model.node_wall_compliance * dp
    geometric = volume - wall
    if len(model.accumulator_node):
        nodes, weights = np.polynomial.legendre.leggauss(ACCUMULATOR_QUADRATURE_POINTS)
        pa = p[:, model.accumulator_node]
        p0 = np.minimum(model.accumulator_precharge, pa)
        half, mid = 0.5 * (pa - p0), 0.5 * (pa + p0)
        liquid = laws.accumulator_liquid_volume_with_derivative(
            mid[..., None] + half[..., None] * nodes, model.accumulator_gas_volume[:, None],
            model.accumulator_precharge[:, None], model.accumulator_index[:, None],
        )[0]
        np.add.at(extra_integral, (rows, model.accumulator_node), half * (liquid @ weights))
        current = laws.accumulator_liquid_volume_with_derivative(
            pa, model.accumulator_gas_volume, model.accumulator_precharge, model.accumulator_index
        )[0]
        np.add.at(geometric, (rows, model.accumulator_node), -current)
    energy = oil * fluid.pressure_potential(p) - geometric * dp - extra_integral
    return np.sum(energy[:, ~model.node_fixed], axis=1)
