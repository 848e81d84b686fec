"""Energy bookkeeping of a network: oil stored energy and branch powers.

With the oil content m as state, the energy stored in a node of geometric
volume V_g and pressure-dependent extra volume V_e(p) (hose walls,
accumulators) is

    U = m·μ(p) − V_g·(p − p_ref) − ∫_{p_ref}^{p} V_e(p') dp',

with μ the pressure potential of :meth:`hydraulics.fluid.Fluid.pressure_potential`
(∂U/∂m = μ, ∂U/∂V_g = −(p − p_ref)).  A branch carrying Q from node i to node j
exchanges Q·(μ_i − μ_j): dissipated in orifices, valves and leaks, supplied by
pumps, passed to the shaft of motors.  A fixed node off the reference pressure (a
pressure source) supplies μ(p)·(its net outflow).  The sum closes exactly in
continuous time; a stepper's residual is its numerical dissipation.
"""

from __future__ import annotations

import numpy as np

from .network import NetworkModel, NetworkState

ACCUMULATOR_QUADRATURE_POINTS = 16  # Gauss–Legendre points for ∫ V_liquid dp


def stored_energy(model: NetworkModel, state: NetworkState) -> float:
    """Elastic energy in the oil of all free nodes [J], relative to the reference pressure."""
    return float(stored_energy_at(model, state.node_oil, state.node_pressure, state.actuator_position))


def stored_energy_at(model: NetworkModel, oil, pressure, position, volumes=None):
    """Elastic energy in the oil of all free nodes [J] at oil content ``oil`` [m³], ``pressure`` [Pa], ``position`` [m or rad].

    Broadcasts over leading axes like the node relations of :class:`NetworkModel`:
    ``oil`` and ``pressure`` of shape (..., node_count), ``position`` (..., actuator_count)
    give shape (...), one energy per sample.  ``volumes`` may pass
    :meth:`NetworkModel.node_volume_at` of the same samples to save recomputing it.
    At the ``incompressible`` level the oil is rigid and stores nothing: zero (its pressures are derived from the
    efforts, not states whose compression holds energy).
    """
    fluid = model.fluid
    p = np.asarray(pressure, dtype=float)
    if getattr(model, "fidelity", "") == "incompressible":
        return np.zeros(p.shape[:-1])[()]
    dp = p - fluid.reference_pressure
    volume = (model.node_volume_at(position, p) if volumes is None else volumes)[0]
    extra_integral = 0.5 * model.node_wall_compliance * dp**2
    wall = model.node_wall_compliance * dp
    geometric = volume - wall
    if len(model.accumulator_node):
        nodes, weights = np.polynomial.legendre.leggauss(ACCUMULATOR_QUADRATURE_POINTS)
        pa = p.take(model.accumulator_node, axis=-1)
        p0 = np.minimum(model.accumulator_precharge, pa)
        half, mid = 0.5 * (pa - p0), 0.5 * (pa + p0)
        at = mid[..., None, :] + half[..., None, :] * nodes[:, None]  # (..., point, accumulator)
        liquid = model.accumulator_liquid_volume(at)[0]
        np.add.at(extra_integral, (..., model.accumulator_node), half * _ordered_sum(liquid * weights[:, None], -2))
        current = model.accumulator_liquid_volume(pa)[0]
        np.add.at(geometric, (..., model.accumulator_node), -current)
    energy = oil * fluid.pressure_potential(p) - geometric * dp - extra_integral
    return _ordered_sum(energy[..., ~model.node_fixed], -1)


def _ordered_sum(terms, axis):
    """Sum of ``terms`` along ``axis``, term by term in index order: the same float for a sample alone as within any
    batch of samples (``np.sum``'s blocked pairwise order depends on the array's shape, so a logged value would
    change in its last bits with the size of the batch it is derived in)."""
    terms = np.moveaxis(np.asarray(terms, dtype=float), axis, 0)
    if not len(terms):
        return np.zeros(terms.shape[1:])[()]
    total = terms[0] + 0.0
    for term in terms[1:]:
        total = total + term
    return total


def branch_powers(model: NetworkModel, state: NetworkState, flow: np.ndarray) -> dict:
    """Power of each branch family [W] at the given pressures and branch flows.

    Returns ``{"pump": supplied by pumps and pressure sources, "source": of that, supplied by pressure sources,
    "motor": delivered to motor shafts, "dissipated": lost in orifices, valves, reliefs, checks and leaks,
    "rigid": delivered to rigid actuators (their metering loss and their work)}``.

    A pressure source is a fixed node whose pressure differs from the reference pressure (a ``pressure_source``,
    or a tank set off it); it supplies μ(p)·(its net outflow) (:func:`source_power`).
    """
    mu = model.fluid.pressure_potential(state.node_pressure)
    power = flow * (mu[model.branch_from] - mu[model.branch_to])
    sl = model.branch_slices
    pumps, shafts, dissipative = model.ledger_branches
    supplied = source_power(model, flow)
    return {"pump": float(-np.sum(power[pumps])) + supplied, "source": supplied,
            "motor": float(np.sum(power[shafts])), "dissipated": float(np.sum(power[dissipative])),
            "rigid": float(np.sum(power[sl["rigid"]]))}


def source_power(model: NetworkModel, flow: np.ndarray) -> float:
    """Power [W] the pressure sources deliver: Σ over the fixed nodes k off the reference pressure of
    μ(p_k)·(Σ Q of the branches leaving k − Σ Q of those entering k), with the branch flows ``flow`` [m³/s].

    The branch powers Q·(μ_from − μ_to) sum to Σ over all nodes of μ·(net outflow); over the free nodes that is the
    change of their stored oil energy, so the fixed nodes' share is the work they supply (zero for a tank at the
    reference pressure, where μ = 0).  A rigid actuator's chambers are fixed nodes at the reference: none."""
    mu = model.source_potential_ends
    if mu is None:
        return 0.0
    flow = np.asarray(flow, float)
    return float(flow @ mu[0] - flow @ mu[1])
