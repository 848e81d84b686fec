"""Cylinders as outside models drive them: an actuator on the rod's slide joint (or a ``<fixed>`` tendon over it),
barrel and rod bodies, a ``connect`` closure at the rod eye and MuJoCo's default equality settings
(tests/scenes/outside_arm.xml), driven pin to pin on the links (:mod:`sim.io.cylinder_pins`).

* The closed cylinder holds the arm in both modes, with realistic (20 kg / 60 kg) and 0.5 kg barrel and rod bodies:
  the cap force is the virtual-work force F = (dV/dθ)/(dL/dθ) of the closed-form geometry within 1 %, the arm sags
  less than 1 mrad over 3 s, and the cap pressure is that of its twin with a spatial tendon between pins on the links.
* A joint transmission and a one-joint fixed tendon give the same compiled cylinder; the H-link's cylinder holds its
  bucket with the virtual-work force either way.
* What cannot be a pin-to-pin line is refused in one line naming the MJCF element.
"""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim.io.scenario import ScenarioError, load_scenario
from sim.io.scene import load_scene
from sim.plants.mujoco import MujocoPlant
from sim.plants.pbd import make_pbd_plant

SCENES = Path(__file__).parent / "scenes"
G = 9.81
A_PIN = np.array([0.5, 0.2])  # barrel pin (x, z) [m]
L0 = 0.9433981132056605  # pin to pin at qpos0 [m]
THETA = 0.1  # the hold scenario's arm angle [rad]
MASSES = {"realistic": (20.0, 60.0), "light": (0.5, 0.5)}  # barrel, rod [kg]


def virtual_work_force(theta: float, barrel: float, rod: float) -> float:
    """Cylinder force [N] holding the arm at θ with barrel and rod masses [kg]: (dV/dθ)/(dL/dθ) of the geometry."""

    def geometry(t):
        b = np.array([math.cos(t), 1.0 + math.sin(t)])  # arm pin B (x, z)
        length = float(np.linalg.norm(b - A_PIN))
        u = (b - A_PIN) / length
        heights = (1.0 + math.sin(t), 1.0 + 2.0 * math.sin(t) - 0.1 * math.cos(t),  # arm 200 kg, payload 100 kg
                   A_PIN[1] + 0.3 * u[1], A_PIN[1] + (length - L0 + 0.7) * u[1])  # barrel COM 0.3 m, rod COM 0.7 m
        return G * sum(m * z for m, z in zip((200.0, 100.0, barrel, rod), heights)), length

    h = 1e-6
    (v1, l1), (v0, l0) = geometry(theta + h), geometry(theta - h)
    return (v1 - v0) / (l1 - l0)


def with_masses(text: str, barrel: float, rod: float) -> str:
    """MJCF text with the barrel's and rod's masses (inertias scaled with them)."""
    text = text.replace('mass="20" diaginertia="0.6 0.6 0.02"', f'mass="{barrel}" diaginertia="{0.03 * barrel} {0.03 * barrel} {0.001 * barrel}"')
    return text.replace('mass="60" diaginertia="2 2 0.03"', f'mass="{rod}" diaginertia="{rod / 30} {rod / 30} {rod / 2000}"')


def twin_text() -> str:
    """The same machine with a spatial tendon between pins on the links and MuJoCo's default equality settings."""
    text = (SCENES / "loop_arm_links.xml").read_text()
    return text.replace('    <equality solref="0.002 1" solimp="0.99 0.999 0.001"/>\n', "")


def scene_in(tmp_path, xml: str, mode: str):
    shutil.copy(SCENES / "loop.circuit.toml", tmp_path / "loop.circuit.toml")
    (tmp_path / "arm.xml").write_text(xml)
    scenario = (SCENES / "hold_outside.scenario.toml").read_text().replace('mjcf = "outside_arm.xml"', 'mjcf = "arm.xml"')
    (tmp_path / "hold.scenario.toml").write_text(scenario)
    return load_scene(load_scenario(tmp_path / "hold.scenario.toml").with_overrides(mode=mode))


def cap_force(net, state) -> float:
    """p_cap·A_cap − p_rod·A_rod − p_amb·(A_cap − A_rod) [N] of the one cylinder."""
    p = state.node_pressure
    a_cap, a_rod = net.cylinder_cap_area[0], net.cylinder_rod_area[0]
    return float(p[net.cylinder_cap_node[0]] * a_cap - p[net.cylinder_rod_node[0]] * a_rod
                 - net.fluid.reference_pressure * (a_cap - a_rod))


