"""The plausibility monitor (sim.run.monitor): wrong runs stop with the time, the component and the quantity;
right runs complete; ``--no-monitor`` goes on with warnings in the log."""

import re
import shutil

import pytest

from conftest import MODELS
from sim.cli import main
from sim.io.examples import example_path, examples
from sim.io.mcap_log import read_log
from sim.io.scenario import ScenarioError, load_scenario
from sim.run import monitor as M
from sim.run.runner import run
from reference.scenes import vertical_lift

BOOM = MODELS / "boom"


def _boom_copy(tmp_path, *, circuit=None, mjcf=None, scenario: str):
    """The boom scene copied into tmp_path with its circuit / MJCF text replaced and a scenario written."""
    for f in BOOM.iterdir():
        if f.is_file():
            shutil.copy(f, tmp_path / f.name)
    if circuit is not None:
        (tmp_path / "boom.circuit.toml").write_text(circuit)
    if mjcf is not None:
        (tmp_path / "boom.xml").write_text(mjcf)
    path = tmp_path / "test.scenario.toml"
    path.write_text('[scene]\nmjcf = "boom.xml"\ncircuit = "boom.circuit.toml"\n' + scenario)
    return path


def _circuit_without(name: str, *, reverse: bool = False) -> str:
    """The boom circuit with component ``name`` deleted, or with its two ports swapped (``reverse``)."""
    blocks = (BOOM / "boom.circuit.toml").read_text().split("[[component]]")
    out = [blocks[0]]
    for block in blocks[1:]:
        if f'name = "{name}"' in block:
            if not reverse:
                continue
            block = block.replace('ports = { inlet = "supply", outlet = "tank" }', 'ports = { inlet = "tank", outlet = "supply" }')
        out.append(block)
    return "[[component]]".join(out)


# the boom driven against its end stop: the pump's whole flow must go somewhere (the pump starts at 0.1 s, so the
# equilibrium start, which knows no pump flow, is the same with and without the relief)
END_STOP = """[run]
dt = 0.001
duration = 2.0
[initial]
qpos = { boom_hinge = 0.7 }
[inputs]
boom_valve = { t = [0.0, 0.1, 0.2], value = [0.0, 0.0, 1.0] }
pump = { t = [0.0, 0.1, 0.2], value = [0.0, 0.0, 40.0] }
"""


def _result_record(result):
    return read_log(result.log_path).metadata["hydroplant.result"]


CASES = [("mujoco", c, False) for c in ("implicit", "implicit-linear", "rosenbrock", "explicit")] + [
    ("pbd", c, False) for c in ("implicit", "implicit-linear", "rosenbrock")] + [("mujoco", "implicit", True), ("pbd", "implicit", True)]


@pytest.mark.parametrize("mode,coupling,reverse", CASES,
                         ids=[f"{m}-{c}-{'reversed' if r else 'deleted'}" for m, c, r in CASES])
