"""Pictures of the live views for the documentation, from a real excavator log.

- ``viewer-overlay.png``: the frame :class:`sim.live.viewer.ViewerOverlay` shows, rendered
  offscreen with ``mujoco.Renderer`` (needs ``MUJOCO_GL=egl`` or ``osmesa``) at the log's last
  sample, its cylinders coloured by cap pressure; the overlay text (the same lines the viewer
  writes, :func:`sim.live.viewer.overlay_lines`) and the strip chart of cap pressures (from the
  logged samples) are drawn over it with matplotlib, since the renderer has no public text or
  figure call.  The frame budget line is the run's average: physics
  time per 60 Hz frame = (1/60 s) / real-time factor of the run that made the log.
- ``scene-cylinders.png``: the 3D scene of the shipped layout at the same time, drawn with
  matplotlib from the log's own messages: the body primitives of ``/hydroplant/scene`` placed
  by ``/tf``, and the cylinders of ``/hydroplant/scene/cylinders``.  It is what Foxglove's 3D
  panel draws from these messages, not a screenshot of Foxglove.

Usage::

    MUJOCO_GL=egl python -m sim.live.figures docs/figures          # runs the dig to 4.5 s first
"""

from __future__ import annotations

import json
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sim.io.foxglove_scene import CYLINDER_TOPIC, CylinderPins
from sim.io.log_schemas import cdr_decode, ros2msg_type
from sim.io.mcap_log import read_log
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.live.protocol import FrameStats
from sim.live.viewer import overlay_lines, render_overlay

FRAME_PERIOD = 1.0 / 60.0  # s: the frame the budget line is quoted against
DIG_TIME = 4.5  # s: mid-dig (stick in, bucket curling, teeth in the ground)
CLIP = 14.0  # m: a scene cube wider than this is the ground plane


def _messages(path: Path, topics: Sequence[str]) -> dict[str, list[tuple[int, object]]]:
    """Decoded messages of ``topics``: JSON as dicts, CDR with the log's own schema text."""
    from mcap.reader import make_reader

    out: dict[str, list] = {t: [] for t in topics}
    types = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=list(topics), log_time_order=True):
            if channel.message_encoding == "json":
                body = json.loads(message.data)
            else:
                t = types.get(schema.id) or types.setdefault(schema.id, ros2msg_type(schema.name, schema.data.decode()))
                body = cdr_decode(t, message.data)
            out[channel.topic].append((message.log_time, body))
    return out


def _at(messages: list[tuple[int, object]], log_time: int):
    """The last message at or before ``log_time``."""
    times = [t for t, _ in messages]
    return messages[max(0, int(np.searchsorted(times, log_time, side="right")) - 1)][1]


def _matrix(q: dict) -> np.ndarray:
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _vec(v: dict) -> np.ndarray:
    return np.array([v["x"], v["y"], v["z"]], dtype=float)


