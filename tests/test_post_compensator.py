"""The post-compensator (flow sharing): its law against the hand formula, and two loads lifted from one saturated
load-sensing pump, in both modes.

* Law: the orifice law through the opening S((p_in − p_LS − Δp_s)/w + 1), derivatives against central differences.
* Flow sharing: two lifts (200 kg and 2000 kg, 10 and 100 bar) behind metering orifices of areas 2:1 on a pump
  that gives about two thirds of what the sections ask at its margin.  Downstream compensators hold both metering
  edges' outlets at the LS line, so both edges see the same drop and the flows stand in the ratio of the areas,
  2 within 10 % (the compensators' 0.5 bar band and the shuttle's drop), whatever the loads; the same machine with
  pre-compensators upstream of the edges keeps the light section's flow and slows the heavy load instead (the ratio
  more than 20 % off), which is what flow sharing is for.
"""

from __future__ import annotations

import numpy as np
import pytest

from hydraulics.components import PostCompensator
from hydraulics.components.post_compensator import flow_with_derivatives as post_law
from hydraulics.fluid import Fluid
from reference.circuits import bench, orifice
from reference.laws import orifice_textbook
from sim.io.mcap_log import read_log
from sim.run.runner import run

FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.01325e5)
P0 = FLUID.reference_pressure
VALVE = PostCompensator(area=3e-5, spring_pressure=1e5, regulation_band=3e5)
# (p_in, p_out, p_ls): open (inlet above LS + spring), regulating, shut, reverse
POINTS = [(P0 + 1.02e7, P0 + 5e6, P0 + 1e7), (P0 + 9.9e6, P0 + 5e6, P0 + 1e7), (P0 + 9.7e6, P0 + 5e6, P0 + 1e7),
          (P0 + 9.9e6, P0 + 1.05e7, P0 + 1e7)]


@pytest.mark.parametrize("point", POINTS)
def test_post_compensator_law_equals_hand_value_and_derivatives(point):
    row = VALVE.law_row(FLUID)
    p_in, p_out, p_ls = point
    z = (p_in - p_ls - VALVE.spring_pressure) / VALVE.regulation_band + 1
    y = 0.0 if z <= 0 else 1.0 if z >= 1 else 3 * z**2 - 2 * z**3
    q, d_in, d_out, d_ls = post_law(row, *point)
    expected = orifice_textbook(VALVE.leakage_area + VALVE.area * y, VALVE.discharge_coefficient, p_in - p_out, FLUID)
    assert q == pytest.approx(expected, rel=1e-12, abs=1e-22)
    for k, d in ((0, d_in), (1, d_out), (2, d_ls)):
        up, down = list(point), list(point)
        up[k] += 1.0
        down[k] -= 1.0
        numeric = (post_law(row, *up)[0] - post_law(row, *down)[0]) / 2
        assert d == pytest.approx(numeric, rel=1e-6, abs=1e-9 * max(abs(d_in), abs(d_out)))


MJCF = """<mujoco model="two_lifts">
  <compiler angle="radian" autolimits="false"/>
  <option timestep="0.001" integrator="implicitfast"/>
  <worldbody>
""" + "".join(f"""    <site name="{name}_barrel" pos="{x} 0 0" size="0.01"/>
    <body name="{name}_load" pos="{x} 0 0">
      <joint name="{name}_z" type="slide" axis="0 0 1" limited="true" range="0.5 1.0"/>
      <inertial pos="0 0 0" mass="{mass}" diaginertia="0.01 0.01 0.01"/>
      <site name="{name}_rod" pos="0 0 0" size="0.01"/>
    </body>
""" for name, x, mass in (("light", 0.0, 200.0), ("heavy", 1.0, 2000.0))) + """  </worldbody>
  <tendon>
""" + "".join(f"""    <spatial name="{name}" limited="true" range="0.5 1.0"><site site="{name}_barrel"/><site site="{name}_rod"/></spatial>
""" for name in ("light", "heavy")) + """  </tendon>
  <actuator>
""" + "".join(f"""    <general name="{name}" tendon="{name}" ctrllimited="false" gaintype="fixed" gainprm="1" biastype="affine" biasprm="0 0 0"/>
""" for name in ("light", "heavy")) + """  </actuator>
</mujoco>
"""

HEAD = bench() + """
[[component]]
name = "pump"
type = "pump_load_sensing"
displacement = 1.0e-5
speed = 20.0
margin = 2.0e6
cutoff_pressure = 3.0e7
regulator_band = 1.0e6
stroke_time = 0.05
proportional_gain = 2.0e-7
ports = { inlet = "tank", outlet = "supply", ls = "ls" }

[[component]]
name = "supply_volume"
type = "volume"
volume = 1.0e-3
ports = { port = "supply" }

[[component]]
name = "ls_volume"
type = "volume"
volume = 1.0e-5
ports = { port = "ls" }

""" + orifice("ls_bleed", "ls", "tank", 2.0e-8)