def test_a_circuit_without_its_relief_stops_on_pressure(tmp_path, capsys, mode, coupling, reverse):
    """Dead-headed at the end stop, the pump raises the supply to the bound (no relief: NO_RELIEF_PRESSURE_LIMIT;
    reversed: 2 x (200 bar + 10 %) + ambient = 441.013 bar); the run stops there, exit status 3, the node named,
    at the same time within 1 ms in every mode and coupling (the pump's flow into the supply's oil column)."""
    scenario = END_STOP.replace("[run]\n", f'[run]\nmode = "{mode}"\ncoupling = "{coupling}"\n')
    path = _boom_copy(tmp_path, circuit=_circuit_without("relief", reverse=reverse), scenario=scenario)
    bound = M.NO_RELIEF_PRESSURE_LIMIT if not reverse else 2.0 * 1.1 * 2.0e7 + 1.01325e5
    result = run(path, out=tmp_path / "run.mcap")
    assert result.status == "diverged"
    match = re.match(r"t = ([0-9.]+) s, node '(\w+)': pressure ([0-9.]+) bar above its bound ([0-9.]+) bar", result.message)
    assert match, result.message
    assert match.group(2) in ("supply", "boom_valve_a", "boom_cyl_cap")  # the pump side of the closed circuit
    assert float(match.group(3)) * 1e5 > bound and float(match.group(4)) == pytest.approx(bound / 1e5, rel=1e-6)
    assert float(match.group(1)) == pytest.approx(result.simulated_time)
    if not reverse:
        assert 0.471 <= result.simulated_time <= 0.474
    else:
        assert 0.2 < result.simulated_time < 0.471
    log = read_log(result.log_path)  # kept, finished, marked, the last sample and the event at the stop
    record = log.metadata["hydroplant.result"]
    assert record["status"] == "diverged" and record["check"] == "plausibility" and record["quantity"] == "pressure"
    assert float(record["time_s"]) == result.simulated_time and record["component"] == f"node '{match.group(2)}'"
    events = log.topic("/hydroplant/events")
    assert events.messages[-1]["message"] == "implausible: " + result.message
    assert events.log_time[-1] == log.topic("/hydroplant/nodes").log_time[-1] == round(result.simulated_time * 1e9)
    if (mode, coupling) == ("mujoco", "implicit"):  # the CLI: exit status 3, its status line the monitor's message
        assert main(["run", str(path), "--out", str(tmp_path / "cli.mcap"), "--no-progress"]) == 3
        assert f"status        diverged: {result.message}" in capsys.readouterr().out


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_the_block_path_finds_the_same_step_as_the_per_step_path(tmp_path, mode):
    """A block whose per-step pressure extremes leave the bound is replayed step by step: the block path (fast MuJoCo
    plant, PBD compiled blocks) stops at the same step, node and log time as the per-step path."""
    path = _boom_copy(tmp_path, circuit=_circuit_without("relief"), scenario=END_STOP.replace("[run]\n", f'[run]\nmode = "{mode}"\n'))
    fast = run(path, out=tmp_path / "fast.mcap")
    slow = run(path, out=tmp_path / "slow.mcap", fast=False)
    assert fast.status == slow.status == "diverged"
    assert fast.steps == slow.steps and fast.message.split(":")[0] == slow.message.split(":")[0]
    assert read_log(fast.log_path).topic("/hydroplant/nodes").log_time[-1] == round(fast.simulated_time * 1e9)


def test_no_monitor_goes_on_with_a_warning_event(tmp_path):
    """--no-monitor: the same relief-less circuit runs to the end (exit 0), the log holds the warnings."""
    path = _boom_copy(tmp_path, circuit=_circuit_without("relief"), scenario=END_STOP.replace("duration = 2.0", "duration = 0.5"))
    out = tmp_path / "run.mcap"
    assert main(["run", str(path), "--out", str(out), "--no-progress", "--no-monitor"]) == 0
    log = read_log(out)
    assert log.metadata["hydroplant.result"]["status"] == "complete"
    events = [m["message"] for m in log.topic("/hydroplant/events").messages]
    assert any(e.startswith("plausibility monitor off") for e in events)
    assert any("plausibility (monitor off, the run goes on)" in e and "pressure" in e and "bar above its bound" in e
               for e in events)


