"""The backward-Euler stepper (compiled kernels) agrees with its numpy oracle (``tests/reference/newton.py``) to
round-off, step by step."""

import numpy as np
import pytest

from conftest import MODELS, network_from_toml
from hydraulics._compiled import elimination_order
from hydraulics.circuit import load_circuit
from hydraulics.network import NetworkModel
from hydraulics import numerics
from hydraulics.steppers import ActuatorMotion, StepperImplicitEuler
from reference.newton import StepperImplicitEulerOracle
from test_network import ALL_KINDS

DT = 1e-3  # s
CIRCUITS = {
    "boom": MODELS / "boom" / "boom.circuit.toml",
    "excavator": MODELS / "excavator" / "excavator.circuit.toml",
    "seed_cylinder": MODELS / "seed_cylinder" / "seed_cylinder.circuit.toml",
    "lift": MODELS / "lift_1dof" / "lift.circuit.toml",
    "all_kinds": None,
}
PRESSURE_RTOL, PRESSURE_ATOL = 1e-9, 1e-3  # -, Pa
OIL_RTOL = 1e-9
LINEARIZATION_RTOL = 1e-8

# the excavator with its front and swing rigid (incompressible among compressible actuators): rigid branches, whose
# flow is the displaced rate r(spool)·v, and a rigid motor without a motor branch
RIGID_FRONT = {"stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"}
_models = {}


def model(name) -> NetworkModel:
    if name not in _models:
        if name == "excavator_rigid":
            _models[name] = NetworkModel.from_circuit(load_circuit(CIRCUITS["excavator"]), actuator_fidelity=RIGID_FRONT)
        else:
            path = CIRCUITS[name]
            _models[name] = network_from_toml(ALL_KINDS) if path is None else NetworkModel.from_circuit(load_circuit(path))
    return _models[name]


def start_state(m: NetworkModel):
    x0 = np.where(m.actuator_kind == 0, 0.5 * _strokes(m), 0.0)
    p0 = np.full(m.node_count, 3e6)
    if len(m.accumulator_node):  # the pump cannot charge the accumulator to the relief in time: start above it
        p0[m.accumulator_node] = 1.02 * np.min(m.relief_cracking)
    return m.state(actuator_position=x0, node_pressure=p0)


def _strokes(m):
    stroke = np.ones(m.actuator_count)
    stroke[m.cylinder_actuator] = m.cylinder_stroke
    return stroke


def motion_at(m, t, amplitude):
    """Smooth prescribed actuator motion: x = x_mid + a·sin(2πft + k); motors turn at a sine speed."""
    k = np.arange(m.actuator_count)
    omega = 2 * np.pi * 1.5
    scale = np.where(m.actuator_kind == 0, amplitude * _strokes(m), 3.0)
    mid = np.where(m.actuator_kind == 0, 0.5 * _strokes(m), 0.0)
    return mid + scale * np.sin(omega * t + k), scale * omega * np.cos(omega * t + k)


def command_at(m, n):
    """Valves closed for 100 steps (pump on: supply climbs to the relief, moving actuators cavitate a chamber),
    then slammed open, shut, reversed and shut every 50 steps."""
    if n < 100:
        return np.zeros(len(m.valve_names))
    phase = (n - 100) // 50 + np.arange(len(m.valve_names))
    return np.array([1.0, 0.0, -1.0, 0.0])[phase % 4]


def assert_states_close(a, b, where):
    np.testing.assert_allclose(b.node_pressure, a.node_pressure, rtol=PRESSURE_RTOL, atol=PRESSURE_ATOL, err_msg=where)
    np.testing.assert_allclose(b.node_oil, a.node_oil, rtol=OIL_RTOL, atol=0.0, err_msg=where)  # NaN == NaN on tanks
    np.testing.assert_array_equal(b.valve_spool, a.valve_spool, err_msg=where)