def _faces(kind: str, size: np.ndarray, segments: int = 18) -> list[np.ndarray]:
    """Polygons of a unit primitive scaled to ``size`` (full extents), in its own frame."""
    if kind == "cube":
        h = 0.5 * size
        c = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
        quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
        return [c[list(q)] for q in quads]
    a = np.linspace(0, 2 * np.pi, segments + 1)
    if kind == "cylinder":
        rx, ry, hz = 0.5 * size[0], 0.5 * size[1], 0.5 * size[2]
        ring = np.stack([rx * np.cos(a), ry * np.sin(a)], axis=1)
        faces = [np.array([[*ring[i], -hz], [*ring[i + 1], -hz], [*ring[i + 1], hz], [*ring[i], hz]])
                 for i in range(segments)]
        faces += [np.column_stack([ring, np.full(len(ring), z)]) for z in (-hz, hz)]
        return faces
    # sphere / ellipsoid
    b = np.linspace(0, np.pi, segments // 2 + 1)
    r = 0.5 * size
    p = np.stack([np.outer(np.cos(a), np.sin(b)) * r[0], np.outer(np.sin(a), np.sin(b)) * r[1],
                  np.outer(np.ones_like(a), np.cos(b)) * r[2]], axis=-1)
    return [np.array([p[i, j], p[i + 1, j], p[i + 1, j + 1], p[i, j + 1]])
            for i in range(len(a) - 1) for j in range(len(b) - 1)]


def _ground(entity: dict, frame_origin: np.ndarray, clip: float, low: np.ndarray, high: np.ndarray):
    """The top faces of ``entity``'s cubes wider than ``clip`` (a plane), as one rectangle over the plotted area."""
    out = []
    for item in entity.get("cubes", []):
        size = _vec(item["size"])
        if size[0] > clip:
            z = frame_origin[2] + item["pose"]["position"]["z"] + 0.5 * size[2]
            color = item["color"]
            out.append((np.array([[low[0], low[1], z], [high[0], low[1], z], [high[0], high[1], z], [low[0], high[1], z]]),
                        (color["r"], color["g"], color["b"], 0.6)))
    return out


def _entity_polygons(entity: dict, frame_rotation: np.ndarray, frame_origin: np.ndarray, clip: float):
    polygons, colors = [], []
    for key, kind in (("cubes", "cube"), ("spheres", "sphere"), ("cylinders", "cylinder")):
        for item in entity.get(key, []):
            size = _vec(item["size"])
            if kind == "cube" and size[0] > clip:  # the ground plane: drawn separately, under everything
                continue
            r = frame_rotation @ _matrix(item["pose"]["orientation"])
            o = frame_origin + frame_rotation @ _vec(item["pose"]["position"])
            color = item["color"]
            for face in _faces(kind, size):
                polygons.append(face @ r.T + o)
                colors.append((color["r"], color["g"], color["b"], color["a"]))
    return polygons, colors


def scene_figure(log_path: Path, png: Path, log_time: int) -> Path:
    """Draw the 3D scene of ``log_path`` at ``log_time`` [ns] (see the module docstring) into ``png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    found = _messages(log_path, ["/hydroplant/scene", "/tf", CYLINDER_TOPIC])
    scene, tf, cylinders = (_at(found[t], log_time) for t in ("/hydroplant/scene", "/tf", CYLINDER_TOPIC))
    frames = {"world": (np.eye(3), np.zeros(3))}
    for transform in tf["transforms"]:
        frames[transform["child_frame_id"]] = (_matrix(transform["rotation"]), _vec(transform["translation"]))
    low, high = np.array([-3.5, -4.5, 0.0]), np.array([11.0, 4.5, 5.5])
    polygons, colors, ground = [], [], []
    for entity in scene["entities"]:
        rotation, origin = frames[entity["frame_id"]]
        p, c = _entity_polygons(entity, rotation, origin, CLIP)
        polygons += p
        colors += c
        ground += _ground(entity, origin, CLIP, low, high)
    for entity in cylinders["entities"]:  # world-frame entities, drawn as logged
        p, c = _entity_polygons(entity, np.eye(3), np.zeros(3), np.inf)
        polygons += p
        colors += [(r, g, b, 1.0) for r, g, b, _ in c]
    fig = plt.figure(figsize=(10, 6.2), dpi=110)
    ax = fig.add_subplot(projection="3d", computed_zorder=False)  # collections in order: the ground first
    if ground:
        ax.add_collection3d(Poly3DCollection([g for g, _ in ground], facecolors=[c for _, c in ground]))
    ax.add_collection3d(Poly3DCollection(polygons, facecolors=colors, edgecolors=(0, 0, 0, 0.08), linewidths=0.2))
    ax.set_xlim(low[0], high[0]), ax.set_ylim(low[1], high[1]), ax.set_zlim(low[2], high[2])
    ax.set_box_aspect(high - low)
    ax.view_init(elev=16, azim=-58)
    ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]"), ax.set_zlabel("z [m]")
    t = log_time * 1e-9
    ax.set_title(f"/hydroplant/scene on /tf with {CYLINDER_TOPIC} at t = {t:.2f} s "
                 "(barrel grey → red with cap pressure, 0 → 350 bar)", fontsize=9)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.02, top=0.95)
    fig.savefig(png)
    plt.close(fig)
    return png


def viewer_figure(log_path: Path, png: Path, log_time: int, real_time_factor: float, scenario_path: Path) -> Path:
    """The viewer overlay at ``log_time`` [ns] of ``log_path`` (see the module docstring) into ``png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco

    scene = load_scene(load_scenario(scenario_path))
    model, pins = scene.mjmodel, CylinderPins.of_scene(scene)
    net = scene.network
    log = read_log(log_path)
    joints = log.topic("/hydroplant/joint_states")
    row = int(np.flatnonzero(joints.log_time <= log_time)[-1])
    qpos = model.qpos0.copy()
    for name in scene.joint_names:
        qpos[model.jnt_qposadr[model.joint(name).id]] = joints[f"position/{name}"][row]
    values = {}
    for name in pins.names:
        topic = log.topic(f"/hydroplant/cylinders/{name}")
        values[f"{name}/p_cap_bar"] = float(topic["p_cap_bar"][row])
        values[f"{name}/p_rod_bar"] = float(topic["p_rod_bar"][row])
    for name in net.valve_names:
        values[f"{name}/command"] = float(log.topic(f"/hydroplant/valves/{name}")["command"][row])
    physics = FRAME_PERIOD / real_time_factor
    stats = FrameStats(int(round(log_time * 1e-9 / FRAME_PERIOD)), log_time * 1e-9, physics, FRAME_PERIOD, 0.0, False)
    camera = mujoco.MjvCamera()
    camera.lookat[:] = (5.0, 0.0, 1.6)
    camera.distance, camera.azimuth, camera.elevation = 13.5, -118.0, -14.0
    image = render_overlay(model, qpos, pins, np.array([values[f"{n}/p_cap_bar"] * 1e5 for n in pins.names]),
                           size=(720, 1280), camera=camera)
    fig = plt.figure(figsize=(12.8, 7.2), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(image)
    ax.axis("off")
    lines = overlay_lines(log_time * 1e-9, values, stats)
    width = max(len(label) for label, _ in lines)
    text = "\n".join(f"{label:<{width}}  {value}" for label, value in lines)
    ax.text(0.012, 0.975, text, transform=ax.transAxes, va="top", ha="left", family="monospace", fontsize=11,
            color="white", bbox={"facecolor": (0.1, 0.1, 0.1, 0.55), "edgecolor": "none", "pad": 6})
    # the viewer's strip chart (PressureChart: cap pressures of the last 600 frames), from the logged samples
    chart = fig.add_axes((0.69, 0.06, 0.29, 0.27), facecolor=(0.1, 0.1, 0.1, 0.6))
    shown = (joints.log_time <= log_time) & (joints.log_time >= log_time - round(600 * FRAME_PERIOD * 1e9))
    for name in pins.names:
        chart.plot(joints.log_time[shown] * 1e-9, log.topic(f"/hydroplant/cylinders/{name}")["p_cap_bar"][shown],
                   label=name, linewidth=1.2)
    chart.set_title("cap pressure [bar]", color="white", fontsize=9)
    chart.set_xlabel("time [s]", color="white", fontsize=8)
    chart.tick_params(colors="white", labelsize=8)
    chart.legend(fontsize=7, loc="upper left", framealpha=0.3)
    fig.savefig(png)
    plt.close(fig)
    return png


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m sim.live.figures OUT_DIR``: run the excavator dig to :data:`DIG_TIME` and draw both pictures."""
    from sim.io.examples import example_path
    from sim.run.runner import run

    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print("usage: python -m sim.live.figures OUT_DIR", file=sys.stderr)
        return 2
    out = Path(args[0])
    scenario = example_path("excavator/dig")
    with tempfile.TemporaryDirectory() as work:
        result = run(scenario, out=Path(work) / "dig.mcap", overrides={"duration": DIG_TIME})
        log_time = round(DIG_TIME * 1e9)
        print(viewer_figure(result.log_path, out / "viewer-overlay.png", log_time, result.real_time_factor, scenario))
        print(scene_figure(result.log_path, out / "scene-cylinders.png", log_time))
        print(f"real-time factor of the run: {result.real_time_factor:.1f}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())


__all__ = ["main", "scene_figure", "viewer_figure"]