def test_the_scenario_setting_and_its_errors(tmp_path):
    path = _boom_copy(tmp_path, scenario=END_STOP + "[monitor]\nenabled = false\n")
    assert load_scenario(path).monitor is False
    path.write_text(path.read_text().replace("enabled = false", "enabled = 1"))
    with pytest.raises(ScenarioError, match=r"\[monitor\].*'enabled'"):
        load_scenario(path)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_a_joint_pushed_through_a_soft_limit_stops_on_its_range(tmp_path, mode):
    """The boom's hinge limited to 0.5 rad by a soft limit (solreflimit 0.5 s) and its cylinder's end stop removed:
    the cylinder's 200 bar push the hinge past 0.5 + JOINT_RANGE_TOLERANCE_HINGE = 0.55 rad (the cylinder still inside
    its stroke), found at a logged sample (100 Hz), the same in both modes."""
    mjcf = (BOOM / "boom.xml").read_text()
    mjcf = mjcf.replace('limited="true" range="-0.2448 0.7710"', 'limited="true" range="-0.2448 0.5" solreflimit="0.5 1"')
    mjcf = mjcf.replace('limited="true" range="0.66 1.06"', 'limited="false" range="0.66 1.06"')
    scenario = (f'[run]\nmode = "{mode}"\ndt = 0.001\nduration = 3.0\n[initial]\nqpos = {{ boom_hinge = 0.3 }}\n[inputs]\n'
                "boom_valve = { t = [0.0, 0.1, 0.3], value = [0.0, 0.0, 1.0] }\npump = 40.0\n")
    result = run(_boom_copy(tmp_path, mjcf=mjcf, scenario=scenario), out=tmp_path / "run.mcap")
    assert result.status == "diverged"
    bound = 0.5 + M.JOINT_RANGE_TOLERANCE_HINGE
    match = re.match(r"t = ([0-9.]+) s, joint 'boom_hinge': position ([0-9.]+) rad outside its range -0.2448 .. 0.5 rad "
                     r"\(bound ([0-9.]+) rad", result.message)
    assert match, result.message
    assert float(match.group(3)) == pytest.approx(bound) and float(match.group(2)) > bound and result.final_joints["boom_hinge"] == pytest.approx(float(match.group(2)), abs=1e-4)
    assert round(float(match.group(1)) * 100) == pytest.approx(float(match.group(1)) * 100, abs=1e-9)  # a logged sample
    assert result.final_strokes["boom_cyl"] < 0.4  # the stroke is still inside its ends


def test_pbd_pin_errors_name_the_joint():
    """PBD mode checks its own constraint errors: the boom body moved 0.1 m off its hinge pin reads as a pin error of
    0.1 m on joint 'boom_hinge' (world position of the two anchors), beyond EQUALITY_TOLERANCE."""
    from sim.io.scene import load_scene
    from sim.run.runner import make_plant

    plant = make_plant(load_scene(load_scenario(BOOM / "lift.scenario.toml").with_overrides(mode="pbd")))
    monitor = M.RunMonitor(plant)
    assert monitor.check_constraints(0.0) is None
    boom = plant.xmodel.body_names.index("boom")
    plant.state.x[boom] += (0.0, 0.06, 0.08)
    found = monitor.check_constraints(0.25)
    assert found.component == "joint 'boom_hinge'" and found.quantity == "violation"
    assert found.value == pytest.approx(0.1, rel=1e-9)
    assert found.message.startswith("t = 0.25 s, joint 'boom_hinge': violation 0.1 m beyond the tolerance 0.01 m")


# a 5 t load hanging from a vertical cylinder whose annulus is vented and that has no end stop
HANGING_MJCF = """<mujoco model="hanging">
  <option timestep="0.001" integrator="implicitfast" gravity="0 0 -9.81"/>
  <worldbody>
    <site name="barrel" pos="0 0 3"/>
    <body name="load" pos="0 0 2">
      <joint name="drop" type="slide" axis="0 0 1" limited="false"/>
      <inertial pos="0 0 0" mass="5000" diaginertia="100 100 100"/>
      <site name="rod" pos="0 0 0"/>
    </body>
  </worldbody>
  <tendon>
    <spatial name="boom_cyl" limited="false" range="0.5 1.5"><site site="barrel"/><site site="rod"/></spatial>
  </tendon>
  <actuator>
    <general name="boom_cyl" tendon="boom_cyl" gaintype="fixed" gainprm="1" biastype="affine" biasprm="0 0 0"/>
  </actuator>
</mujoco>
"""


def _fall_time(bound: float, x0: float = 0.5) -> float:
    """When the free-falling 5 t load's rod passes ``bound`` [s]: m·ẍ = m·g − c·ẋ − F_c + (p_cav − p_amb)·A_cap (seal
    friction, viscous c = 2000 N·s/m and Coulomb F_c = 400 N; the cap chamber cavitated at 3 kPa, the annulus vented)."""
    import math

    m, g, c, coulomb = 5000.0, 9.81, 2000.0, 400.0
    pressure = (3.0e3 - 1.01325e5) * math.pi / 4 * 0.063**2
    x, v, t, h = x0, 0.0, 0.0, 1e-6
    while x < bound:
        v += h * (g - (c * v + coulomb - pressure) / m)
        x += h * v
        t += h
    return t