def run_both(name, steps=300, amplitude=0.05, substeps=1):
    m = model(name)
    pure = StepperImplicitEulerOracle(m, substeps=substeps)
    fast = StepperImplicitEuler(m, substeps=substeps)
    sa = sb = start_state(m)
    control = m.control()
    floor_hit = relief_flow = 0.0
    history = []
    relief = m.relief_branches
    for n in range(steps):
        control.valve_command[:] = command_at(m, n)
        x0, v0 = motion_at(m, n * DT, amplitude)
        x1, v1 = motion_at(m, (n + 1) * DT, amplitude)
        motion = ActuatorMotion(x0, x1, v0, v1)
        history.append((sa, control.valve_command.copy(), v1))
        sa, ra = pure.step(sa, control, motion, DT)
        sb, rb = fast.step(sb, control, motion, DT)
        where = f"{name} step {n}"
        assert (rb.status, rb.newton_iterations, rb.rhs_evaluations, rb.jacobian_evaluations) == (
            ra.status, ra.newton_iterations, ra.rhs_evaluations, ra.jacobian_evaluations), where
        assert rb.residual == pytest.approx(ra.residual, rel=1e-6, abs=1e-3), where  # Newton tolerance is 1e-2 Pa
        np.testing.assert_allclose(rb.branch_flow, ra.branch_flow, rtol=1e-7, atol=1e-12, err_msg=where)
        assert_states_close(sa, sb, where)
        floor_hit = max(floor_hit, np.sum(sa.node_pressure[m.free_nodes] <= m.fluid.pressure_floor))
        relief_flow = max(relief_flow, np.max(ra.branch_flow[relief], initial=0.0))
    assert (pure.rhs_count, pure.jacobian_count) == (fast.rhs_count, fast.jacobian_count)
    return m, history, floor_hit, relief_flow


_histories = {}


@pytest.mark.parametrize("name", list(CIRCUITS))
def test_steps_match_oracle(name):
    m, _histories[name], floor_hit, relief_flow = run_both(name)
    if name != "seed_cylinder":  # the seed has no cavitation floor and no relief valve
        assert floor_hit, "the scenario should make a chamber cavitate"
        assert relief_flow > 0, "the scenario should open a relief valve"


def test_hard_motion_and_substeps_match():
    """Large, fast strokes (deep cavitation, pressure spikes) with two substeps per step."""
    run_both("lift", steps=200, amplitude=0.3, substeps=2)
    run_both("all_kinds", steps=150, amplitude=0.3, substeps=2)


def test_rigid_actuators_match_oracle():
    """A network with rigid actuators (rigid branches Q = r(spool)·v from each rigid valve's P to T, a rigid motor):
    steps, and both linearisations, as the oracle's to round-off; the rigid branches carry the displaced flow."""
    m = model("excavator_rigid")
    assert np.any(m.actuator_rigid) and len(m.rigid_branch_actuator) == 3
    _, history, _, _ = run_both("excavator_rigid", steps=200, amplitude=0.1)
    rigid = m.branch_slices["rigid"]
    pure, fast = StepperImplicitEulerOracle(m), StepperImplicitEuler(m)
    control = m.control()
    moved = 0.0
    for state, command, velocity in history[100::20]:
        control.valve_command[:] = command
        for newton in (True, False):
            a = pure.linearize(state, control, velocity, DT, newton=newton)
            b = fast.linearize(state, control, velocity, DT, newton=newton)
            rel = LINEARIZATION_RTOL
            np.testing.assert_allclose(b.effort, a.effort, rtol=rel, atol=rel * np.max(np.abs(a.effort)))
            g = a.oil_velocity_gradient
            np.testing.assert_allclose(b.oil_velocity_gradient, g, rtol=rel, atol=rel * np.max(np.abs(g)))
            assert_states_close(a.state, b.state, "excavator_rigid linearize")
            moved = max(moved, np.max(np.abs(b.report.branch_flow[rigid])))
    assert moved > 0  # the rigid branches carried flow


@pytest.mark.parametrize("newton", [True, False], ids=["newton", "one-step"])
@pytest.mark.parametrize("name", list(CIRCUITS))
def test_linearize_matches_oracle(name, newton):
    m = model(name)
    history = _histories.get(name) or run_both(name)[1]
    pure, fast = StepperImplicitEulerOracle(m), StepperImplicitEuler(m)
    control = m.control()
    for state, command, velocity in history[::25]:
        control.valve_command[:] = command
        a = pure.linearize(state, control, velocity, DT, newton=newton)
        b = fast.linearize(state, control, velocity, DT, newton=newton)
        rel = LINEARIZATION_RTOL
        scale = np.max(np.abs(a.effort_velocity_gradient))
        np.testing.assert_allclose(b.effort, a.effort, rtol=rel, atol=rel * np.max(np.abs(a.effort)))
        np.testing.assert_allclose(b.effort_velocity_gradient, a.effort_velocity_gradient, rtol=rel, atol=rel * scale)
        np.testing.assert_array_equal(b.velocity, a.velocity)
        assert_states_close(a.state, b.state, f"{name} linearize")
        np.testing.assert_allclose(b.state.actuator_position, a.state.actuator_position, rtol=1e-15)
        assert b.state.time == a.state.time
        assert b.report.newton_iterations == a.report.newton_iterations
        # ∂m⁺/∂v (the linearly implicit finish and the finish's Newton start use it)
        g = a.oil_velocity_gradient
        assert g.shape == (m.node_count, m.actuator_count) and not np.any(g[m.node_fixed])
        np.testing.assert_allclose(b.oil_velocity_gradient, g, rtol=rel, atol=rel * np.max(np.abs(g)))


