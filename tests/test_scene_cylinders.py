"""The hydraulic cylinders in the logged 3D scene: barrel and rod between the pins MuJoCo computes, at every scene
sample, decoded from the log by Foxglove's own CDR decoder (mcap-ros2-support)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from conftest import MODELS
from sim.io.foxglove_scene import (BARREL_GREY, BARREL_RED, CYLINDER_TOPIC, PRESSURE_FULL_SCALE, SCENE_UPDATE,
                                   CylinderPins, cylinder_primitives)
from sim.io.mcap_log import read_log, ros2msg_type
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.run.runner import run

DIG = MODELS / "excavator" / "dig.scenario.toml"


def excavator_pins():
    scene = load_scene(load_scenario(DIG))
    return scene, CylinderPins.of_scene(scene)


def ends(center, quat_xyzw, length):
    """The two end points of a Foxglove cylinder primitive (axis = its local z)."""
    x, y, z, w = quat_xyzw
    axis = np.zeros(3)
    mujoco.mju_rotVecQuat(axis, np.array([0.0, 0.0, 1.0]), np.array([w, x, y, z]))
    return np.asarray(center) - 0.5 * length * axis, np.asarray(center) + 0.5 * length * axis


def test_pins_and_primitive_ends_are_mujocos_sites_at_any_pose():
    scene, pins = excavator_pins()
    m = scene.mjmodel
    d = mujoco.MjData(m)
    assert pins.names == ("boom_cyl", "stick_cyl", "bucket_cyl")
    assert [m.site(i).name for i in pins.cap_site] == ["boom_cyl_barrel", "stick_cyl_barrel", "bucket_cyl_barrel"]
    rng = np.random.default_rng(7)
    for _ in range(5):
        d.qpos[:] = rng.uniform(-1.0, 1.0, m.nq)
        mujoco.mj_kinematics(m, d)
        cap, rod = pins.world(d.xpos, d.xquat)
        np.testing.assert_allclose(cap, d.site_xpos[pins.cap_site], atol=1e-12)
        np.testing.assert_allclose(rod, d.site_xpos[pins.rod_site], atol=1e-12)
        rows = cylinder_primitives(pins, cap, rod, np.full(3, 1e5))
        for i in range(3):
            barrel_start, barrel_end = ends(rows[i, 0:3], rows[i, 3:7], pins.barrel_length[i])
            rod_start, rod_end = ends(rows[i, 10:13], rows[i, 13:17], pins.rod_length[i])
            np.testing.assert_allclose(barrel_start, cap[i], atol=1e-12)
            np.testing.assert_allclose(rod_end, rod[i], atol=1e-12)
            # both on the pin-to-pin line, the rod's inner end inside the barrel or between the pins
            u = (rod[i] - cap[i]) / np.linalg.norm(rod[i] - cap[i])
            np.testing.assert_allclose(np.cross(rod_start - cap[i], u), 0.0, atol=1e-12)
            assert np.dot(rod_start - cap[i], u) > 0 and np.dot(barrel_end - cap[i], u) > 0


def test_orientation_straight_down_and_colour_scale():
    _, pins = excavator_pins()
    cap = np.zeros((3, 3))
    rod = np.array([[0.0, 0.0, -2.0], [0.0, 0.0, 2.0], [2.0, 0.0, 0.0]])  # −z (the half-way form's singular case), +z, x
    rows = cylinder_primitives(pins, cap, rod, np.array([1e5, 1e5 + PRESSURE_FULL_SCALE / 2, 1e9]))
    for i in range(3):
        np.testing.assert_allclose(ends(rows[i, 10:13], rows[i, 13:17], pins.rod_length[i])[1], rod[i], atol=1e-12)
    np.testing.assert_allclose(rows[0, 7:10], BARREL_GREY)
    np.testing.assert_allclose(rows[1, 7:10], (BARREL_GREY + BARREL_RED) / 2)
    np.testing.assert_allclose(rows[2, 7:10], BARREL_RED)


@pytest.mark.parametrize("tf_rate_hz", [100.0, 50.0])  # /tf on every sample; on every other one
def test_logged_cylinders_sit_on_mujocos_pins_at_every_scene_sample(tmp_path, tf_rate_hz):
    result = run(DIG, out=tmp_path / "dig.mcap", overrides={"duration": 0.3, "tf_rate_hz": tf_rate_hz})
    scene, pins = excavator_pins()
    m = scene.mjmodel
    d = mujoco.MjData(m)
    log = read_log(result.log_path)
    joints = log.topic("/hydroplant/joint_states")
    qpos_columns = {name: m.jnt_qposadr[m.joint(name).id] for name in scene.joint_names}
    cylinders = {name: log.topic(f"/hydroplant/cylinders/{name}") for name in pins.names}
    decoders = DecoderFactory()
    count = 0
    with open(result.log_path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=[CYLINDER_TOPIC]):
            assert (schema.name, channel.message_encoding) == (SCENE_UPDATE.name, "cdr")
            assert ros2msg_type(schema.name, schema.data.decode()) == SCENE_UPDATE
            update = decoders.decoder_for("cdr", schema)(message.data)
            row = int(np.flatnonzero(joints.log_time == message.log_time)[0])
            for name in scene.joint_names:
                d.qpos[qpos_columns[name]] = joints[f"position/{name}"][row]
            mujoco.mj_kinematics(m, d)
            (entity,) = update.entities
            assert entity.id == "cylinders" and entity.frame_id == "world"
            assert entity.timestamp.sec * 10**9 + entity.timestamp.nanosec == message.log_time
            assert len(entity.cylinders) == 2 * len(pins.names)
            for i in range(len(pins.names)):
                barrel, rod = entity.cylinders[2 * i:2 * i + 2]
                p = barrel.pose.position, barrel.pose.orientation
                start, _ = ends((p[0].x, p[0].y, p[0].z), (p[1].x, p[1].y, p[1].z, p[1].w), barrel.size.z)
                p = rod.pose.position, rod.pose.orientation
                _, end = ends((p[0].x, p[0].y, p[0].z), (p[1].x, p[1].y, p[1].z, p[1].w), rod.size.z)
                np.testing.assert_allclose(start, d.site_xpos[pins.cap_site[i]], atol=1e-9)
                np.testing.assert_allclose(end, d.site_xpos[pins.rod_site[i]], atol=1e-9)
                assert (barrel.size.z, rod.size.x) == (pins.barrel_length[i], pins.rod_diameter[i])
                # the barrel's colour is its cap pressure at that sample
                p_cap = cylinders[pins.names[i]]["p_cap_pa"][row]
                level = np.clip((p_cap - 1e5) / PRESSURE_FULL_SCALE, 0, 1)
                assert barrel.color.r == pytest.approx(BARREL_GREY[0] + level * (BARREL_RED[0] - BARREL_GREY[0]))
            count += 1
    assert count == len(log.topic("/tf")) == round(0.3 * tf_rate_hz) + 1  # at the /tf samples
    # the bar fields are the pascal fields in bar
    boom = cylinders["boom_cyl"]
    np.testing.assert_array_equal(boom["p_cap_bar"], boom["p_cap_pa"] / 1e5)
