"""Tests of sim.io.foxglove_scene: scene geometry and per-step body transforms."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader

from sim.io.foxglove_scene import FrameTransformsChannel, body_frame_ids, log_scene, scene_update_message
from sim.io.mcap_log import LogWriter, read_log

MJCF = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 1" rgba="0.2 0.3 0.4 1"/>
    <body name="base" pos="0 0 1">
      <freejoint/>
      <geom type="box" size="0.1 0.2 0.3" pos="0.05 0 0" rgba="1 0 0 1"/>
      <body name="arm" pos="0 0 0.3">
        <joint type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.5 0 0.2" size="0.04" rgba="0 1 0 0.5"/>
      </body>
    </body>
    <body pos="1 1 0.5">
      <freejoint/>
      <geom type="sphere" size="0.07" pos="0 0 0.01"/>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture()
def model():
    return mujoco.MjModel.from_xml_string(MJCF)


def _reject(constant):
    raise ValueError(constant)


def test_scene_entities_and_sizes(model):
    message = scene_update_message(model)
    json.loads(json.dumps(message, allow_nan=False), parse_constant=_reject)
    entities = message["entities"]
    assert [e["frame_id"] for e in entities] == ["world", "base", "arm", "body3"] == body_frame_ids(model)
    assert all(e["frame_locked"] is True and e["lifetime"] == {"sec": 0, "nsec": 0} for e in entities)
    assert all(e["id"] == e["frame_id"] for e in entities)

    world, base, arm, ball = entities
    assert len(world["cubes"]) == 1 and world["cubes"][0]["size"]["z"] == pytest.approx(1e-3)
    assert world["cubes"][0]["color"] == {"r": pytest.approx(0.2), "g": pytest.approx(0.3),
                                          "b": pytest.approx(0.4), "a": 1.0}

    (cube,) = base["cubes"]
    assert [cube["size"][k] for k in "xyz"] == pytest.approx([0.2, 0.4, 0.6])
    assert [cube["pose"]["position"][k] for k in "xyz"] == pytest.approx([0.05, 0.0, 0.0])
    assert cube["color"] == {"r": 1.0, "g": 0.0, "b": 0.0, "a": 1.0}

    capsule = int(np.flatnonzero(model.geom_bodyid == 2)[0])
    radius, half_length = model.geom_size[capsule][:2]
    (cylinder,) = arm["cylinders"]
    assert [cylinder["size"][k] for k in "xyz"] == [2 * radius, 2 * radius, 2 * half_length]
    quat = model.geom_quat[capsule]
    assert cylinder["pose"]["orientation"] == {"x": quat[1], "y": quat[2], "z": quat[3], "w": quat[0]}
    assert [cylinder["pose"]["position"][k] for k in "xyz"] == list(model.geom_pos[capsule])
    assert len(arm["spheres"]) == 2
    axis = np.array([0.5, 0.0, 0.2]) / np.linalg.norm([0.5, 0.0, 0.2])
    ends = sorted(tuple(s["pose"]["position"][k] for k in "xyz") for s in arm["spheres"])
    np.testing.assert_allclose(ends, [(0, 0, 0), (0.5, 0, 0.2)], atol=1e-12)
    assert half_length == pytest.approx(np.linalg.norm([0.5, 0.0, 0.2]) / 2)
    np.testing.assert_allclose(np.subtract(ends[1], ends[0]) / (2 * half_length), axis, atol=1e-12)
    assert all(s["size"]["x"] == 2 * radius for s in arm["spheres"])
    assert arm["cylinders"][0]["color"]["a"] == 0.5

    (sphere,) = ball["spheres"]
    assert [sphere["size"][k] for k in "xyz"] == pytest.approx([0.14] * 3)
    assert sphere["pose"]["position"]["z"] == pytest.approx(0.01)
    assert not ball["cubes"] and not ball["cylinders"]


def test_transforms_match_xpos_xquat(model, tmp_path):
    path = tmp_path / "scene.mcap"
    data = mujoco.MjData(model)
    data.qvel[:] = np.linspace(-1.0, 1.0, model.nv)
    steps = 60
    xpos_history = np.empty((steps, model.nbody, 3))
    xquat_history = np.empty((steps, model.nbody, 4))
    with LogWriter(path, dt=model.opt.timestep, batch_size=16) as log:
        log_scene(log, model)
        tf = FrameTransformsChannel(log, model)
        for step in range(steps):
            mujoco.mj_step(model, data)
            xpos_history[step] = data.xpos
            xquat_history[step] = data.xquat
            tf.append(step, data.xpos, data.xquat)

    with open(path, "rb") as stream:
        for _, channel, message in make_reader(stream, validate_crcs=True).iter_messages():
            if channel.message_encoding == "json":  # the scene; /tf is ROS 2 CDR
                json.loads(message.data, parse_constant=_reject)
    log = read_log(path)
    assert log.schema_names == {"/hydroplant/scene": "foxglove.SceneUpdate", "/tf": "foxglove_msgs/msg/FrameTransforms"}
    scene = log.topic("/hydroplant/scene").messages
    assert len(scene) == 1 and len(scene[0]["entities"]) == model.nbody

    transforms = log.topic("/tf")
    assert len(transforms) == steps
    assert tf.frame_ids == ["base", "arm", "body3"]
    for body, frame in enumerate(tf.frame_ids, start=1):
        for axis, name in enumerate("xyz"):
            np.testing.assert_array_equal(transforms[f"translation.{name}/{frame}"], xpos_history[:, body, axis])
        for index, name in enumerate("wxyz"):  # MuJoCo (w, x, y, z) -> Foxglove fields
            np.testing.assert_array_equal(transforms[f"rotation.{name}/{frame}"], xquat_history[:, body, index])
        assert set(transforms.text(f"parent_frame_id/{frame}")) == {"world"}
    first = transforms.messages[0]["transforms"][0]
    assert first["timestamp"] == {"sec": 0, "nanosec": 0}
    np.testing.assert_array_equal(transforms.log_time, [log_time for log_time in
                                                        (np.arange(steps) * round(model.opt.timestep * 1e9))])