@pytest.mark.parametrize("name", ["excavator", "lift"])
def test_warm_started_steps_match_oracle(name):
    """Newton started from a prediction of the end oil (as the implicit coupling's finish does), 1 and 2 substeps:
    same iterations and states in both paths, and within the Newton tolerance of the cold start.  (Along these
    valve slams the prediction at v = 0 is poor; along the coupled dig it halves the finish's iterations, see
    bench/bench_fast.py.)"""
    m = model(name)
    history = _histories.get(name) or run_both(name)[1]
    control = m.control()
    for substeps in (1, 2):
        pure, fast = StepperImplicitEulerOracle(m, substeps=substeps), StepperImplicitEuler(m, substeps=substeps)
        for n, (state, command, velocity) in enumerate(history[::10]):
            control.valve_command[:] = command
            lin = pure.linearize(state, control, np.zeros(m.actuator_count), DT)
            guess = lin.state.node_oil + lin.oil_velocity_gradient @ velocity
            motion = ActuatorMotion(state.actuator_position, state.actuator_position + DT * velocity, velocity, velocity)
            sa, ra = pure.step(state, control, motion, DT, oil_guess=guess)
            sb, rb = fast.step(state, control, motion, DT, oil_guess=guess)
            assert (ra.status, ra.newton_iterations, ra.rhs_evaluations) == (rb.status, rb.newton_iterations,
                                                                              rb.rhs_evaluations)
            where = f"{name} warm step {n}, {substeps} substeps"
            np.testing.assert_allclose(sb.node_pressure, sa.node_pressure, rtol=PRESSURE_RTOL, atol=PRESSURE_ATOL, err_msg=where)
            np.testing.assert_allclose(sb.node_oil, sa.node_oil, rtol=OIL_RTOL, atol=0.0, err_msg=where)
            np.testing.assert_allclose(sb.valve_spool, sa.valve_spool, rtol=1e-13, atol=1e-15, err_msg=where)  # exp()s
            sc, rc = pure.step(state, control, motion, DT)
            np.testing.assert_allclose(sa.node_pressure, sc.node_pressure, rtol=1e-8, atol=0.1)  # Newton tolerance
            assert rc.success


def test_newton_failure_reported_alike(monkeypatch):
    """With the iteration limit cut to 1 (read from hydraulics.numerics by both: the stepper when it packs the
    network) a valve slam fails alike."""
    monkeypatch.setattr(numerics, "NEWTON_MAX_ITERATIONS", 1)
    m = model("excavator")
    pure, fast = StepperImplicitEulerOracle(m), StepperImplicitEuler(m)
    state = start_state(m)
    control = m.control(boom_valve=1.0, stick_valve=-1.0)
    motion = ActuatorMotion.held(state.actuator_position)
    (sa, ra), (sb, rb) = pure.step(state, control, motion, 0.05), fast.step(state, control, motion, 0.05)
    assert not ra.success
    assert (rb.status, rb.message, rb.newton_iterations, rb.rhs_evaluations) == (ra.status, ra.message, ra.newton_iterations, ra.rhs_evaluations)
    assert sb is state and sa is state  # a failed step returns the last good state


def _fill_in(pattern: np.ndarray) -> int:
    """Entries Gaussian elimination in the given order turns from zero to non-zero (symbolic, no pivoting)."""
    p = pattern.copy()
    fills = 0
    for k in range(len(p)):
        rows, cols = np.flatnonzero(p[k + 1:, k]) + k + 1, np.flatnonzero(p[k, k + 1:]) + k + 1
        block = p[np.ix_(rows, cols)]
        fills += int((~block).sum())
        p[np.ix_(rows, cols)] = True
    return fills


