"""Property tests: every evaluation method of ``NetworkModel`` (compiled kernels on the packed model) against its
numpy formulation (``tests/reference/network_eval.py``, the oracle), on random states and inputs of the shipped
circuits at every fidelity, of circuits with rigid actuators, entrained air, accumulators and law branches, and of
the boom with tabulated metering edges and a variable orifice.

Tolerance: 1e-12 relative to each quantity's largest magnitude over the network (terms cancel in net flows and
efforts), exact for the discrete outputs (law pieces, rigid directions).  Node pressures of compliant nodes
(elastic walls, accumulators) are solved by two different iterations (the kernel starts from a second-order
series, the oracle from the rigid-volume pressure), each to PRESSURE_INVERSION_TOLERANCE on ln(V·φ/m): they agree
to β·tolerance [Pa] on top of that.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import MODELS, network_from_toml
from hydraulics.circuit import load_circuit
from hydraulics.energy import stored_energy_at
from hydraulics.network import PRESSURE_INVERSION_TOLERANCE, NetworkModel
from reference import network_eval as ref
from test_branch_laws import CIRCUIT as LAW_BRANCHES
from test_network import ALL_KINDS

RTOL = 1e-12  # of the quantity's largest magnitude
EXAMPLES = settings(max_examples=25, deadline=None)
EXCAVATOR = MODELS / "excavator" / "excavator.circuit.toml"
SHIPPED = {"boom": MODELS / "boom" / "boom.circuit.toml", "excavator": EXCAVATOR,
           "seed_cylinder": MODELS / "seed_cylinder" / "seed_cylinder.circuit.toml",
           "lift": MODELS / "lift_1dof" / "lift.circuit.toml"}
CASES = ([f"{name}:{fidelity}" for name in SHIPPED for fidelity in ("compressible", "lines")]
         + ["excavator:rigid_front", "excavator:rigid_boom", "all_kinds", "all_kinds:lines", "law_branches", "metering"])
METERED = ('type = "valve_4_3"            # closed-centre directional valve, CETOP 3 / NG6 class\n',
           'type = "valve_4_3"\nmetering = "table"\narea_table = { "P-A" = [[0.05, 0.0], [0.3, 2e-6], [1.0, 1.5e-5]], '
           '"A-T" = [[0.1, 0.0], [0.6, 1.2e-5], [1.0, 1.6e-5]] }\n')
THROTTLE = ('\n[[component]]\nname = "bleed"\ntype = "variable_orifice"\nmax_area = 2e-6\nmetering = "exponential"\n'
            'metering_exponent = 2.5\nports = { a = "supply", b = "tank" }\n')

_models = {}


def model(case: str) -> NetworkModel:
    """The network of a test case (built once)."""
    if case not in _models:
        name, _, variant = case.partition(":")
        if name == "all_kinds":
            m = network_from_toml(ALL_KINDS, fidelity=variant or "compressible")
        elif name == "law_branches":
            m = network_from_toml(LAW_BRANCHES)
        elif name == "metering":  # the boom with tabulated edges and an exponential bleed throttle
            text = SHIPPED["boom"].read_text(encoding="utf-8")
            assert text.count(METERED[0]) == 1
            m = network_from_toml(text.replace(*METERED) + THROTTLE)
        elif variant == "rigid_front":
            m = NetworkModel.from_circuit(load_circuit(EXCAVATOR), actuator_fidelity={
                "stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"})
        elif variant == "rigid_boom":
            m = NetworkModel.from_circuit(load_circuit(EXCAVATOR), actuator_fidelity={"boom_cyl": "incompressible"})
        else:
            m = NetworkModel.from_circuit(load_circuit(SHIPPED[name]), fidelity=variant)
        _models[case] = m
    return _models[case]


def sample(m: NetworkModel, seed: int, rows=()):
    """Random actuator positions (cylinders a little past both ends too), node pressures from near the cavitation
    floor to 40 MPa (fixed nodes at their set pressure), oil contents of those pressures (some nodes 0.2 % short:
    ~3 MPa lower, many into cavitation), spools past ±1, pump speeds and actuator velocities of both signs;
    ``rows``: leading shape."""
    rng = np.random.default_rng(seed)
    na, n = m.actuator_count, m.node_count
    x = rng.uniform(-np.pi, np.pi, rows + (na,))
    x[..., m.cylinder_actuator] = m.cylinder_stroke * rng.uniform(-0.05, 1.05, rows + (len(m.cylinder_actuator),))
    p = 10.0 ** rng.uniform(3.0, np.log10(4e7), rows + (n,))
    p = np.where(m.node_fixed, m.node_fixed_pressure, p)
    oil = ref.oil_from_pressure(m, p, x) * np.where(rng.uniform(size=rows + (n,)) < 0.2, 0.998, 1.0)
    spool = rng.uniform(-1.2, 1.2, len(m.valve_names))
    speed = m.pump_nominal_speed * rng.uniform(-0.2, 2.0, len(m.pump_names))
    v = rng.uniform(-1.0, 1.0, na)
    return x, p, oil, spool, speed, v


def close(kernel, oracle, atol=0.0):
    """``kernel`` equals ``oracle`` (same shape) to RTOL of the oracle's largest magnitude (+ ``atol``)."""
    kernel, oracle = np.asarray(kernel, float), np.asarray(oracle, float)
    assert kernel.shape == oracle.shape
    finite = np.isfinite(oracle)
    np.testing.assert_array_equal(np.isfinite(kernel), finite)
    scale = np.max(np.abs(oracle[finite]), initial=0.0)
    np.testing.assert_allclose(kernel[finite], oracle[finite], rtol=RTOL, atol=RTOL * scale + atol)