@pytest.mark.parametrize("mode,coupling", [("mujoco", "explicit"), ("mujoco", "implicit"), ("pbd", "implicit")])
def test_a_load_falling_through_the_cylinder_stops_on_stroke(tmp_path, mode, coupling):
    """5 t on a 1 m cylinder with its rod chamber vented and its valve closed and no end stop: nothing holds the load
    (the cap chamber cavitates), it falls from mid-stroke and passes the bound stroke + max(1 cm, 5 %) = 1.05 m at
    t = 0.345 s (:func:`_fall_time`; 0.335 s in free fall); the run stops within 1.5 ms of it, naming the cylinder
    (explicit coupling on the per-step path, the implicit ones from the blocks' per-step stroke extremes)."""
    bound = 1.0 + max(M.STROKE_TOLERANCE, M.STROKE_TOLERANCE_FRACTION * 1.0)
    circuit = (BOOM / "boom.circuit.toml").read_text()
    circuit = circuit.replace("stroke = 0.40 ", "stroke = 1.0 ").replace('ports = { cap = "boom_cyl_cap", rod = "boom_cyl_rod" }',
                                                                           'ports = { cap = "boom_cyl_cap", rod = "tank" }')
    scenario = (f'[run]\nmode = "{mode}"\ncoupling = "{coupling}"\ndt = 0.001\nduration = 1.0\n[initial]\n'
                'equilibrium = false\n[inputs]\npump = 40.0\n')
    path = _boom_copy(tmp_path, circuit=circuit, mjcf=HANGING_MJCF, scenario=scenario)
    result = run(path, out=tmp_path / "run.mcap")
    assert result.status == "diverged"
    match = re.match(r"t = [0-9.]+ s, cylinder 'boom_cyl': stroke ([0-9.]+) m beyond its extended end \(stroke 0 \.\. 1 m, "
                     r"bound ([0-9.]+) m", result.message)
    assert match, result.message
    assert float(match.group(2)) == pytest.approx(bound) and bound < float(match.group(1)) < bound + 0.01
    assert result.simulated_time == pytest.approx(_fall_time(bound), abs=1.5e-3)
    assert _result_record(result)["quantity"] == "stroke"


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
@pytest.mark.parametrize("speed", [20.0, 1e300])
def test_a_huge_start_velocity_does_not_end_complete(tmp_path, mode, speed):
    """The boom started at 20 rad/s slams its rod chamber past 441 bar within 2 ms; at 1e300 rad/s the kinetic energy
    is infinite at t = 0: both stop, naming the node or the joint, in both modes."""
    result = run(example_path("boom/lift"), out=tmp_path / "run.mcap",
                 overrides={"mode": mode, "duration": 0.5, "qvel": {"boom_hinge": speed}})
    assert result.status == "diverged" and _result_record(result)["check"] == "plausibility"
    if speed == 20.0:
        assert re.match(r"t = 0\.00[1-5] s, node 'boom_cyl_rod': pressure", result.message), result.message
    else:
        assert result.message.startswith("t = 0 s, joint 'boom_hinge': start energy inf J is not finite")