def _newton_pattern(m: NetworkModel, numbering) -> np.ndarray:
    """Non-zero pattern of the Newton matrix with the free nodes numbered as ``numbering``: the diagonal and every
    pair of free nodes a branch joins."""
    index = np.full(m.node_count, -1)
    index[numbering] = np.arange(len(numbering))
    pattern = np.eye(len(numbering), dtype=bool)
    for f, t in zip(index[m.branch_from], index[m.branch_to]):
        if f >= 0 and t >= 0:
            pattern[f, t] = pattern[t, f] = True
    return pattern


@pytest.mark.parametrize("name", ["boom", "excavator", "all_kinds"])
def test_elimination_order_makes_no_fill_in(name):
    """The kernels number the free nodes hub last (``elimination_order``): the Newton matrix of the excavator's
    circuit (an arrowhead: the supply joins every work port) then factors without fill-in, where the model's own
    order fills it in; the order is a permutation of the free nodes."""
    m = model(name)
    order = elimination_order(m)
    assert sorted(order) == sorted(m.free_nodes)
    assert _fill_in(_newton_pattern(m, order)) == 0
    if name == "excavator":
        assert _fill_in(_newton_pattern(m, m.free_nodes)) > 0  # the supply is node 1, eliminated first in the model's order


@pytest.mark.parametrize("name", ["excavator", "all_kinds"])
def test_law_pieces_compiled_matches_pure(name):
    """_same_law_pieces(pa, pb) ⇔ NetworkModel.law_pieces(pa) == law_pieces(pb), on pressure pairs that move the
    reliefs, check valves and compensators across their kinks (and pairs that do not)."""
    from hydraulics._compiled import _same_law_pieces, _unpack, pack_network

    m = model(name)
    net = _unpack(*pack_network(m))
    assert len(m.law_pieces(m.state().node_pressure)) > 0
    rng = np.random.default_rng(3)
    changed = same = 0
    for _ in range(400):
        pa = rng.uniform(1e5, 4e7, m.node_count)
        pb = pa + rng.choice([0.0, 1.0, 1e3, 1e6, -1e6, 2e7], m.node_count)
        expected = bool(np.array_equal(m.law_pieces(pa), m.law_pieces(pb)))
        assert _same_law_pieces(net, pa, pb, m.component_state_start.copy(), 0.0) == expected
        changed, same = changed + (not expected), same + expected
    assert changed > 50 and same > 20  # both outcomes exercised


def test_borrowed_views_alias_their_arrays():
    """``borrowed`` passes arrays through as views of the same memory (writes reach the caller's array), other
    members unchanged."""
    import numba

    from hydraulics._compiled import borrowed

    @numba.njit
    def scale_first(*args):
        a, k, (b, c) = borrowed(args)
        for i in range(a.size):
            a[i] *= k
        c[0] = -1
        return b[1, 0] + k

    a, b, c = np.arange(4.0), np.eye(2) + 1.0, np.zeros(2, np.int64)
    assert scale_first(a, 3.0, (b, c)) == 4.0
    np.testing.assert_array_equal(a, [0.0, 3.0, 6.0, 9.0])
    np.testing.assert_array_equal(c, [-1, 0])  # arrays in a nested tuple are borrowed too


def test_pressure_potential_compiled_matches_pure_with_entrained_air():
    """_compiled._potential (the energy ledger's μ(p) of the compiled plants) equals Fluid.pressure_potential, on a
    fluid with entrained air (the Gauss–Legendre branch), from the cavitation floor to 35 MPa; both take their rule
    from fluid.potential_quadrature, and a coarser rule is visibly different there."""
    import numba

    from hydraulics import _compiled as C
    from hydraulics.fluid import potential_quadrature

    @numba.njit
    def potentials(F, I, p, quad):
        pnet = C._ref(C._unpack(F, I))
        out = np.empty(p.size)
        for i in range(p.size):
            out[i] = C._potential(pnet, p[i], quad)
        return out

    m = model("all_kinds")
    assert m.fluid.air_fraction > 0
    F, I = C.pack_network(m)
    p = np.geomspace(m.fluid.cavitation_pressure, 3.5e7, 41)
    pure = m.fluid.pressure_potential(p)
    np.testing.assert_allclose(potentials(F, I, p, potential_quadrature()), pure, rtol=1e-12, atol=1e-9)
    coarse = np.concatenate(np.polynomial.legendre.leggauss(4))
    assert np.max(np.abs(potentials(F, I, p, coarse) - pure)) > 1e-6 * np.max(np.abs(pure))  # the rule matters here
