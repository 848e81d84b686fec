"""The implicit couplings' compiled rules against their numpy oracles (``tests/reference/coupling_implicit.py``).

* Property tests (hypothesis, random inputs on the shipped circuits): the θ-rule, the short-chord velocity guess,
  the secant oil guess, the predicted oil, the blended effort law, the finiteness check of a linearisation and the
  linear finish, each kernel against its numpy formulation.
* Whole couplings: ``implicit``, ``implicit-linear`` and ``rosenbrock`` of :mod:`hydraulics.coupling` against
  their oracles (numpy Newton of ``tests/reference/newton.py``), begin and finish on random states, and coupled
  MuJoCo scenes stepped with either: same trajectories to round-off.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import MODELS
from hydraulics import _compiled as C
from hydraulics import coupling
from hydraulics.circuit import load_circuit
from hydraulics.network import NetworkModel
from reference import coupling_implicit as oracle

CIRCUITS = {"boom": MODELS / "boom" / "boom.circuit.toml", "excavator": MODELS / "excavator" / "excavator.circuit.toml"}
_models = {}
EXAMPLES = settings(max_examples=60, deadline=None)


def model(name) -> NetworkModel:
    if name not in _models:
        _models[name] = NetworkModel.from_circuit(load_circuit(CIRCUITS[name]))
    return _models[name]


def _strokes(m):
    stroke = np.ones(m.actuator_count)
    stroke[m.cylinder_actuator] = m.cylinder_stroke
    return stroke


def _random_motion(m, seed):
    """Positions inside the stroke [m] (motor angles [rad]) and velocities of both signs up to 2 m/s (rad/s)."""
    rng = np.random.default_rng(seed)
    x = np.where(m.actuator_kind == 0, rng.uniform(0.0, 1.0, m.actuator_count) * _strokes(m), rng.uniform(-3, 3, m.actuator_count))
    v = rng.choice([-1.0, 1.0], m.actuator_count) * 10.0 ** rng.uniform(-4, 0.3, m.actuator_count)
    return x, v


def _random_state(m, seed):
    """A state with random chamber pressures (0.1–30 MPa), random spools and a random last oil change."""
    rng = np.random.default_rng(seed)
    x, v = _random_motion(m, seed)
    p = rng.uniform(1e5, 3e7, m.node_count)
    state = m.state(actuator_position=x, node_pressure=p)
    state.valve_spool[:] = rng.uniform(-1, 1, len(m.valve_names))
    state.node_oil_change = np.where(m.node_fixed, np.nan, rng.normal(0, 1e-7, m.node_count))
    return state, v


seeds = st.integers(0, 2**32 - 1)
names = st.sampled_from(sorted(CIRCUITS))


@EXAMPLES
@given(slope=st.lists(st.floats(-1e9, 1e7, allow_nan=False), min_size=1, max_size=6),
       mass=st.floats(1e-3, 1e6), dt=st.floats(1e-5, 1e-1))
def test_blend_factor_matches_oracle(slope, mass, dt):
    """θ = clip(1 − 2/w, 0, 1), w = max(−slope, 0)·h/m_eff: equal to the numpy formula (w = 0 → θ = 0)."""
    masses = np.full(len(slope), mass)
    np.testing.assert_allclose(coupling.blend_factor(slope, masses, dt), oracle.blend_factor(slope, masses, dt),
                               rtol=1e-15, atol=0.0)


@EXAMPLES
@given(name=names, seed=seeds, dt=st.floats(1e-4, 2e-2))
def test_start_velocity_guess_matches_oracle(name, seed, dt):
    """The short-chord rule: the same actuators keep their start velocity, the same are zeroed."""
    m = model(name)
    x, v = _random_motion(m, seed)
    np.testing.assert_array_equal(coupling.start_velocity_guess(m, x, v, dt), oracle.start_velocity_guess(m, x, v, dt))


@EXAMPLES
@given(name=names, seed=seeds)
def test_secant_oil_guess_matches_oracle(name, seed):
    """m + Δm, NaN on the tanks alike; None without a last step."""
    state, _ = _random_state(model(name), seed)
    np.testing.assert_array_equal(coupling.secant_oil_guess(state), oracle.secant_oil_guess(state))
    state.node_oil_change = None
    assert coupling.secant_oil_guess(state) is None and oracle.secant_oil_guess(state) is None


@EXAMPLES
@given(n=st.integers(1, 12), na=st.integers(1, 5), seed=seeds)
def test_predicted_oil_matches_oracle(n, na, seed):
    """m_lin + (∂m/∂v)·(v⁺ − v_g) to round-off."""
    rng = np.random.default_rng(seed)
    lin = SimpleNamespace(state=SimpleNamespace(node_oil=rng.uniform(1e-4, 1e-2, n)), velocity=rng.normal(0, 1, na),
                          oil_velocity_gradient=rng.normal(0, 1e-4, (n, na)))
    v_end = rng.normal(0, 1, na)
    expected = oracle.predicted_oil(lin, v_end)
    got = C.predicted_oil_kernel(lin.state.node_oil, lin.oil_velocity_gradient, lin.velocity, v_end)
    np.testing.assert_allclose(got, expected, rtol=1e-14, atol=1e-14 * np.max(np.abs(lin.oil_velocity_gradient)))


@EXAMPLES
@given(name=names, seed=seeds, blend=st.booleans(), dt=st.floats(1e-4, 1e-2))
def test_effort_law_matches_oracle(name, seed, blend, dt):
    """The blended backward-Euler effort law (constant, slope, θ) from random linearisation terms: pressure part of
    the slope from diag(∂f/∂v⁺) minus the friction slope at the guess, friction at the start velocity with its
    dissipative slope only."""
    m = model(name)
    rng = np.random.default_rng(seed)
    state, v = _random_state(m, seed)
    guess = np.where(rng.uniform(size=m.actuator_count) < 0.3, 0.0, v * rng.uniform(0.5, 1.5, m.actuator_count))
    gradient = np.diag(-10.0 ** rng.uniform(3, 9, m.actuator_count)) + rng.normal(0, 1e3, (m.actuator_count,) * 2)
    lin = SimpleNamespace(velocity=guess, effort_velocity_gradient=gradient,
                          state=SimpleNamespace(node_pressure=rng.uniform(1e5, 3e7, m.node_count),
                                                actuator_position=state.actuator_position))
    pressure_start = m.pressure_effort(state.node_pressure)
    mass = 10.0 ** rng.uniform(0, 5, m.actuator_count)
    F, I = C.packed(m)
    got = C.effort_law_kernel(F, I, guess, lin.state.node_pressure, lin.state.actuator_position, v, gradient,
                              pressure_start, mass, dt, blend)
    expected = oracle.effort_law(m, lin, v, pressure_start, mass if blend else None, dt)
    for a, b in zip(got, expected):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9 * np.max(np.abs(b)))


@EXAMPLES
@given(shape=st.tuples(st.integers(1, 6), st.integers(1, 4)), seed=seeds, bad=st.sampled_from(["none", "p", "g"]),
       value=st.sampled_from([np.nan, np.inf, -np.inf]))
def test_finite_linearization_matches_oracle(shape, seed, bad, value):
    """The finiteness part of a usable linearisation (``_finite_linearization``) as the numpy check."""
    rng = np.random.default_rng(seed)
    n, na = shape
    p, g = rng.normal(size=n), rng.normal(size=(na, na))
    if bad == "p":
        p[rng.integers(n)] = value
    elif bad == "g":
        g[rng.integers(na), rng.integers(na)] = value
    lin = SimpleNamespace(report=SimpleNamespace(success=True), state=SimpleNamespace(node_pressure=p),
                          effort_velocity_gradient=g)
    assert C._finite_linearization(p, g) == oracle.usable(lin) == (bad == "none")


@EXAMPLES
@given(name=names, seed=seeds)
def test_linear_finish_matches_oracle(name, seed):
    """p⁺ = p(m⁺, x⁺) and the branch flows at (p⁺, v⁺) with the linearisation's spools, to round-off."""
    m = model(name)
    state, v = _random_state(m, seed)
    rng = np.random.default_rng(seed + 1)
    oil = np.where(m.node_fixed, np.nan, state.node_oil * rng.uniform(0.999, 1.001, m.node_count))
    speed = rng.uniform(0, 40, len(m.pump_names))
    F, I = C.packed(m)
    p, flow = C.linear_finish_kernel(F, I, oil, state.valve_spool, state.actuator_position, v, speed, 1e-3)
    p_ref, flow_ref = oracle.linear_finish(m, oil, state.valve_spool, state.actuator_position, v, speed)
    # pressures are iterated to the inversion tolerance, 1e-13 on ln(V·φ/m), i.e. β·1e-13 ≈ 2e-4 Pa
    np.testing.assert_allclose(p, p_ref, rtol=1e-10, atol=1e-3)
    np.testing.assert_allclose(flow, flow_ref, rtol=1e-8, atol=1e-9 * np.max(np.abs(flow_ref)))


