"""Loop closures as outside models build them: a cylinder on its own barrel and rod bodies, pinned to the arm
by a ``connect`` equality (tests/scenes/loop_arm.xml), against the same arm with the pins on the links
(tests/scenes/loop_arm_links.xml).

* The equilibrium start holds the load: the cylinder force equals the virtual-work force
  F = (dV/dθ)/(dL/dθ) of the closed-form kinematics within 1 %, in both modes, and the arm
  does not sag (no leakage in this circuit) over 0.5 s.
* The inertia the cylinder sees through the loop is the same with the pins on the barrel/rod
  bodies and on the links, and ω_h = √(k/m_eff) matches a measured free oscillation within 2 %.
* With seal friction on the cylinder the loop holds as well, in both modes.
* A start pose that sets one joint of the loop is projected onto it; one that contradicts it is refused.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim.io.scenario import ScenarioError, load_scenario
from sim.io.scene import initial_qpos_qvel, load_scene
from sim.plants.constraints import equality_rows
from sim.plants.mujoco import MujocoPlant
from sim.plants.pbd import make_pbd_plant
from sim.run import guards

SCENES = Path(__file__).parent / "scenes"
HOLD = SCENES / "hold.scenario.toml"
HOLD_LINKS = SCENES / "hold_links.scenario.toml"
G = 9.81
A_PIN = np.array([0.5, 0.2])  # barrel pin (x, z) [m]
L0 = 0.9433981132056605  # pin to pin at qpos0 [m]


def virtual_work_force(theta: float) -> float:
    """Cylinder force [N] holding loop_arm at arm angle θ: (dV/dθ)/(dL/dθ) of the closed-form geometry (virtual work)."""

    def geometry(t):
        b = np.array([math.cos(t), 1.0 + math.sin(t)])  # arm pin B (x, z)
        length = float(np.linalg.norm(b - A_PIN))
        u = (b - A_PIN) / length
        z = {
            "arm": 1.0 + math.sin(t),  # 200 kg at 1 m along the arm
            "payload": 1.0 + 2.0 * math.sin(t) - 0.1 * math.cos(t),  # 100 kg at (2, -0.1) in the arm frame
            "barrel": A_PIN[1] + 0.3 * u[1],  # 20 kg, 0.3 m up the barrel
            "rod": A_PIN[1] + (length - L0 + 0.7) * u[1],  # 60 kg, 0.7 m along the rod from its slide origin
        }
        mass = {"arm": 200.0, "payload": 100.0, "barrel": 20.0, "rod": 60.0}
        return G * sum(mass[k] * z[k] for k in mass), length

    h = 1e-6
    (v1, l1), (v0, l0) = geometry(theta + h), geometry(theta - h)
    return (v1 - v0) / (l1 - l0)


def cap_force(net, state) -> float:
    """p_cap·A_cap − p_rod·A_rod − p_amb·(A_cap − A_rod) [N] of the one cylinder."""
    a_cap, a_rod = net.cylinder_cap_area[0], net.cylinder_rod_area[0]
    p = state.node_pressure
    p_cap, p_rod = p[net.cylinder_cap_node[0]], p[net.cylinder_rod_node[0]]
    return float(p_cap * a_cap - p_rod * a_rod - net.fluid.reference_pressure * (a_cap - a_rod))


def plant_for(path, mode="mujoco", **changes):
    scenario = load_scenario(path).with_overrides(mode=mode)
    if changes:
        scenario = replace(scenario, **changes)
    scene = load_scene(scenario)
    return MujocoPlant(scene) if mode == "mujoco" else make_pbd_plant(scene, block=False)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_holding_pressure_is_the_virtual_work_force_and_the_arm_does_not_sag(mode):
    plant = plant_for(HOLD, mode)
    expected = virtual_work_force(0.1)
    assert plant.holding_residual < 1e-9
    assert cap_force(plant.network, plant.net_state) == pytest.approx(expected, rel=1e-2)
    p0 = float(plant.net_state.node_pressure[plant.network.cylinder_cap_node[0]])
    angles, pressures = [], []
    for _ in range(500):
        plant.step()
        angles.append(plant.joint_state()[0][0])
        pressures.append(plant.net_state.node_pressure[plant.network.cylinder_cap_node[0]])
    # no leakage: only the settling of the loop's pin (MuJoCo's soft equality) and the oil column's ringing
    assert np.max(np.abs(np.array(angles) - 0.1)) < 1e-5
    assert np.max(np.abs(np.array(pressures) / p0 - 1.0)) < 1e-2


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_seal_friction_through_the_loop_holds_the_load(mode):
    """With cylinder seal friction (loop_friction.circuit.toml: F_s = 600 N) the closed loop holds, the friction
    acting on the cylinder between the barrel and rod bodies and the rod held to the arm by the connect.  Over
    1.5 s the arm stays within 1e-5 rad of its start angle and the cylinder's pressure force within the static
    friction band F₀ ± F_s of its start (sticking friction may carry part of the load: MuJoCo mode's soft connect
    settles into the band, its cap pressure 2 % below the start); PBD mode keeps the cap pressure within 1 %."""
    plant = plant_for(HOLD, mode, circuit=SCENES / "loop_friction.circuit.toml")
    static = float(plant.network.cylinder_static[0])
    assert static == 600.0
    cap = plant.network.cylinder_cap_node[0]
    p0, f0 = float(plant.net_state.node_pressure[cap]), cap_force(plant.network, plant.net_state)
    forces = []
    for _ in range(1500):
        plant.step()
        forces.append(cap_force(plant.network, plant.net_state))
    assert np.max(np.abs(np.array(forces) - f0)) < static
    assert abs(plant.joint_state()[0][0] - 0.1) < 1e-5
    if mode == "pbd":
        assert abs(float(plant.net_state.node_pressure[cap]) / p0 - 1.0) < 1e-2


def test_holding_ignoring_the_loop_would_be_wrong():
    """A fit over the actuator moments alone, ignoring the loop: the pins' bodies carry no load and F is far off."""
    plant = plant_for(HOLD)
    m, d = plant.model, mujoco.MjData(plant.model)
    d.qpos[:] = plant.data.qpos
    mujoco.mj_forward(m, d)
    mujoco.mj_inverse(m, d)
    from sim.plants.constraints import actuator_moments

    J = actuator_moments(m, d, plant.binding.actuator_id)
    unconstrained = np.linalg.lstsq(J.T, d.qfrc_inverse, rcond=None)[0][0]
    assert abs(unconstrained / virtual_work_force(0.1) - 1.0) > 0.5


