"""The sparse Newton solves (``hydraulics._compiled.sparse_pattern``, ``_newton_solve``) agree with dense Gaussian
elimination: on random matrices with a circuit's pattern (to round-off against LAPACK, bit for bit against the
kernels' dense path), on the excavator's own Newton matrices, and over whole runs of the excavator in both modes;
their work grows linearly with the number of booms on one pump."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from conftest import MODELS, network_from_toml
from hydraulics import _compiled as C
from hydraulics import numerics
from hydraulics.circuit import load_circuit
from hydraulics.network import NetworkModel
from test_network import ALL_KINDS

EXCAVATOR = MODELS / "excavator" / "excavator.circuit.toml"


def _model(name):
    if name == "all_kinds":
        return network_from_toml(ALL_KINDS)
    return NetworkModel.from_circuit(load_circuit(EXCAVATOR if name == "excavator" else MODELS / name))


def _booms(count: int) -> NetworkModel:
    """``count`` valves, hoses and cylinders on one pump's supply (the arrowhead of bench/bench_scaling.py)."""
    parts = ['[fluid]\nbulk_modulus = 1.5e9\n',
             '[[component]]\nname = "tank"\ntype = "tank"\npressure = 1.01325e5\nports = { port = "tank" }\n',
             '[[component]]\nname = "pump"\ntype = "pump_fixed"\ndisplacement = 1e-5\nspeed = 40.0\n'
             'ports = { inlet = "tank", outlet = "supply" }\n',
             '[[component]]\nname = "gallery"\ntype = "volume"\nvolume = 3e-4\nports = { port = "supply" }\n',
             '[[component]]\nname = "relief"\ntype = "relief_valve"\ncracking_pressure = 2.0e7\ngradient = 5.0e-10\n'
             'ports = { inlet = "supply", outlet = "tank" }\n']
    for i in range(count):
        parts.append(
            f'[[component]]\nname = "valve{i}"\ntype = "valve_4_3"\nmax_area = 1.5e-5\ncentre = "closed"\n'
            f'ports = {{ P = "supply", T = "tank", A = "a{i}", B = "b{i}" }}\n'
            f'[[component]]\nname = "hose_a{i}"\ntype = "hose"\nlength = 2.0\ninner_diameter = 0.0127\n'
            f'ports = {{ a = "a{i}", b = "cap{i}" }}\n'
            f'[[component]]\nname = "hose_b{i}"\ntype = "hose"\nlength = 2.0\ninner_diameter = 0.0127\n'
            f'ports = {{ a = "b{i}", b = "rod{i}" }}\n'
            f'[[component]]\nname = "cyl{i}"\ntype = "cylinder"\nbore = 0.063\nrod_diameter = 0.035\nstroke = 0.4\n'
            f'ports = {{ cap = "cap{i}", rod = "rod{i}" }}\n')
    return network_from_toml("\n".join(parts))


def _dense(net, val):
    nf = net.lu_diag.size
    a = np.zeros((nf, nf))
    a[net.lu_row, net.lu_col] = val
    return a


def _random_values(net, rng, dominant=True):
    """Random entries on the pattern's non-fill positions (fill-in positions zero), the columns diagonally
    dominant when ``dominant`` (the Newton matrix's property) or one column's largest entry off the diagonal."""
    nf = net.lu_diag.size
    structural = np.zeros(net.lu_row.size, bool)
    structural[net.branch_lu[net.branch_lu >= 0]] = True
    structural[net.lu_diag] = True
    val = np.where(structural, rng.uniform(-1.0, 1.0, net.lu_row.size), 0.0)
    a = _dense(net, val)
    column = np.abs(a).sum(axis=0) - np.abs(np.diag(a))
    val[net.lu_diag] = 1.0 + column + rng.uniform(0.0, 1.0, nf)
    if not dominant:
        k = int(np.argmax([np.count_nonzero(net.lu_row[net.lu_col == j] > j) for j in range(nf)]))
        below = np.flatnonzero((net.lu_col == k) & (net.lu_row > k) & structural)
        val[below[0]] = 10.0 * val[net.lu_diag[k]]
    return val


def _solve(net, val, b):
    """(solvable, x) from the kernels' _newton_solve (the compact matrix and the right-hand sides are copies)."""
    nf = net.lu_diag.size
    x = np.array(b, float).reshape(nf, -1).copy()
    ok = C._newton_solve(net, val.copy(), np.empty(val.size), np.empty((nf, nf)), x)
    return ok, x


def _net(model, sparse=True, monkeypatch=None):
    if monkeypatch is not None:
        monkeypatch.setattr(numerics, "SPARSE_FACTORISATION", sparse)
    return C._unpack(*C.pack_network(model))


