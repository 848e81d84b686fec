"""The pressure-compensated flow control valve (hydraulics/components/flow_control.py): its law and its
characteristic.

* The metering area passes the flow setting at Δp_c through the orifice law, laminar blend included; the law
  against hand-derived values (the textbook orifice law at min(Δp, Δp_c) outside the blend) and its derivatives
  against central finite differences: below, inside and above the blend, reverse flow.
* Flow held over Δp (network): a cylinder fed from 200 bar (gauge) through the valve pushes against forces that
  leave 10–190 bar across the valve; its speed is the flow setting over the cap area within 0.2 % (the oil's
  compression in the chamber accounted for), and with 3 bar across the valve (below Δp_c) the orifice law's flow.
* On the boom (tests/scenes/flow_control_lift.scenario.toml, both modes): the boom rises at the valve's
  10 L/min, not the pump's 28.8 L/min, within 1 %, with the supply at 200 bar and again at 100 bar (the boom
  rings on its oil column fed by a flow source, about ±30 bar at 8 Hz: the fit spans several periods).
"""

from __future__ import annotations

import math
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest

from hydraulics.circuit import load_circuit, parse_circuit
from hydraulics.components import CircuitError, FlowControlValve, build_component
from hydraulics.components.flow_control import flow_with_derivatives as flow_control_law
from hydraulics.fluid import Fluid
from hydraulics.load import MassLoad, simulate
from hydraulics.network import NetworkModel
from sim.io.mcap_log import read_log
from sim.run.runner import run
from reference.laws import orifice_textbook
from reference.circuits import bench

SCENES = Path(__file__).parent / "scenes"
FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.01325e5)
P0 = FLUID.reference_pressure


VALVE = FlowControlValve(flow_setting=1e-4, compensator_pressure=6e5)  # 6 L/min, blend 5.4–6.6 bar


def test_metering_area_passes_the_setting_at_the_compensator_drop():
    """Q_orifice(A_m, Δp_c) = Q_set to 1e-12; A_m a little above the turbulent formula's Q/(C_d·sqrt(2Δp_c/ρ))."""
    area = VALVE.law_row(FLUID)[2]
    assert orifice_textbook(area, 0.7, 6e5, FLUID) == pytest.approx(1e-4, rel=1e-12)
    turbulent = 1e-4 / (0.7 * math.sqrt(2 * 6e5 / FLUID.density))
    assert turbulent < area < 1.01 * turbulent


@pytest.mark.parametrize("dp", [-2e6, 2e5, 5.3e5, 5.7e5, 6.3e5, 6.7e5, 1e6, 2e7])
def test_flow_and_derivatives(dp):
    """Outside the blend Q = Q_orifice(A_m, min(Δp, Δp_c)) to 1e-12 (reverse flow uncompensated); inside it Q lies
    between the two; ∂Q/∂p_in = −∂Q/∂p_out against central differences (1 Pa); no pilot terminal."""
    row = VALVE.law_row(FLUID)
    area = row[2]
    q, d_in, d_out, d_x = flow_control_law(row, P0 + dp, P0, 0.0)
    if dp <= 5.4e5 or dp >= 6.6e5:
        assert q == pytest.approx(orifice_textbook(area, 0.7, min(dp, 6e5), FLUID), rel=1e-12)
    else:
        assert orifice_textbook(area, 0.7, 5.4e5, FLUID) < q < orifice_textbook(area, 0.7, dp, FLUID)
    assert d_x == 0.0 and d_out == -d_in
    numeric = (flow_control_law(row, P0 + dp + 1.0, P0, 0.0)[0] - flow_control_law(row, P0 + dp - 1.0, P0, 0.0)[0]) / 2
    assert d_in == pytest.approx(numeric, rel=1e-6, abs=1e-12 * 1e-4 / 6e5)
    if dp >= 6.6e5:
        assert d_in == 0.0  # held flow


def test_blend_must_lie_at_positive_drops():
    with pytest.raises(CircuitError, match="blend_width"):
        build_component("flow_control_valve", {"flow_setting": 1e-4, "compensator_pressure": 5e5, "blend_width": 1e6},
                        "c.toml: component 'f'")