def pressure_atol(m):
    """Two inversions of a compliant node, each to the tolerance on ln(V·φ/m), differ by up to ~2·β·tolerance [Pa]."""
    return 2.0 * m.fluid.bulk_modulus * PRESSURE_INVERSION_TOLERANCE if len(m.compliant_nodes) else 0.0


@pytest.mark.parametrize("case", CASES)
@EXAMPLES
@given(seed=st.integers(0, 2**32 - 1))
def test_node_relations(case, seed):
    """Volumes, chamber volumes, ∂V/∂x, oil content, pressure inversion with ∂p/∂m, bulk modulus, stiffness."""
    m = model(case)
    x, p, oil, *_ = sample(m, seed)
    close(m.geometric_volume(x), ref.geometric_volume(m, x))
    for k, o in zip(m.extra_volume(p), ref.extra_volume(m, p)):
        close(k, o)
    for k, o in zip(m.node_volume_at(x, p), ref.node_volume_at(m, x, p)):
        close(k, o)
    for k, o in zip(m.chamber_volumes(x), ref.chamber_volumes(m, x)):
        close(k, o)
    close(m.volume_position_gradient(x), ref.volume_position_gradient(m, x))
    close(m.oil_from_pressure(p, x), ref.oil_from_pressure(m, p, x))
    pk, dk = m.pressure(oil, x)
    po, do = ref.pressure(m, oil, x)
    close(pk, po, atol=pressure_atol(m))
    close(dk, do, atol=np.nanmax(np.abs(do)) * pressure_atol(m) / m.fluid.bulk_modulus)
    close(m.effective_bulk_modulus(p, x), ref.effective_bulk_modulus(m, p, x))
    close(m.chamber_stiffness(p, x), ref.chamber_stiffness(m, p, x))
    if len(m.accumulator_node):
        pa = p[m.accumulator_node]
        close(m.accumulator_liquid_volume(pa)[0], ref.laws.accumulator_liquid_volume_with_derivative(
            pa, m.accumulator_gas_volume, m.accumulator_precharge, m.accumulator_index)[0])


@pytest.mark.parametrize("case", CASES)
@EXAMPLES
@given(seed=st.integers(0, 2**32 - 1))
def test_flows(case, seed):
    """Valve areas and rigid rates, law pieces, branch flows and their derivatives, flow Jacobian, ∂inflow/∂v."""
    m = model(case)
    x, p, oil, spool, speed, v = sample(m, seed)
    areas = m.valve_areas(spool)
    close(areas, ref.valve_areas(m, spool))
    np.testing.assert_array_equal(m.rigid_direction(spool), ref.rigid_direction(m, spool))
    close(m.rigid_rates(spool), ref.rigid_rates(m, spool))
    close(m.rigid_metering_area(spool), ref.rigid_metering_area(m, spool))
    np.testing.assert_array_equal(m.law_pieces(p), ref.law_pieces(m, p))
    kernel, oracle = m.branch_flows(p, areas, speed, v), ref.branch_flows(m, p, areas, speed, v)
    for name in ("flow", "dflow_dfrom", "dflow_dto", "dflow_dpilot"):
        if getattr(oracle, name) is None:
            assert getattr(kernel, name) is None
        else:
            close(getattr(kernel, name), getattr(oracle, name))
    close(m.flow_jacobian(kernel), ref.flow_jacobian(m, oracle))
    close(m.flow_velocity_gradient(areas), ref.flow_velocity_gradient(m, areas))
    if not len(m.rigid_branch_actuator):
        close(m.flow_velocity_gradient(), ref.flow_velocity_gradient(m))