def test_a_leftover_velocity_actuator_braking_the_boom_shows_in_the_residual(tmp_path, monkeypatch):
    """A <velocity kv=2e5> actuator on the boom hinge the circuit does not drive, left acting (the scene loader's
    zeroing of undriven actuators switched off): the lowering boom's potential energy goes into the brake, outside
    every modelled loss, and the energy residual passes half the throughput; without the brake the same run's
    residual stays below 1 % of it."""
    import sim.io.scene

    monkeypatch.setattr(sim.io.scene, "disable_unbound_actuators", lambda *args, **kwargs: None, raising=False)
    mjcf = (BOOM / "boom.xml").read_text()
    braked = mjcf.replace("</actuator>", '  <velocity name="brake" joint="boom_hinge" kv="200000"/>\n  </actuator>')
    scenario = ("[run]\ndt = 0.001\nduration = 3.0\n[initial]\nqpos = { boom_hinge = 0.5 }\n[inputs]\n"
                "boom_valve = { t = [0.0, 0.2, 0.4], value = [0.0, 0.0, -1.0] }\npump = 0.0\n")
    free = run(_boom_copy(tmp_path, scenario=scenario), out=tmp_path / "free.mcap")
    assert free.status == "complete" and abs(free.energy["residual"]) < 0.01 * abs(free.energy["delta"])
    path = _boom_copy(tmp_path, mjcf=braked, scenario=scenario)
    result = run(path, out=tmp_path / "braked.mcap")
    assert result.status == "diverged"
    assert re.match(r"t = [0-9.]+ s, energy balance: residual [0-9.e+]+ J beyond the bound", result.message), result.message
    e = result.energy
    floor = M.ENERGY_RESIDUAL_FLOOR_PER_KG * 350.0  # the boom and its payload
    assert e["residual"] > M.ENERGY_RESIDUAL_FRACTION * (e["pump_work"] + abs(e["delta"])) + floor
    assert f"+ {floor:g} J): energy is lost or made outside the modelled losses" in result.message


def test_a_loop_closure_pulled_apart_stops_on_the_equality(tmp_path):
    """A soft connect (solref 0.5 s) holding the boom tip to the world: the lifting cylinder pulls it apart by more
    than EQUALITY_TOLERANCE; the run stops naming the equality."""
    mjcf = (BOOM / "boom.xml").read_text().replace(
        "</tendon>", '</tendon>\n  <equality>\n    <connect name="tip_stay" body1="boom" anchor="2.5 0 0" solref="0.5 1"/>\n  </equality>')
    scenario = ("[run]\ndt = 0.001\nduration = 2.0\n[initial]\nqpos = { boom_hinge = 0.0 }\n[inputs]\n"
                "boom_valve = { t = [0.0, 0.1, 0.3], value = [0.0, 0.0, 1.0] }\npump = 40.0\n")
    result = run(_boom_copy(tmp_path, mjcf=mjcf, scenario=scenario), out=tmp_path / "run.mcap")
    assert result.status == "diverged"
    match = re.match(r"t = [0-9.]+ s, equality 'tip_stay': violation ([0-9.]+) m beyond the tolerance 0.01 m", result.message)
    assert match, result.message
    assert float(match.group(1)) > M.EQUALITY_TOLERANCE and _result_record(result)["quantity"] == "violation"


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
@pytest.mark.parametrize("name", [name for name, _ in examples()])
def test_every_shipped_scenario_completes(tmp_path, name, mode):
    """Right runs stay within every bound: each example completes in both modes (the closed-cylinder benchmark,
    whose scheme damps its unresolved oil column on purpose, has its monitor set to warn)."""
    result = run(example_path(name), out=tmp_path / "run.mcap", overrides={"mode": mode})
    assert result.status == "complete", result.message


# --------------------------------------------------------------------------------- every level
def test_a_start_pose_inside_the_ground_is_refused_before_the_oil_is_driven_to_megabars(tmp_path, capsys):
    """The push scene with the stick at 0.0 rad (inside its range) buries the bucket 0.56 m in the ground: counted
    in the equilibrium its contacts drove the boom's rod side to megabars, left out they throw the machine on the
    first step. The start pose is refused in one line naming the field, the two geoms and the allowed overlap."""
    folder = tmp_path / "excavator"
    shutil.copytree(MODELS / "excavator", folder)
    scenario = folder / "push.scenario.toml"
    text = scenario.read_text()
    assert text.count("stick = -0.50") == 1
    scenario.write_text(text.replace("stick = -0.50", "stick = 0.0"))
    assert load_scenario(scenario).fidelity == "incompressible"
    assert main(["run", str(scenario), "--no-progress", "--out", str(tmp_path / "push.mcap")]) == 2
    error = capsys.readouterr().err.strip()
    assert "\n" not in error and f"{scenario}, field 'initial.qpos'" in error
    assert "geoms 'ground' and 'tooth_" in error and "overlap by 0.5" in error and "at most 0.05 m" in error
    assert not (tmp_path / "push.mcap").exists()