@pytest.mark.parametrize("scheme", ["implicit", "implicit-linear", "rosenbrock"])
@pytest.mark.parametrize("name", sorted(CIRCUITS))
def test_couplings_match_oracles_on_random_states(name, scheme):
    """begin (law, θ, linearisation) and finish (end state) of the package's coupling and of its oracle, from 30 random
    states, velocity guesses from the start velocities, effective masses given or not."""
    m = model(name)
    package, reference = coupling.make_coupling(scheme, m), oracle.ORACLES[scheme](m)
    control = m.control()
    dt = 1e-3
    for seed in range(30):
        state, v = _random_state(m, seed)
        rng = np.random.default_rng(seed)
        control.valve_command[:] = rng.choice([-1.0, -0.3, 0.0, 0.5, 1.0], len(m.valve_names))
        x = state.actuator_position
        mass = None if seed % 3 == 0 else 10.0 ** rng.uniform(1, 4, m.actuator_count)
        guess = coupling.start_velocity_guess(m, x, v, dt)
        a = reference.begin(state, control, x, v, dt, effective_mass=mass, velocity_guess=guess)
        b = package.begin(state, control, x, v, dt, effective_mass=mass, velocity_guess=guess)
        la, lb = reference.last_linearization, package.last_linearization
        where = f"{name} {scheme} seed {seed}"
        np.testing.assert_array_equal(lb.velocity, la.velocity, err_msg=where)
        assert lb.report.newton_iterations == la.report.newton_iterations, where
        np.testing.assert_allclose(b.constant, a.constant, rtol=1e-8, atol=1e-8 * np.max(np.abs(a.constant)), err_msg=where)
        np.testing.assert_allclose(b.slope, a.slope, rtol=1e-8, atol=1e-8 * np.max(np.abs(a.slope)), err_msg=where)
        np.testing.assert_allclose(package.last_theta, reference.last_theta, rtol=1e-10, atol=1e-12, err_msg=where)
        v_end = v * rng.uniform(0.9, 1.1, m.actuator_count)
        sa, ra = reference.finish(state, control, x, x + dt * v_end, v, v_end, dt)
        sb, rb = package.finish(state, control, x, x + dt * v_end, v, v_end, dt)
        assert ra.success == rb.success, where
        if ra.success:
            np.testing.assert_allclose(sb.node_pressure, sa.node_pressure, rtol=1e-9, atol=1e-3, err_msg=where)
            np.testing.assert_allclose(sb.node_oil, sa.node_oil, rtol=1e-9, atol=0.0, err_msg=where)


