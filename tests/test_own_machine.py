"""Models built the way outside models are (tests/scenes/hlink.xml: free base welded to the world, a mesh
geom, an H-link bucket linkage, a cylinder on barrel and rod bodies, leftover velocity actuators): each is
simulated right or refused with one line naming the MJCF element, the same in both modes.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim.io.scenario import ScenarioError, load_scenario
from sim.io.scene import initial_qpos_qvel, load_scene
from sim.plants.constraints import held_dofs, project_pose
from sim.plants.mujoco import MujocoPlant
from sim.plants.pbd import fast_path, make_pbd_plant

SCENES = Path(__file__).parent / "scenes"
HLINK = SCENES / "hlink.scenario.toml"
MODELS = Path(__file__).parent.parent / "models"


def copy_scene(tmp_path, edit_xml) -> Path:
    """The H-link scene copied into ``tmp_path`` with its MJCF text passed through ``edit_xml``."""
    for name in ("hlink.circuit.toml", "hlink.scenario.toml", "cab.obj"):
        shutil.copy(SCENES / name, tmp_path / name)
    (tmp_path / "hlink.xml").write_text(edit_xml((SCENES / "hlink.xml").read_text()))
    return tmp_path / "hlink.scenario.toml"


FIXED = ('<fixed name="bucket_cyl" limited="true" range="0.9 1.3"><joint joint="rod_slide" coef="1"/>'
         '<joint joint="barrel_hinge" coef="0.1"/></fixed>')


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_a_fixed_tendon_summing_joints_is_refused_in_both_modes_naming_it(tmp_path, mode):
    path = copy_scene(tmp_path, lambda text: re.sub(r"<spatial name=\"bucket_cyl\".*?</spatial>", FIXED, text, flags=re.S))
    with pytest.raises(ScenarioError) as error:
        load_scene(load_scenario(path).with_overrides(mode=mode))
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(f"{tmp_path / 'hlink.xml'}: actuator 'bucket_cyl' (a cylinder) acts on <fixed> tendon 'bucket_cyl'")
    assert "must hold exactly one slide joint" in message


def test_undriven_actuators_are_named_and_exert_no_force():
    scene = load_scene(load_scenario(HLINK))
    assert any("actuator(s) 'bucket_vel', 'link1_vel' are not driven by" in w for w in scene.warnings)
    plant = MujocoPlant(scene)
    plant.data.qvel[:] = 0.0
    hinge = scene.mjmodel.joint("bucket_hinge").dofadr[0]
    plant.data.qvel[hinge] = 0.5  # a velocity actuator with kv = 1000 would push back with 500 N·m
    mujoco.mj_forward(scene.mjmodel, plant.data)
    for name in ("bucket_vel", "link1_vel"):
        assert plant.data.actuator_force[scene.mjmodel.actuator(name).id] == 0.0


def test_pbd_mode_names_the_free_base_and_the_mesh_and_its_path():
    scene = load_scene(load_scenario(HLINK).with_overrides(mode="pbd"))
    text = "\n".join(scene.warnings)
    assert "body 'base' has free joint 'base_free', held by weld 'base_weld': PBD mode then steps every body as free" in text
    assert "geom(s) 'cab' (mesh) can collide, but PBD mode's contacts are spheres, capsules and boxes" in text
    assert "joints 'base_free' are not hinges or slides" in fast_path(make_pbd_plant(scene))
    mujoco_scene = load_scene(load_scenario(HLINK))
    assert not any("PBD mode" in w for w in mujoco_scene.warnings)


def virtual_work_force(scene, theta, h=1e-5) -> float:
    """Cylinder force [N] holding the H-link at bucket angle θ: ΔV/ΔL between two poses projected onto the loops."""
    m = scene.mjmodel
    d = mujoco.MjData(m)
    values = []
    for t in (theta - h, theta + h):
        qpos, _ = initial_qpos_qvel(scene, project=False)
        qpos[m.joint("bucket_hinge").qposadr[0]] = t
        qpos, _, _ = project_pose(m, qpos, np.zeros(m.nv), held_dofs(m, ["bucket_hinge"]))
        d.qpos[:] = qpos
        mujoco.mj_forward(m, d)
        mujoco.mj_energyPos(m, d)
        values.append((float(d.energy[0]), float(d.ten_length[0])))
    (v0, l0), (v1, l1) = values
    return (v1 - v0) / (l1 - l0)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_the_hlink_holds_its_bucket_with_the_virtual_work_force(mode):
    scenario = load_scenario(HLINK).with_overrides(mode=mode)
    scene = load_scene(scenario)
    plant = MujocoPlant(scene) if mode == "mujoco" else make_pbd_plant(scene, block=False)
    assert plant.holding_residual < 1e-9
    m = scene.mjmodel
    m.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    assert plant.effort[0] == pytest.approx(virtual_work_force(scene, 0.0), rel=1e-2)
    if mode == "mujoco":
        q0 = plant.joint_state()[0].copy()
        for _ in range(200):
            plant.step()
        assert np.max(np.abs(plant.joint_state()[0] - q0)) < 1e-4  # no leakage: the pins' soft settling only


def test_a_circuit_copied_with_two_actuators_deleted_from_the_mjcf_prunes_their_valve_sections(tmp_path):
    for f in (MODELS / "excavator").iterdir():
        shutil.copy(f, tmp_path / f.name)
    xml = tmp_path / "excavator.xml"
    text = re.sub(r'\s*<general name="(bucket_cyl|swing_motor)"[^>]*/>', "", xml.read_text())
    xml.write_text(text)
    scene = load_scene(load_scenario(tmp_path / "dig.scenario.toml"))
    net = scene.network
    assert net.actuator_names == ("boom_cyl", "stick_cyl") and net.valve_names == ("boom_valve", "stick_valve")
    for name in ("bucket_valve", "bucket_hose_a", "bucket_cyl", "bucket_port_relief_cap", "swing_valve", "swing_motor", "swing_relief_ab"):
        assert name in net.pruned
    assert not {"pump", "main_relief", "boom_valve", "boom_cyl", "stick_valve"} & set(net.pruned)
    assert any("not built: bucket_valve" in w and "their inputs ['bucket_valve', 'swing_valve']" in w for w in scene.warnings)
    plant = MujocoPlant(scene)
    for _ in range(20):
        assert plant.step().success


@pytest.mark.parametrize("scenario,mode", [(SCENES / "hold.scenario.toml", "mujoco"), (SCENES / "hold.scenario.toml", "pbd"),
                                           (HLINK, "mujoco")])
def test_loop_closure_scenes_run_to_the_end_holding_still(scenario, mode, tmp_path):
    """The hold scenarios end complete with the cap pressure within 2 % of the equilibrium start's (the soft pins settle:
    0.5 % on loop_arm, 1.3 % on the H-link with its three equalities)."""
    from sim.run.runner import run

    result = run(scenario, out=tmp_path / "run.mcap", overrides={"mode": mode}, progress=False)
    assert result.status == "complete", result.message
    name = "lift_cyl" if scenario.name == "hold.scenario.toml" else "bucket_cyl"
    cap = f"{name}_cap"
    plant = MujocoPlant(load_scene(load_scenario(scenario)))
    start = plant.net_state.node_pressure[plant.network.node(cap)]
    assert result.peak_pressure[cap] <= 1.02 * start and result.min_pressure[cap] >= 0.98 * start


def test_equality_rows_are_the_same_from_sparse_and_dense_jacobians():
    """Large models make MuJoCo store its constraint Jacobian sparse; the loop-closure rows must not change."""
    from sim.plants.constraints import equality_rows

    rows = []
    for jacobian in (mujoco.mjtJacobian.mjJAC_DENSE, mujoco.mjtJacobian.mjJAC_SPARSE):
        m = mujoco.MjModel.from_xml_path(str(SCENES / "hlink.xml"))
        m.opt.jacobian = jacobian
        d = mujoco.MjData(m)
        d.qpos[m.joint("bucket_hinge").qposadr[0]] = 0.1
        mujoco.mj_forward(m, d)
        rows.append(equality_rows(m, d))
    (G1, r1, n1), (G2, r2, n2) = rows
    assert n1 == n2 == ("base_weld",) * 6 + ("hlink_pin",) * 3 + ("rod_eye",) * 3
    assert np.array_equal(G1, G2) and np.array_equal(r1, r2) and np.max(np.abs(r1)) > 1e-3
