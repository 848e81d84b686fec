"""The viewer overlay as a frame sink, without a window: a stand-in for ``launch_passive``'s handle receives the
cylinder geoms (on MuJoCo's pins), the overlay text (pressures in bar, valve commands, frame budget) and the syncs."""

from __future__ import annotations

import contextlib

import mujoco
import numpy as np
import pytest

from conftest import MODELS
from sim.io.foxglove_scene import BARREL_RED, CylinderPins
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.live.devices import KeyboardSource
from sim.live.protocol import FrameSink, FrameStats
from sim.live.values import display_values
from sim.live.viewer import ViewerOverlay, overlay_lines
from sim.plants.mujoco import MujocoPlant


class Handle:
    """What ViewerOverlay uses of mujoco.viewer's Handle, recorded."""

    def __init__(self, model):
        self.user_scn = mujoco.MjvScene(model, 100)
        self.opt = mujoco.MjvOption()
        self.texts, self.syncs, self.running, self.closed, self.figures = None, 0, True, False, None
        self.viewport = mujoco.MjrRect(0, 0, 1200, 900)

    def set_figures(self, figures):
        self.figures = figures

    def lock(self):
        return contextlib.nullcontext()

    def set_texts(self, texts):
        self.texts = texts

    def sync(self, state_only=False):
        self.syncs += 1

    def is_running(self):
        return self.running

    def close(self):
        self.closed = True


@pytest.fixture(scope="module")
def excavator():
    scene = load_scene(load_scenario(MODELS / "excavator" / "dig.scenario.toml"))
    return scene, CylinderPins.of_scene(scene)


def test_viewer_overlay_draws_cylinders_on_the_pins_and_the_hydraulic_state(excavator):
    scene, pins = excavator
    model = scene.mjmodel
    handles, keys = [], KeyboardSource()

    def launch(m, d, *, key_callback, show_left_ui, show_right_ui):
        assert key_callback == keys.key and not (show_left_ui or show_right_ui)
        handles.append(Handle(m))
        return handles[-1]

    viewer = ViewerOverlay(model, pins, key_callback=keys.key, launch=launch)
    assert isinstance(viewer, FrameSink)
    handle = handles[0]
    assert handle.opt.flags[mujoco.mjtVisFlag.mjVIS_TENDON] == 0  # the cylinders replace the tendon lines
    qpos = np.zeros(model.nq)
    qpos[[model.jnt_qposadr[model.joint(n).id] for n in ("boom", "stick", "bucket")]] = (0.4, -0.7, 0.5)
    values = {"boom_cyl/p_cap_bar": 500.0, "boom_cyl/p_rod_bar": 12.5, "stick_cyl/p_cap_bar": 1.0,
              "stick_cyl/p_rod_bar": 80.0, "bucket_cyl/p_cap_bar": 1.0, "bucket_cyl/p_rod_bar": 1.0,
              "boom_valve/command": 0.4, "stick_valve/command": -1.0}
    stats = FrameStats(7, 2.5, 0.004, 1 / 60, 0.0005, True)
    viewer.show(2.5, qpos, values, stats)

    # geoms: barrel from the cap pin and rod to the rod eye, at MuJoCo's site positions for this qpos
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    geoms = handle.user_scn.geoms
    assert handle.user_scn.ngeom == 2 * len(pins.names) == 6
    for i in range(3):
        barrel, rod = geoms[2 * i], geoms[2 * i + 1]
        axis_b, axis_r = barrel.mat.reshape(3, 3)[:, 2], rod.mat.reshape(3, 3)[:, 2]
        np.testing.assert_allclose(barrel.pos - barrel.size[2] * axis_b, data.site_xpos[pins.cap_site[i]], atol=1e-6)
        np.testing.assert_allclose(rod.pos + rod.size[2] * axis_r, data.site_xpos[pins.rod_site[i]], atol=1e-6)
        np.testing.assert_allclose(2 * barrel.size[2], pins.barrel_length[i], rtol=1e-6)
    np.testing.assert_allclose(geoms[0].rgba[:3], BARREL_RED, atol=1e-6)  # 500 bar: beyond full scale
    assert viewer.data is not None and handle.syncs == 1

    # text: one top-left block; pressures in bar, valve commands, the frame budget and the missed frame
    (_, _, labels, texts), = handle.texts
    lines = dict(zip(labels.split("\n"), texts.split("\n")))
    assert lines["boom_cyl cap / rod"] == " 500.0 /   12.5 bar"
    assert lines["boom_valve"] == "+0.40" and lines["stick_valve"] == "-1.00"
    assert lines["physics / frame"] == "  4.0 /  16.7 ms ( 24 %)" and lines["late, missed"] == "  0.5 ms, 1"

    # the strip chart of cap pressures, bottom right: one line per cylinder, one point per frame so far
    viewer.show(2.6, qpos, {**values, "boom_cyl/p_cap_bar": 250.0}, stats)
    rect, figure = handle.figures
    assert (rect.left, rect.bottom, rect.width, rect.height) == (800, 0, 400, 300)
    assert list(figure.linepnt[:3]) == [2, 2, 2] and figure.linename[0] == b"boom_cyl"
    np.testing.assert_allclose(figure.linedata[0, :4], [2.5, 500.0, 2.6, 250.0])
    assert handle.syncs == 2

    handle.running = False  # the operator closed the window: nothing more is drawn
    viewer.show(2.7, qpos, values, stats)
    assert handle.syncs == 2 and not viewer.running
    viewer.close()
    assert handle.closed


def test_display_values_read_the_plant_in_bar():
    scenario = load_scenario(MODELS / "boom" / "lift.scenario.toml")
    plant = MujocoPlant(load_scene(scenario))
    values = display_values(plant)
    net, p = plant.network, plant.net_state.node_pressure
    assert values["boom_cyl/p_cap_bar"] == p[net.cylinder_cap_node[0]] / 1e5 > 1.0
    assert values["boom_valve/command"] == 0.0
    assert [line[0] for line in overlay_lines(0.0, values, None)] == ["time", "boom_cyl cap / rod", "boom_valve"]