# ------------------------------------------------------------------------ consistent tolerances
LOAD_MJCF = vertical_lift(mass=10.0)


def _load_scene(tmp_path, *, start: float, mode: str, circuit: str | None = None):
    """A 10 kg load on a vertical slide lifted directly by the lift_1dof circuit's 50 mm cylinder (0.5 m stroke),
    at a 60 Hz step, valve opened at 0.5 s."""
    (tmp_path / "load.xml").write_text(LOAD_MJCF)
    (tmp_path / "lift.circuit.toml").write_text(circuit or (MODELS / "lift_1dof" / "lift.circuit.toml").read_text())
    path = tmp_path / "load.scenario.toml"
    path.write_text(f'[scene]\nmjcf = "load.xml"\ncircuit = "lift.circuit.toml"\n[run]\nmode = "{mode}"\n'
                    f'dt = 0.016666666666666666\nduration = 3.0\n[initial]\nqpos = {{ z = {start} }}\nequilibrium = true\n'
                    '[inputs]\nvalve = { t = [0.0, 0.5, 0.6], value = [0.0, 0.0, 1.0] }\npump = 20.0\n[log]\nrate_hz = 60\n')
    return path


def test_a_10_kg_load_lifted_at_60_hz_completes_at_the_pumps_speed(tmp_path):
    """12 L/min into a 50 mm bore lifts the load at Q/A = 0.102 m/s once the supply line has emptied into the cap:
    measured with the monitor on, to 2 %."""
    result = run(_load_scene(tmp_path, start=0.55, mode="mujoco"), out=tmp_path / "run.mcap")
    assert result.status == "complete", result.message
    cyl = read_log(result.log_path).topic("/hydroplant/cylinders/lift")
    moving = (cyl.t > 1.5) & (cyl.t < 2.9)
    import math

    expected = 1.0e-5 * 20.0 / (math.pi / 4 * 0.05**2)
    assert float(cyl["velocity_mps"][moving].mean()) == pytest.approx(expected, rel=0.02)


def test_slide_joint_and_stroke_tolerances_agree(tmp_path):
    """A cylinder lifting a load on a slide joint: the joint's range and the tendon's are the same soft end stop, so
    both are allowed the same overshoot, max(10 mm, 5 % of the range or stroke) = 25 mm here, and a joint message
    states that rule."""
    from sim.io.scene import load_scene
    from sim.run.runner import make_plant

    path = _load_scene(tmp_path, start=0.95, mode="pbd")
    monitor = M.RunMonitor(make_plant(load_scene(load_scenario(path))))
    assert monitor.joint_high[0] - 1.0 == pytest.approx(monitor.stroke_high[0] - 0.5) == pytest.approx(0.025)
    assert monitor.joint_low[0] - 0.5 == pytest.approx(monitor.stroke_low[0]) == pytest.approx(-0.025)
    import numpy as np

    zero = np.zeros(1)
    batch = {"joint_position": np.array([[1.03]]), "step": np.array([60]), "kinetic": zero, "potential": zero,
             "oil": zero, "pump_work": zero, "residual": zero}
    found = monitor.check_batch(batch, 1 / 60, 0.0)
    assert found is not None and found[1].message == (
        "t = 1 s, joint 'z': position 1.03 m outside its range 0.5 .. 1 m (bound 1.025 m: tolerance max(0.01 m, 5% of "
        "the range))")