CIRCUIT = bench(2.0101325e7) + """
[[component]]
name = "control"
type = "flow_control_valve"
flow_setting = 1.0e-4
compensator_pressure = 6.0e5
ports = { inlet = "supply", outlet = "cap" }

[[component]]
name = "cylinder"
type = "cylinder"
bore = 0.05
rod_diameter = 0.03
stroke = 1.0
dead_volume_cap = 1.0e-5
dead_volume_rod = 1.0e-5
ports = { cap = "cap", rod = "tank" }
"""
CAP_AREA = math.pi * 0.05**2 / 4


@pytest.mark.parametrize("drop", [3e5, 1e6, 2e6, 1e7, 1.9e7])
def test_cylinder_speed_held_over_the_pressure_drop(drop):
    """Cylinder speed (fit over 0.2–0.4 s, started at the expected speed) against a force leaving ``drop`` across
    the valve: Q/(A_cap·φ) within 0.2 %, with Q = Q_set for drops above Δp_c and Q_orifice(A_m, drop) below it, and
    φ = exp((p_cap − p_ref)/β) the oil's compression in the chamber (flows count oil at the reference pressure)."""
    model = NetworkModel.from_circuit(parse_circuit(tomllib.loads(CIRCUIT), "flow control"))
    p_cap = P0 + 2e7 - drop
    force = (p_cap - P0) * CAP_AREA  # against extension, rod side at tank
    pressure = np.full(model.node_count, P0)
    pressure[model.node("cap")] = p_cap
    flow = min(1e-4, orifice_textbook(VALVE.law_row(FLUID)[2], 0.7, drop, FLUID))
    expected = flow / CAP_AREA / math.exp((p_cap - P0) / 1.5e9)
    state = model.state(actuator_position=np.array([0.1]), node_pressure=pressure)
    trajectory = simulate(model, MassLoad(actuator="cylinder", mass=100.0, force=-force), state, dt=1e-3,
                          duration=0.4, velocity=expected)
    assert trajectory.status == "complete"
    late = trajectory.time >= 0.2
    speed = np.polyfit(trajectory.time[late], trajectory.position[late], 1)[0]
    assert speed == pytest.approx(expected, rel=2e-3)


def _lift(tmp, mode, relief):
    """Run flow_control_lift in ``mode`` with the relief cracking at ``relief`` [Pa] (a copy of the scene)."""
    scene = tmp / f"{mode}_{relief:g}"
    scene.mkdir()
    for name in ("boom.xml", "flow_control.circuit.toml", "flow_control_lift.scenario.toml"):
        shutil.copy(SCENES / name, scene / name)
    circuit = scene / "flow_control.circuit.toml"
    text = circuit.read_text(encoding="utf-8")
    circuit.write_text(text.replace("cracking_pressure = 2.0e7", f"cracking_pressure = {relief:.6e}"), encoding="utf-8")
    result = run(scene / "flow_control_lift.scenario.toml", out=scene / "run.mcap", overrides={"mode": mode},
                 progress=False)
    assert result.status == "complete", result.message
    return read_log(result.log_path)


@pytest.fixture(scope="module")
def lifts(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("flow_control")
    return {(mode, relief): _lift(tmp, mode, relief) for mode in ("mujoco", "pbd") for relief in (2.0e7, 1.0e7)}


@pytest.mark.parametrize("relief", [2.0e7, 1.0e7])
@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_boom_rises_at_the_valve_flow(lifts, mode, relief):
    """Rod speed over 0.6–1.2 s = Q_set/A_cap within 1 %; the supply sits at the relief (the pump's excess)."""
    valve = load_circuit(SCENES / "flow_control.circuit.toml").component("boom_fcv").params
    log = lifts[mode, relief]
    cylinder = log.topic("/hydroplant/cylinders/boom_cyl")
    window = cylinder.t >= 0.6
    speed = np.polyfit(cylinder.t[window], cylinder["position_m"][window], 1)[0]
    assert speed == pytest.approx(valve.flow_setting / (math.pi * 0.063**2 / 4), rel=0.01)
    nodes = log.topic("/hydroplant/nodes")
    assert np.all(nodes["pressure_pa.supply"][nodes.t >= 0.6] - P0 > relief)