SECTION = """
[[component]]
name = "{s}"
type = "cylinder"
bore = 0.05
rod_diameter = 0.025
stroke = 0.5
dead_volume_cap = 5.0e-5
dead_volume_rod = 5.0e-5
ports = {{ cap = "{s}_cap", rod = "{s}_rod" }}

{s_return}
[[component]]
name = "{s}_inner_volume"
type = "volume"
volume = 1.0e-5
ports = {{ port = "{s}_inner" }}

[[component]]
name = "{s}_shuttle"
type = "check_valve"
cracking_pressure = 1.0e4
full_open_pressure = 1.0e5
area = 3.0e-6
ports = {{ inlet = "{signal}", outlet = "ls" }}
"""

POST = """
{meter}
[[component]]
name = "{s}_compensator"
type = "post_compensator"
area = 1.0e-4
regulation_band = 5.0e4
ports = {{ inlet = "{s}_inner", outlet = "{s}_cap", ls = "ls" }}
"""

PRE = """
[[component]]
name = "{s}_compensator"
type = "pressure_compensator"
pressure_difference = 1.2e6
regulation_band = 1.0e6
area = 1.0e-4
ports = {{ inlet = "supply", outlet = "{s}_inner", load = "{s}_cap" }}
{meter}"""

SCENARIO = """[scene]
mjcf = "lifts.xml"
circuit = "{circuit}"

[run]
mode = "{mode}"
coupling = "implicit"
dt = 0.001
duration = 1.0

[initial]
qpos = {{ light_z = 0.6, heavy_z = 0.6 }}
equilibrium = true

[log]
rate_hz = 200
"""

AREAS = {"light": 4.0e-6, "heavy": 2.0e-6}


def lift(tmp_path, kind, mode):
    """Cylinder flows A_cap·v [m³/s] and metering-edge drops [Pa] of both lifts, averaged over 0.5 … 1.0 s (the
    pump saturated, both rising)."""
    (tmp_path / "lifts.xml").write_text(MJCF, encoding="utf-8")
    template, signal = (POST, "{s}_inner") if kind == "post" else (PRE, "{s}_cap")
    meters = {"post": ("supply", "{s}_inner"), "pre": ("{s}_inner", "{s}_cap")}[kind]
    circuit = HEAD + "".join(
        SECTION.format(s=s, signal=signal.format(s=s), s_return=orifice(f"{s}_return", f"{s}_rod", "tank", 1.0e-4))
        + template.format(s=s, meter=orifice(f"{s}_meter", *(m.format(s=s) for m in meters), a))
        for s, a in AREAS.items())
    (tmp_path / f"{kind}.circuit.toml").write_text(circuit, encoding="utf-8")
    scenario = tmp_path / f"{kind}-{mode}.scenario.toml"
    scenario.write_text(SCENARIO.format(circuit=f"{kind}.circuit.toml", mode=mode), encoding="utf-8")
    result = run(scenario, out=tmp_path / f"{kind}-{mode}.mcap")
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    swash = log.topic("/hydroplant/component_states")["state.pump_displacement_fraction"]
    assert swash[-1] > 0.98  # saturated: the pump gives all it has
    nodes = log.topic("/hydroplant/nodes")
    area = np.pi * 0.05**2 / 4
    flows, drops = {}, {}
    for name in AREAS:
        cyl = log.topic(f"/hydroplant/cylinders/{name}")
        flows[name] = area * float(np.mean(cyl["velocity_mps"][cyl.t >= 0.5]))
        edge = (("supply", f"{name}_inner") if kind == "post" else (f"{name}_inner", f"{name}_cap"))
        late = nodes.t >= 0.5
        drops[name] = float(np.mean(nodes[f"pressure_pa.{edge[0]}"][late] - nodes[f"pressure_pa.{edge[1]}"][late]))
    return flows, drops


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_post_compensators_share_a_saturated_pump_by_metering_area(tmp_path, mode):
    """Post-compensators: both metering edges see the same drop within the compensator's band and the shuttle's
    drop (0.5 + 1 bar), and the flows stand within 10 % of the areas' ratio 2; pre-compensators keep the light
    section's compensated flow and leave the heavy one the rest: their ratio is more than 20 % off."""
    shared, drops = lift(tmp_path, "post", mode)
    assert 0.0 <= drops["light"] - drops["heavy"] < 0.5e5 + 1e5
    ratio = AREAS["light"] / AREAS["heavy"]
    assert shared["heavy"] > 0 and shared["light"] / shared["heavy"] == pytest.approx(ratio, rel=0.1)
    unshared, _ = lift(tmp_path, "pre", mode)
    assert unshared["light"] / unshared["heavy"] > 1.2 * ratio