# ------------------------------------------------------------------------- fixed-pressure supply
def test_a_supply_at_a_fixed_pressure_is_not_stopped(tmp_path):
    """The lift circuit fed by a tank at 200 bar instead of its pump: the ledger counts the work the fixed-pressure
    node supplies (μ(p)·net outflow) with the pump work, so the monitor checks the energy residual and the run
    completes, the load rising, with a residual below 1 % of the supplied work."""
    circuit = (MODELS / "lift_1dof" / "lift.circuit.toml").read_text()
    blocks = circuit.split("[[component]]")
    kept = [blocks[0]] + [b for b in blocks[1:] if 'name = "pump"' not in b and 'name = "relief"' not in b]
    source = '\nname = "source"\ntype = "tank"\npressure = 2.0e7\nports = { port = "supply" }\n\n'
    path = _load_scene(tmp_path, start=0.55, mode="mujoco", circuit="[[component]]".join(kept + [source]))
    path.write_text(path.read_text().replace("pump = 20.0\n", ""))
    from sim.io.scene import load_scene
    from sim.run.runner import make_plant

    monitor = M.RunMonitor(make_plant(load_scene(load_scenario(path))))
    assert monitor.energy and monitor.sources == ["supply"]
    result = run(path, out=tmp_path / "run.mcap", overrides={"duration": 1.5, "dt": 1e-3})
    assert result.status == "complete", result.message
    assert result.final_strokes["lift"] > 0.06
    energy = read_log(result.log_path).topic("/hydroplant/energy")
    assert abs(float(energy["residual_j"][-1])) < 0.01 * float(energy["pump_work_j"][-1])


# ------------------------------------------------------------------------------ equalities
def test_the_equality_violation_is_the_whole_gap_not_its_largest_component():
    """A connect pulled 8 mm in x and 8 mm in z: each component is within 10 mm, the gap (11.3 mm) is not."""
    import types

    import mujoco
    import numpy as np

    model = mujoco.MjModel.from_xml_string("""<mujoco><worldbody><body name="b">
      <joint name="x" type="slide" axis="1 0 0"/><joint name="z" type="slide" axis="0 0 1"/>
      <inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></worldbody>
      <equality><connect name="pin" body1="b" anchor="0 0 0"/></equality></mujoco>""")
    data = mujoco.MjData(model)
    data.qpos[:] = (0.008, 0.008)
    mujoco.mj_forward(model, data)
    name, gap = M.ConstraintErrors(types.SimpleNamespace(model=model, data=data)).worst()
    assert name == "equality 'pin'" and gap == pytest.approx(0.008 * np.sqrt(2), rel=1e-6)


def test_the_incompressible_level_checks_the_energy_residual(tmp_path, monkeypatch):
    """At the ``incompressible`` level the supplied work is that of the forces applied to the actuators (the rigid
    oil stores nothing), so the residual is checked there too: the boom lowered at the metered speed completes with
    a residual below 2 % of the change of stored energy, and the same boom with a
    leftover <velocity kv=2e5> brake on its hinge stops on the energy residual, exit 3 naming the energy balance."""
    import sim.io.scene

    monkeypatch.setattr(sim.io.scene, "disable_unbound_actuators", lambda *args, **kwargs: None, raising=False)
    scenario = ('[run]\nfidelity = "incompressible"\ndt = 0.001\nduration = 2.0\n[initial]\nqpos = { boom_hinge = 0.5 }\n'
                "[inputs]\nboom_valve = { t = [0.0, 0.2, 0.4], value = [0.0, 0.0, -1.0] }\npump = 40.0\n")
    path = _boom_copy(tmp_path, scenario=scenario)
    from sim.io.scene import load_scene
    from sim.run.runner import make_plant

    assert M.RunMonitor(make_plant(load_scene(load_scenario(path)))).energy
    free = run(path, out=tmp_path / "free.mcap")
    assert free.status == "complete", free.message
    assert abs(free.energy["residual"]) < 0.02 * abs(free.energy["delta"])  # measured 0.7 %
    braked = (BOOM / "boom.xml").read_text().replace(
        "</actuator>", '  <velocity name="brake" joint="boom_hinge" kv="200000"/>\n  </actuator>')
    result = run(_boom_copy(tmp_path, mjcf=braked, scenario=scenario), out=tmp_path / "braked.mcap")
    assert result.status == "diverged"
    assert re.match(r"t = [0-9.]+ s, energy balance: residual [0-9.e+]+ J beyond the bound", result.message), result.message