def test_effective_mass_is_the_same_with_pins_on_barrel_and_rod_or_on_the_links():
    masses = {}
    for path in (HOLD, HOLD_LINKS):
        scene = load_scene(load_scenario(path))
        qpos, _ = initial_qpos_qvel(scene)
        masses[path.name], _ = guards.inertia_seen(scene.mjmodel, qpos, scene.binding.actuator_id)
        if path == HOLD:
            rod_alone, _ = guards.inertia_seen(scene.mjmodel, qpos, scene.binding.actuator_id, constrained=False)
    assert masses["hold.scenario.toml"][0] == pytest.approx(masses["hold_links.scenario.toml"][0], rel=1e-9)
    assert rod_alone[0] == pytest.approx(60.0, rel=1e-9)  # the rod body on its slide, without the loop
    assert masses["hold.scenario.toml"][0] > 15 * rod_alone[0]


def measured_frequency(plant, steps=600) -> float:
    """Frequency [Hz] of the cylinder extension's oscillation, from its interpolated zero crossings."""
    x = []
    for _ in range(steps):
        plant.step()
        x.append(plant.net_state.actuator_position[0])
    y = np.array(x) - np.mean(x)
    crossings = np.flatnonzero(np.diff(np.sign(y)) != 0)
    times = [(i + y[i] / (y[i] - y[i + 1])) * plant.dt for i in crossings]
    return 1.0 / (2.0 * float(np.mean(np.diff(times))))


@pytest.mark.parametrize("path", [HOLD, HOLD_LINKS], ids=["barrel-rod", "links"])
@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_omega_h_matches_a_free_oscillation_of_the_closed_cylinder(path, mode):
    plant = plant_for(path, mode, qvel={"arm_hinge": 0.01})  # closed valve, no friction: the oil column rings
    predicted = guards.check(plant.scene, plant.net_state).rows[0].frequency_hz
    assert measured_frequency(plant) == pytest.approx(predicted, rel=2e-2)


