"""The ideal pressure source (``pressure_source``): its net held at p_ref + Δp_s, its work in the energy ledger.

The scene: a 200 kg load on a vertical slide, lifted by a 50 mm cylinder whose cap is fed from a 50 bar source
through a 2 mm² orifice; the rod side is on the tank.  At steady speed the cap holds the load, p_cap = p_ref + m·g/A,
the orifice passes Q = orifice law(Δp_s − m·g/A) of oil content and the chamber grows by A·v at density φ(p_cap), so

    v = Q / (A·φ(p_cap)).

The ledger: the source supplies μ(p_s)·Q (hydraulics.energy.source_power), which goes into the load's potential and
kinetic energy, the oil compressed in the cap and the orifice's loss; what is left is the scheme's residual.
"""

import math

import pytest

from reference.laws import orifice_textbook
from hydraulics.circuit import load_circuit
from hydraulics.components import CircuitError, build_component
from hydraulics.network import NetworkModel
from sim.io.mcap_log import read_log
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.run import monitor as M
from sim.run.runner import make_plant, run
from reference.circuits import bench, lift_cylinder, orifice, pressure_source
from reference.scenes import vertical_lift

MASS = 200.0  # kg
BORE = 0.05  # m
SOURCE = 5.0e6  # Pa gauge
ORIFICE = 2.0e-6  # m²
CD = 0.7
G = 9.81

MJCF = vertical_lift(mass=MASS, inertia=0.1, gravity=G)

CIRCUIT = (bench() + pressure_source(SOURCE) + orifice("feed", "supply", "cap", ORIFICE, CD) + lift_cylinder(BORE))


def _scene(tmp_path, mode):
    (tmp_path / "lift.xml").write_text(MJCF)
    (tmp_path / "lift.circuit.toml").write_text(CIRCUIT)
    path = tmp_path / "lift.scenario.toml"
    path.write_text(f'[scene]\nmjcf = "lift.xml"\ncircuit = "lift.circuit.toml"\n[run]\nmode = "{mode}"\n'
                    'dt = 0.001\nduration = 1.0\n[initial]\nqpos = { z = 0.55 }\nequilibrium = true\n[log]\nrate_hz = 200\n')
    return path


def test_the_source_is_a_fixed_node_at_its_gauge_pressure(tmp_path):
    """One port, its net a fixed node at p_ref + Δp_s; a negative gauge pressure is refused naming the field."""
    _scene(tmp_path, "mujoco")
    net = NetworkModel.from_circuit(load_circuit(tmp_path / "lift.circuit.toml"))
    k = net.node("supply")
    assert net.node_fixed[k] and net.node_fixed_pressure[k] == pytest.approx(1.01325e5 + SOURCE)
    with pytest.raises(CircuitError, match=r"field 'pressure'.*\[0, 1e\+09\] Pa"):
        build_component("pressure_source", {"pressure": -1.0}, "c.toml: component 'source'")


def _expected_speed(fluid):
    area = math.pi / 4 * BORE**2
    load = MASS * G / area  # Pa above the reference in the cap
    flow = orifice_textbook(ORIFICE, CD, SOURCE - load, fluid)  # oil content [m³/s]
    phi = float(fluid.fill_ratio(fluid.reference_pressure + load)[0])
    return flow / (area * phi)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_a_source_through_an_orifice_lifts_the_load_at_the_orifice_law_speed(tmp_path, mode):
    """Steady speed within 1 % of the orifice law (measured 3e-13, 2e-10); the ledger closes: |residual| within 0.1 % of the source's work
    (source work = potential + kinetic + oil energy + the orifice's loss); the monitor checks the energy and lets
    the run complete."""
    path = _scene(tmp_path, mode)
    monitor = M.RunMonitor(make_plant(load_scene(load_scenario(path))))
    assert monitor.energy, monitor.energy_off
    result = run(path, out=tmp_path / "run.mcap")
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    cyl = log.topic("/hydroplant/cylinders/lift")
    steady = (cyl.t > 0.5) & (cyl.t < 0.95)
    fluid = load_circuit(tmp_path / "lift.circuit.toml").fluid
    assert float(cyl["velocity_mps"][steady].mean()) == pytest.approx(_expected_speed(fluid), rel=0.01)
    energy = log.topic("/hydroplant/energy")
    supplied = float(energy["pump_work_j"][-1])
    lifted = MASS * G * (float(cyl["position_m"][-1]) - float(cyl["position_m"][0]))
    assert supplied > lifted > 0
    # measured 9e-5 (MuJoCo) and 4e-5 (PBD) of the supplied 669 J; without the source metered it would be all of it
    assert abs(float(energy["residual_j"][-1])) < 1e-3 * supplied, (float(energy["residual_j"][-1]), supplied)