def hold(scene, mode, seconds=3.0):
    """(start cap force [N], largest |θ − θ₀| [rad], cap pressures [Pa]) of a hold with the valve closed."""
    plant = MujocoPlant(scene) if mode == "mujoco" else make_pbd_plant(scene, block=False)
    assert plant.holding_residual < 1e-9
    start = cap_force(plant.network, plant.net_state)
    cap = plant.network.cylinder_cap_node[0]
    angles, pressures = [], []
    for _ in range(round(seconds / scene.scenario.dt)):
        assert plant.step().success
        angles.append(plant.joint_state()[0][0])
        pressures.append(plant.net_state.node_pressure[cap])
    return start, float(np.max(np.abs(np.array(angles) - THETA))), np.array(pressures)


@pytest.mark.parametrize("masses", sorted(MASSES))
@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_a_joint_transmission_cylinder_holds_like_its_pin_to_pin_twin(tmp_path, mode, masses):
    barrel, rod = MASSES[masses]
    scene = scene_in(tmp_path, with_masses((SCENES / "outside_arm.xml").read_text(), barrel, rod), mode)
    assert any("cylinder 'lift_cyl' on slide 'rod_slide' is driven pin to pin" in n and "body 'arm' (connect 'rod_eye')" in n
               for n in scene.notes)
    force, sag, pressures = hold(scene, mode)
    assert force == pytest.approx(virtual_work_force(THETA, barrel, rod), rel=1e-2)
    assert sag < 1e-3
    twin_dir = tmp_path / "twin"
    twin_dir.mkdir()
    twin_force, twin_sag, twin_pressures = hold(scene_in(twin_dir, with_masses(twin_text(), barrel, rod), mode), mode)
    assert force == pytest.approx(twin_force, rel=1e-9)
    assert np.max(np.abs(pressures / twin_pressures - 1.0)) < 1e-3


def test_the_joint_and_the_fixed_tendon_give_the_same_pin_to_pin_cylinder(tmp_path):
    joint = scene_in(tmp_path, (SCENES / "outside_arm.xml").read_text(), "mujoco")
    fixed_text = (SCENES / "outside_arm.xml").read_text().replace(
        '<general name="lift_cyl" joint="rod_slide"', '<general name="lift_cyl" tendon="slide_t"').replace(
        "  <actuator>", '  <tendon><fixed name="slide_t"><joint joint="rod_slide" coef="-1"/></fixed></tendon>\n  <actuator>')
    (tmp_path / "fixed").mkdir()
    fixed = scene_in(tmp_path / "fixed", fixed_text, "mujoco")
    for scene in (joint, fixed):
        m = scene.mjmodel
        tid = scene.binding.tendon_id[0]
        np.testing.assert_allclose(m.tendon_range[tid], [0.75, 1.15], atol=1e-12)
        assert int(m.actuator_trntype[scene.binding.actuator_id[0]]) == int(mujoco.mjtTrn.mjTRN_TENDON)
    # the tendon runs between pins on the world and the arm, and its length is the pin-to-pin distance
    d = mujoco.MjData(joint.mjmodel)
    mujoco.mj_forward(joint.mjmodel, d)
    assert d.ten_length[joint.binding.tendon_id[0]] == pytest.approx(L0, abs=1e-12)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_the_hlink_driven_on_its_rod_slide_holds_with_the_virtual_work_force(tmp_path, mode):
    """The H-link scene's cylinder put on its rod's slide joint (the spatial tendon removed) holds its bucket with the
    virtual-work force and runs to the end holding still in both modes.  Its side link (10 kg, held by the H-link's
    own closure) is lighter than the rod body (40 kg) that the joint drove: the pins stay on the barrel and rod bodies
    (with them on the links the oil column rings the side link and MuJoCo mode diverges at 0.1 s)."""
    from sim.run.runner import run
    from test_own_machine import copy_scene, virtual_work_force as hlink_force

    def on_slide(text):
        text = re.sub(r'<general name="bucket_cyl" tendon="bucket_cyl"', '<general name="bucket_cyl" joint="rod_slide"', text)
        return re.sub(r"<tendon>.*?</tendon>", "", text, flags=re.S)

    path = copy_scene(tmp_path, on_slide)
    scene = load_scene(load_scenario(path).with_overrides(mode=mode))
    (note,) = scene.notes
    assert "from its barrel pin on body 'barrel'" in note and "to its rod eye on body 'rod'" in note
    plant = MujocoPlant(scene) if mode == "mujoco" else make_pbd_plant(scene, block=False)
    assert plant.holding_residual < 1e-9
    scene.mjmodel.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    assert plant.effort[0] == pytest.approx(hlink_force(scene, 0.0), rel=1e-2)
    start = plant.net_state.node_pressure[plant.network.node("bucket_cyl_cap")]
    result = run(path, out=tmp_path / "run.mcap", overrides={"mode": mode}, progress=False)
    assert result.status == "complete", result.message
    assert 0.97 * start <= result.min_pressure["bucket_cyl_cap"] <= result.peak_pressure["bucket_cyl_cap"] <= 1.03 * start