@pytest.mark.parametrize("fidelity", ["compressible", "lines"])
@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_omega_h_with_hoses_matches_a_free_oscillation_at_both_fidelities(mode, fidelity):
    """With hoses on the work ports the oil column holds the hoses' oil too: lumped into the chamber (compressible) or
    joined to it through each π-line's resistance (lines), the predicted frequency is the measured one within 2 %."""
    plant = plant_for(HOLD, mode, qvel={"arm_hinge": 0.01}, circuit=SCENES / "loop_hoses.circuit.toml", fidelity=fidelity)
    assert len(plant.network.hose_lines) == (2 if fidelity == "lines" else 0)
    predicted = guards.check(plant.scene, plant.net_state).rows[0].frequency_hz
    assert measured_frequency(plant, 1500) == pytest.approx(predicted, rel=2e-2)


def test_start_pose_setting_one_joint_of_the_loop_is_projected_onto_it():
    scene = load_scene(replace(load_scenario(HOLD), qpos={"barrel_hinge": -0.06}))
    qpos, _ = initial_qpos_qvel(scene)
    m = scene.mjmodel
    assert qpos[m.jnt_qposadr[m.joint("barrel_hinge").id]] == -0.06  # the joint the user set is kept
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    _, violation, names = equality_rows(m, d)
    assert names == ("rod_eye",) * 3 and np.max(np.abs(violation)) < 1e-9
    assert qpos[m.jnt_qposadr[m.joint("arm_hinge").id]] != 0.0  # the arm followed


def test_start_pose_contradicting_the_loop_is_refused_naming_the_equality():
    scenario = replace(load_scenario(HOLD), qpos={"arm_hinge": 0.1, "barrel_hinge": 0.3, "rod_slide": 0.0})
    with pytest.raises(ScenarioError, match=r"hold.scenario.toml, \[initial\]: equality 'rod_eye' is violated by .* at the start pose"):
        load_scene(scenario)


def test_a_start_the_actuators_and_loops_cannot_hold_is_warned(tmp_path):
    """Without the rod's pin the arm hangs on nothing: the static balance leaves 99 % of the load unheld."""
    import re
    import shutil

    from sim.run.guards import check_plant

    for name in ("hold.scenario.toml", "loop.circuit.toml"):
        shutil.copy(SCENES / name, tmp_path / name)
    (tmp_path / "loop_arm.xml").write_text(re.sub(r'<connect name="rod_eye"[^>]*/>', "", (SCENES / "loop_arm.xml").read_text()))
    plant = MujocoPlant(load_scene(load_scenario(tmp_path / "hold.scenario.toml")))
    assert plant.holding_residual == pytest.approx(0.992, abs=1e-3)
    (warning,) = [w for w in check_plant(plant).warnings if "initial.equilibrium" in w]
    assert warning.startswith(f"{tmp_path / 'hold.scenario.toml'}, field 'initial.equilibrium': the actuators and the MJCF's "
                              "equality constraints cannot hold the start pose at rest (static balance residual 0.992 of the load)")


def cap_pressure_range(plant, steps) -> tuple:
    p = []
    for _ in range(steps):
        plant.step()
        p.append(plant.net_state.node_pressure[plant.network.cylinder_cap_node[0]])
    return min(p), max(p)


def test_a_light_rod_near_its_retracted_end_is_warned_and_diverges_where_the_guard_says():
    """Arm at −0.2 rad: x = 0.019 m, the stiff column rings the 60 kg rod at ω_local·dt = 2.12 > √2 and MuJoCo mode
    diverges at 1 ms; at the advised dt (0.6 ms, ω_local·dt = 1.27) the start's ringing decays to its equilibrium pressure."""
    plant = plant_for(HOLD, qpos={"arm_hinge": -0.2})
    (warning,) = [w for w in guards.check(plant.scene, plant.net_state).warnings if "pins sit on bodies" in w]
    assert "lift_cyl: its pins sit on bodies of 60 kg" in warning and "omega*dt = 2.12 > 1.41" in warning
    advised = float(warning.split("use dt <= ")[1].split(" s")[0])
    assert advised == pytest.approx(6.67e-4, rel=1e-2)
    start = plant.net_state.node_pressure[plant.network.cylinder_cap_node[0]]
    low, high = cap_pressure_range(plant, 500)
    assert high > 10 * start  # the local mode blows up
    stable = plant_for(HOLD, qpos={"arm_hinge": -0.2}, dt=6e-4)
    low, high = cap_pressure_range(stable, 400)  # the pins' settling: a few % at first, decaying
    assert 0.95 * start < low and high < 1.05 * start
    low, high = cap_pressure_range(stable, 400)
    assert 0.995 * start < low and high < 1.005 * start
    assert not [w for w in guards.check(stable.scene, stable.net_state).warnings if "pins sit on bodies" in w]