@pytest.mark.parametrize("name", ["excavator", "all_kinds"])
def test_sparse_solve_matches_dense_elimination_on_random_matrices(name, monkeypatch):
    """Random column-dominant matrices on the circuit's pattern, three right-hand sides: the sparse path equals
    LAPACK's solve to round-off and the dense path bit for bit; a matrix whose partial pivoting exchanges rows takes
    the dense path (bit for bit too) and still solves it."""
    model = _model(name)
    sparse, dense = _net(model, True, monkeypatch), _net(model, False, monkeypatch)
    rng = np.random.default_rng(7)
    for dominant in (True, True, False):
        val = _random_values(sparse, rng, dominant)
        b = rng.normal(size=(sparse.lu_diag.size, 3))
        ok, x = _solve(sparse, val, b)
        ok_dense, x_dense = _solve(dense, val, b)
        assert ok and ok_dense
        expected = np.linalg.solve(_dense(sparse, val), b)
        assert np.allclose(x, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
        assert np.array_equal(x, x_dense)
        if dominant:
            assert C._sparse_factor(sparse, val.copy()) == sparse.lu_diag.size  # no row exchange: sparse path
        else:
            assert C._sparse_factor(sparse, val.copy()) < sparse.lu_diag.size  # exchange: dense path


def test_singular_matrix_is_reported():
    """A zero column makes the matrix exactly singular: the solve says so (as LAPACK's getrf, info > 0)."""
    net = _net(_model("excavator"))
    val = _random_values(net, np.random.default_rng(3))
    val[net.lu_col == 2] = 0.0
    ok, _ = _solve(net, val, np.ones(net.lu_diag.size))
    assert not ok


def test_factorisation_work_grows_linearly_with_booms():
    """N booms on one pump: the supply (every valve's P port) is numbered last, nothing fills in, and the
    elimination's updates Σₖ|U(k)|² and the pattern's entries grow in proportion to N (dense: N³ and N²)."""
    counts = {}
    for n in (4, 8, 16, 32):
        model = _booms(n)
        pattern = C.sparse_pattern(model, C.elimination_order(model))
        counts[n] = (pattern["lu_update"].size, pattern["lu_row"].size)
        nf = len(model.free_nodes)
        structural = np.zeros(pattern["lu_row"].size, bool)
        structural[pattern["branch_lu"][pattern["branch_lu"] >= 0]] = True
        structural[pattern["lu_diag"]] = True
        assert structural.all()  # no fill-in
        assert counts[n][1] < 6 * nf
    for small, big in ((4, 8), (8, 16), (16, 32)):
        assert counts[big][0] <= 2.05 * counts[small][0] and counts[big][1] <= 2.05 * counts[small][1]


def test_excavator_newton_matrix_needs_no_row_exchange():
    """The excavator's Newton matrix, after a 1 ms step from random pressures with every valve half open, is column
    diagonally dominant (each node's outflows grow with its pressure), so partial pivoting keeps the diagonal and
    the sparse path solves it."""
    model = _model("excavator")
    F, I = C.pack_network(model)
    net = C._unpack(F, I)
    rng = np.random.default_rng(1)
    p = np.where(model.node_fixed, model.node_fixed_pressure, rng.uniform(2e6, 2e7, model.node_count))
    x = np.where(model.actuator_kind == 0, 0.2, 0.0)
    state = model.state(actuator_position=x, node_pressure=p)
    nvalve, npump = len(model.valve_names), len(model.pump_names)
    spool0 = np.zeros(len(state.valve_spool))
    oil, p_end, spool, flow, dflow, istats = C._step_kernel(
        F, I, state.node_oil, spool0, np.full(nvalve, 0.5), np.full(npump, 40.0), x, np.zeros(model.actuator_count),
        1e-3, True, state.node_oil)[:6]
    assert istats[C.IS_STATUS] == 0
    _, dpdm = C._eval_pressure(F, I, oil[None, :], x[None, :])
    val = np.empty(net.lu_row.size)
    C._newton_values(net, dflow, dpdm[0], 1e-3, val)
    assert C._sparse_factor(net, val.copy()) == net.lu_diag.size


VALVE_RAMPS = {"boom_valve": (0.02, 0.08, -0.35), "stick_valve": (0.03, 0.1, 0.8), "bucket_valve": (0.05, 0.12, 0.5),
               "swing_valve": (0.02, 0.1, 1.0)}


def _end_states(scenario_path, overrides, steps):
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.run.runner import make_plant

    from sim.io.scenario import Schedule

    scenario = load_scenario(scenario_path)
    ramps = {name: Schedule(np.array([0.0, t0, t1]), np.array([0.0, 0.0, value]))
             for name, (t0, t1, value) in VALVE_RAMPS.items()}  # every valve moving within the first 0.12 s
    plant = make_plant(load_scene(scenario.with_overrides(inputs={**scenario.inputs, **ramps}, **overrides)))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        report = plant.advance(steps)
    assert report.success, report.message
    state = plant.net_state
    return dict(joints=np.asarray(plant.joint_state()[0], float), pressure=state.node_pressure,
                actuator=np.concatenate((state.actuator_position, state.actuator_velocity)),
                effort=np.asarray(plant.effort, float))


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_excavator_run_agrees_with_dense_factorisation(mode, monkeypatch):
    """The excavator dig's first 0.3 s (MuJoCo mode: 1 ms steps; PBD mode: 60 Hz frames × 10 substeps) with the sparse
    and with the dense factorisation (packed flag ``numerics.SPARSE_FACTORISATION``) ends in the same state within
    1e-9 of each quantity's largest magnitude."""
    path = MODELS / "excavator" / "dig.scenario.toml"
    overrides, steps = (dict(mode=mode, dt=1 / 60, pbd_substeps=10), 18) if mode == "pbd" else (dict(mode=mode), 300)
    monkeypatch.setattr(numerics, "SPARSE_FACTORISATION", True)
    sparse = _end_states(path, overrides, steps)
    monkeypatch.setattr(numerics, "SPARSE_FACTORISATION", False)
    dense = _end_states(path, overrides, steps)
    assert np.max(sparse["pressure"]) > 2e6  # pressurised: the valves have opened
    for key, value in sparse.items():
        scale = max(float(np.max(np.abs(value))), 1e-300)
        assert np.max(np.abs(value - dense[key])) <= 1e-9 * scale, key