@pytest.mark.parametrize("scheme", ["implicit", "rosenbrock"])
@pytest.mark.parametrize("scenario, duration", [("boom/lift.scenario.toml", 0.6), ("excavator/dig.scenario.toml", 0.4)])
def test_coupled_scenes_match_oracle(scenario, duration, scheme):
    """The per-step MuJoCo plant with the package's coupling and with its numpy oracle: joint trajectories and node
    pressures agree to round-off (the scene's own valve commands, slams included)."""
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants.mujoco import MujocoPlant

    sc = load_scenario(MODELS / scenario).with_overrides(coupling=scheme)
    package, reference = MujocoPlant(load_scene(sc)), MujocoPlant(load_scene(sc))
    reference.coupling = oracle.ORACLES[scheme](reference.network)
    steps = int(round(duration / sc.dt))
    worst_q = worst_p = 0.0
    for n in range(steps):
        ra, rb = reference.step(), package.step()
        assert ra.success and rb.success
        qa, qb = reference.joint_state()[0], package.joint_state()[0]
        pa, pb = reference.net_state.node_pressure, package.net_state.node_pressure
        worst_q = max(worst_q, np.max(np.abs(qb - qa)))
        worst_p = max(worst_p, np.nanmax(np.abs(pb - pa) / np.maximum(np.abs(pa), 1e5)))
    assert worst_q < 1e-8 and worst_p < 1e-7, (worst_q, worst_p)
