"""The double-rod (equal-area) cylinder: the ``cylinder`` kind with ``cap_rod_diameter`` = ``rod_diameter``.

* Areas: A_cap = A_rod = π·(D² − d²)/4; a cap-end rod as thick as the bore is refused, naming the field.
* Force: F = (p_cap − p_rod)·A, no ambient term (both rods leave the cylinder).
* Symmetry (network): driven by a symmetric 4/3 valve from a 100 bar supply against no load, the rod extends
  and retracts at the same speed (to 0.1 %) and the chambers swap their pressures; the same circuit with a
  differential cylinder of the same bore and rod does not (speeds differ by more than 10 %).
* On the boom (tests/scenes/double_rod_lift.scenario.toml, both modes): the rod extends at the pump's flow over the
  annulus, Q/(A·φ) within 0.5 % (φ = exp(p_cap/β), the oil's compression at the window's mean cap pressure),
  not over the bore.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from hydraulics.circuit import parse_circuit
from hydraulics.components import CircuitError, build_component
from hydraulics.load import MassLoad, simulate
from hydraulics.network import NetworkModel
from sim.io.mcap_log import read_log
from sim.run.runner import run
from reference.circuits import bench

P0 = 1.01325e5
SCENES = Path(__file__).parent / "scenes"


def test_equal_areas_and_validation():
    cylinder = build_component("cylinder", {"bore": 0.08, "rod_diameter": 0.045, "cap_rod_diameter": 0.045, "stroke": 0.5},
                               "c.toml: component 'c'")
    annulus = math.pi * (0.08**2 - 0.045**2) / 4
    assert cylinder.cap_area == pytest.approx(annulus, rel=1e-15) and cylinder.rod_area == pytest.approx(annulus, rel=1e-15)
    differential = build_component("cylinder", {"bore": 0.08, "rod_diameter": 0.045, "stroke": 0.5}, "c.toml: component 'c'")
    assert differential.cap_area == pytest.approx(math.pi * 0.08**2 / 4, rel=1e-15)
    with pytest.raises(CircuitError, match="field 'cap_rod_diameter'.*smaller than bore"):
        build_component("cylinder", {"bore": 0.08, "rod_diameter": 0.045, "cap_rod_diameter": 0.08, "stroke": 0.5},
                        "c.toml: component 'c'")


CIRCUIT = """
[[component]]
name = "valve"
type = "valve_4_3"
max_area = 1.0e-5
leakage_area = 0.0
time_constant = 0.0
ports = {{ P = "supply", T = "tank", A = "cap", B = "rod" }}

[[component]]
name = "cylinder"
type = "cylinder"
bore = 0.08
rod_diameter = 0.045
cap_rod_diameter = {cap_rod}
stroke = 1.0
dead_volume_cap = 1.0e-5
dead_volume_rod = 1.0e-5
ports = {{ cap = "cap", rod = "rod" }}
"""


def _model(cap_rod):
    return NetworkModel.from_circuit(parse_circuit(tomllib.loads(bench(1.0e7) + CIRCUIT.format(cap_rod=cap_rod)), "double rod"))


def test_force_has_no_ambient_term():
    model = _model(0.045)
    area = math.pi * (0.08**2 - 0.045**2) / 4
    pressure = np.full(model.node_count, P0)
    pressure[model.node("cap")], pressure[model.node("rod")] = 5e6, 2e6
    effort = model.actuator_effort(pressure, np.zeros(1))[0][0]
    assert effort == pytest.approx((5e6 - 2e6) * area, rel=1e-12)


def _speeds(cap_rod):
    """Steady (last 0.1 s of 0.3 s) extending and retracting speeds [m/s] and the chamber pressures [Pa]."""
    model = _model(cap_rod)
    out = []
    for command in (1.0, -1.0):
        state = model.state(actuator_position=np.array([0.5]), node_pressure=np.full(model.node_count, P0))
        run = simulate(model, MassLoad(actuator="cylinder", mass=50.0), state, dt=1e-3, duration=0.3,
                       inputs={"valve": command})
        assert run.status == "complete"
        late = run.time >= 0.2
        speed = np.polyfit(run.time[late], run.position[late], 1)[0]
        out.append((speed, run.pressure(model, "cap")[-1], run.pressure(model, "rod")[-1]))
    return out


def test_extends_and_retracts_at_the_same_speed():
    (extend, cap_e, rod_e), (retract, cap_r, rod_r) = _speeds(0.045)
    assert extend > 0.05 and retract == pytest.approx(-extend, rel=1e-3)
    assert cap_e == pytest.approx(rod_r, rel=1e-3) and rod_e == pytest.approx(cap_r, rel=1e-3)
    (extend_d, _, _), (retract_d, _, _) = _speeds(0.0)
    assert abs(abs(retract_d / extend_d) - 1.0) > 0.1


@pytest.fixture(scope="module")
def lifts(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("double_rod")
    out = {}
    for mode in ("mujoco", "pbd"):
        result = run(SCENES / "double_rod_lift.scenario.toml", out=tmp / f"{mode}.mcap", overrides={"mode": mode},
                     progress=False)
        assert result.status == "complete", result.message
        out[mode] = read_log(result.log_path)
    return out


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_boom_rises_at_the_pump_flow_over_the_annulus(lifts, mode):
    """Rod speed over 0.4–0.8 s = η_v·D·n/(A_ann·φ) within 0.5 % (12 cm³/rev at 40 rev/s, η_v = 1)."""
    log = lifts[mode]
    cylinder, nodes = log.topic("/hydroplant/cylinders/boom_cyl"), log.topic("/hydroplant/nodes")
    window = cylinder.t >= 0.4
    speed = np.polyfit(cylinder.t[window], cylinder["position_m"][window], 1)[0]
    p_cap = float(np.mean(nodes["pressure_pa.boom_cyl_cap"][nodes.t >= 0.4])) - P0
    annulus = math.pi * (0.063**2 - 0.035**2) / 4
    assert speed == pytest.approx(1.2e-5 * 40.0 / annulus / math.exp(p_cap / 1.5e9), rel=5e-3)