@pytest.mark.parametrize("case", CASES)
@EXAMPLES
@given(seed=st.integers(0, 2**32 - 1))
def test_efforts(case, seed):
    """Pressure efforts, friction with its slope, total effort, ∂effort/∂p."""
    m = model(case)
    x, p, oil, spool, speed, v = sample(m, seed)
    close(m.pressure_effort(p), ref.pressure_effort(m, p))
    for k, o in zip(m.friction_effort(v, p, x), ref.friction_effort(m, v, p, x)):
        close(k, o)
    for k, o in zip(m.actuator_effort(p, v), ref.actuator_effort(m, p, v)):
        close(k, o)
    np.testing.assert_array_equal(m.effort_pressure_gradient(), ref.effort_pressure_gradient(m))


@pytest.mark.parametrize("case", ["excavator:compressible", "all_kinds", "excavator:rigid_front"])
def test_batches_broadcast_over_leading_axes(case):
    """A batch of samples (leading shape (3, 4)) gives the oracle's batch, and each row equals the single sample."""
    m = model(case)
    x, p, oil, *_ = sample(m, 7, rows=(3, 4))
    for k, o in zip(m.node_volume_at(x, p), ref.node_volume_at(m, x, p)):
        close(k, o)
    close(m.geometric_volume(x), ref.geometric_volume(m, x))
    close(m.oil_from_pressure(p, x), ref.oil_from_pressure(m, p, x))
    close(m.effective_bulk_modulus(p, x), ref.effective_bulk_modulus(m, p, x))
    close(m.chamber_stiffness(p, x), ref.chamber_stiffness(m, p, x))
    close(m.pressure_effort(p)[2, 1], ref.pressure_effort(m, p[2, 1]))
    assert m.pressure(oil, x)[0].shape == (3, 4, m.node_count)
    np.testing.assert_array_equal(m.pressure(oil, x)[0][1, 2], m.pressure(oil[1, 2], x[1, 2])[0])
    np.testing.assert_array_equal(m.node_volume_at(x[0], p[0, 1])[0][1], m.node_volume_at(x[0, 1], p[0, 1])[0])  # broadcast
    energy = stored_energy_at(m, oil, p, x)
    assert energy.shape == (3, 4)
    assert energy[2, 3] == pytest.approx(stored_energy_at(m, oil[2, 3], p[2, 3], x[2, 3]), rel=1e-13)


def test_methods_agree_with_the_oracle_under_disable_jit():
    """With NUMBA_DISABLE_JIT=1 the same kernels run as plain Python and still agree with the oracle."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    here = Path(__file__).resolve().parent
    script = (
        "import sys; sys.path.insert(0, sys.argv[1])\n"
        "import numpy as np, test_network_oracle as T\n"
        "from reference import network_eval as ref\n"
        "for case in ('all_kinds', 'excavator:rigid_front', 'law_branches'):\n"
        "    m = T.model(case); x, p, oil, spool, speed, v = T.sample(m, 3); a = m.valve_areas(spool)\n"
        "    T.close(a, ref.valve_areas(m, spool))\n"
        "    T.close(m.pressure(oil, x)[0], ref.pressure(m, oil, x)[0], atol=T.pressure_atol(m))\n"
        "    T.close(m.branch_flows(p, a, speed, v).flow, ref.branch_flows(m, p, a, speed, v).flow)\n"
        "    T.close(m.chamber_stiffness(p, x), ref.chamber_stiffness(m, p, x))\n"
        "    T.close(m.actuator_effort(p, v)[0], ref.actuator_effort(m, p, v)[0])\n"
        "print('agree')\n"
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    result = subprocess.run([sys.executable, "-W", "ignore", "-c", script, str(here)], env=env, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "agree"