@pytest.mark.parametrize("edit,message", [
    (lambda t: t.replace('joint="rod_slide" gaintype', 'joint="barrel_hinge" gaintype'),
     r"actuator 'lift_cyl' \(a cylinder\) acts on joint 'barrel_hinge', which is not a slide"),
    (lambda t: t.replace('type="slide" axis="0 0 1" limited="true"', 'type="slide" axis="0 0 1" limited="false"'),
     r"joint 'rod_slide' \(the slide of cylinder 'lift_cyl'\): needs limited=\"true\" and a range"),
    (lambda t: t.replace('range="-0.1933981132056605 0.2066018867943395"', 'range="-0.2 0.3"'),
     r"joint 'rod_slide' \(the slide of cylinder 'lift_cyl'\) has range \[-0.2, 0.3\] \(width 0.5000 m\) but the circuit's stroke is 0.4 m"),
    (lambda t: t.replace('<body name="rod" pos="0 0 0">', '<body name="rod" pos="0.01 0 0">'),
     r"cylinder 'lift_cyl': its barrel pin \(hinge 'barrel_hinge'\) lies 10 mm off the axis of slide 'rod_slide'"),
])
def test_what_is_not_a_pin_to_pin_line_is_refused_in_one_line(tmp_path, edit, message):
    with pytest.raises(ScenarioError, match=message) as error:
        scene_in(tmp_path, edit((SCENES / "outside_arm.xml").read_text()), "mujoco")
    assert "\n" not in str(error.value) and str(error.value).startswith(str(tmp_path / "arm.xml"))


def soft_barrel_rod_text(barrel: float, rod: float) -> str:
    """loop_arm (a spatial tendon between sites on the barrel and rod bodies) with MuJoCo's default equality settings."""
    text = (SCENES / "loop_arm.xml").read_text().replace('    <equality solref="0.002 1" solimp="0.99 0.999 0.001"/>\n', "")
    return with_masses(text, barrel, rod)


@pytest.mark.parametrize("masses", sorted(MASSES))
def test_the_predicted_closure_gap_is_the_one_a_hold_opens_and_is_warned_with_the_settings_that_close_it(tmp_path, masses):
    """Pins on the barrel and rod bodies with MuJoCo's soft default equality: the predicted static gap of the rod eye is
    what 3 s of hold open (within 10 %: the arm sags meanwhile), the start is warned with the stiffer settings' gap,
    and the same machine driven on its rod's slide joint (pins on the links) is not warned."""
    from sim.plants.constraints import actuator_moments, closure_gaps
    from sim.run.guards import CLOSURE_GAP_WARN, check_plant
    from sim.io.scene import initial_qpos_qvel

    scene = scene_in(tmp_path, soft_barrel_rod_text(*MASSES[masses]), "mujoco")
    m = scene.mjmodel
    qpos, _ = initial_qpos_qvel(scene)
    (gap, force), = closure_gaps(m, qpos, lambda d: actuator_moments(m, d, scene.binding.actuator_id)).values()
    assert force == pytest.approx(4.8e3, rel=0.1)
    plant = MujocoPlant(scene)
    (warning,) = [w for w in check_plant(plant).warnings if w.startswith("equality 'rod_eye'")]
    assert f"opens {gap * 1e3:.3g} mm" in warning and 'solref="0.002 1" solimp="0.99 0.999 0.001"' in warning
    for _ in range(3000):
        plant.step()
    rows = np.flatnonzero(np.asarray(plant.data.efc_type[: plant.data.nefc]) == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY))
    assert gap > CLOSURE_GAP_WARN
    assert float(np.linalg.norm(plant.data.efc_pos[rows])) == pytest.approx(gap, rel=0.1)
    (tmp_path / "slide").mkdir()
    on_slide = scene_in(tmp_path / "slide", with_masses((SCENES / "outside_arm.xml").read_text(), *MASSES[masses]), "mujoco")
    assert not [w for w in check_plant(MujocoPlant(on_slide)).warnings if w.startswith("equality")]