FLAP_JOINT = '<joint name="flap_hinge" type="hinge" axis="0 -1 0" limited="true" range="{}"/>'
FLAP = '<body name="flap" pos="1.5 0 0">{}<inertial pos="0.2 0 0" mass="50" diaginertia="0.5 0.5 0.5"/></body>'


def flap_plant(folder, joint_range, mode="mujoco"):
    """loop_arm_links with a 50 kg flap on the arm, hinged at 1.5 m, at qpos0 = 0 (``joint_range`` None: welded)."""
    import shutil

    folder.mkdir()
    for name in ("hold_links.scenario.toml", "loop.circuit.toml"):
        shutil.copy(SCENES / name, folder / name)
    flap = FLAP.format(FLAP_JOINT.format(joint_range) if joint_range else "")
    xml = (SCENES / "loop_arm_links.xml").read_text().replace('<body name="payload"', flap + '\n      <body name="payload"')
    (folder / "loop_arm_links.xml").write_text(xml)
    scene = load_scene(load_scenario(folder / "hold_links.scenario.toml").with_overrides(mode=mode))
    return MujocoPlant(scene) if mode == "mujoco" else make_pbd_plant(scene, block=False)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_a_flap_resting_on_its_stop_is_held_by_the_stop(tmp_path, mode):
    """The flap's weight on its lower stop: the stop carries its torque about the flap hinge, the cylinder the rest,
    exactly as if the flap were welded to the arm; a flap that would hang from its upper stop cannot be held."""
    from sim.run.guards import check_plant

    welded = flap_plant(tmp_path / "welded", None, mode)
    resting = flap_plant(tmp_path / "resting", "0 1", mode)
    assert resting.holding_residual < 1e-9
    assert resting.effort[0] == pytest.approx(welded.effort[0], rel=1e-9)
    assert resting.effort[0] > virtual_work_force(0.1) + 100.0  # the flap's 50 kg is on the cylinder too
    hanging = flap_plant(tmp_path / "hanging", "-1 0", mode)
    assert hanging.holding_residual > 1e-3
    assert any("initial.equilibrium" in w for w in check_plant(hanging).warnings)


HOLD_CONTACT = SCENES / "hold_contact.scenario.toml"


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_start_pose_mesh_contacts_are_left_out_of_the_equilibrium_and_named(mode):
    """A mesh stop on the arm overlaps a post by 2.7 mm at the start pose: by default the equilibrium is hand statics
    (the virtual-work force within 1 %), and the warning names the contact and its load."""
    plant = plant_for(HOLD_CONTACT, mode)
    assert plant.effort[0] == pytest.approx(virtual_work_force(0.1), rel=1e-2)
    (warning,) = [w for w in guards.check_plant(plant).warnings if w.startswith("start pose:")]
    assert "1 contact(s) touch (rest-stop" in warning or "2 contact(s) touch (rest-stop" in warning
    assert "leave them out" in warning


def test_start_pose_contacts_counted_on_request_carry_their_share():
    """``[initial] start_contacts = "include"``: the contact's penetration force props the arm, and the cylinder holds
    the rest: the efforts differ from hand statics by the contact's load times its lever."""
    included = plant_for(HOLD_CONTACT, start_contacts="include")
    (warning,) = [w for w in guards.check_plant(included).warnings if w.startswith("start pose:")]
    assert "counts them" in warning
    total = float(warning.split("; ")[1].split(" kN in all")[0]) * 1e3
    assert total > 100.0
    assert included.effort[0] < virtual_work_force(0.1) - 0.05 * total


def test_check_names_the_start_contacts():
    from sim.tools.check import check_scene

    text, _ = check_scene(HOLD_CONTACT)
    assert "warning: start pose:" in text and "rest-stop" in text
