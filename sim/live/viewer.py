"""The MuJoCo viewer as a frame sink: the machine with its hydraulic state overlaid.

:class:`ViewerOverlay` wraps ``mujoco.viewer.launch_passive`` (a window on its own thread;
the paced loop stays in charge of time) and, per frame:

- sets its own ``MjData`` to the frame's ``qpos`` (the simulation's data is never touched),
- draws every hydraulic cylinder into the viewer's ``user_scn`` as two MuJoCo cylinders
  between its pins (:func:`add_cylinder_geoms`: barrel from the cap pin, grey to red with the
  cap pressure; rod from the rod eye), the same geometry as the logged 3D scene
  (:class:`sim.io.foxglove_scene.CylinderPins`); the model's own tendon lines are hidden,
- writes a text overlay (:func:`overlay_texts`): time, each cylinder's cap and rod pressure
  in bar, each valve's command, and the frame budget (physics time against the frame period,
  missed frames), and a strip chart of the cap pressures over the last 600 frames
  (:class:`PressureChart`, ``set_figures``),
- and syncs the window.

Nothing opens until a :class:`ViewerOverlay` is made; tests pass a ``launch`` that returns a
stand-in handle, so no window is needed.  :func:`render_overlay` draws the same frame offscreen
(``mujoco.Renderer``, e.g. ``MUJOCO_GL=egl``) for pictures.

Example
-------
::

    keys = KeyboardSource()
    viewer = ViewerOverlay(scene.mjmodel, CylinderPins.of_scene(scene), key_callback=keys.key)
    viewer.show(plant.time, plant.data.qpos, display_values(plant), stats)   # once per frame
    viewer.close()
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from sim.io.foxglove_scene import ROD_COLOR, CylinderPins, cylinder_primitives
from sim.live.frame_topic import budget_percent
from sim.live.protocol import FrameStats

PA_PER_BAR = 1e5
AMBIENT_PA = 1e5  # the pressure the barrel colour starts from [Pa]


def overlay_lines(t: float, values: Mapping[str, float], stats: FrameStats | None, missed: int = 0,
                  ) -> list[tuple[str, str]]:
    """The overlay as (label, value) lines: time; per cylinder ``p cap / rod`` in bar; per valve its command; the
    frame budget.  Names come from ``values`` (``<cylinder>/p_cap_bar``, ``<valve>/command``)."""
    lines = [("time", f"{t:7.2f} s")]
    cylinders = sorted({k.rsplit("/", 1)[0] for k in values if k.endswith("/p_cap_bar")})
    for name in cylinders:
        cap, rod = values.get(f"{name}/p_cap_bar", float("nan")), values.get(f"{name}/p_rod_bar", float("nan"))
        lines.append((f"{name} cap / rod", f"{cap:6.1f} / {rod:6.1f} bar"))
    for key in sorted(k for k in values if k.endswith("/command")):
        lines.append((key.rsplit("/", 1)[0], f"{values[key]:+.2f}"))
    if stats is not None:
        lines.append(("physics / frame", f"{1e3 * stats.physics:5.1f} / {1e3 * stats.cycle:5.1f} ms "
                                         f"({budget_percent(stats):3.0f} %)"))
        lines.append(("late, missed", f"{1e3 * stats.lateness:5.1f} ms, {missed}"))
    return lines


def overlay_texts(t: float, values: Mapping[str, float], stats: FrameStats | None, missed: int = 0) -> list[tuple]:
    """:func:`overlay_lines` as the ``set_texts`` argument of a viewer handle: one top-left block, labels left,
    values right."""
    lines = overlay_lines(t, values, stats, missed)
    return [(mujoco.mjtFontScale.mjFONTSCALE_150, mujoco.mjtGridPos.mjGRID_TOPLEFT,
             "\n".join(label for label, _ in lines), "\n".join(value for _, value in lines))]


def add_cylinder_geoms(scene: mujoco.MjvScene, pins: CylinderPins, data: mujoco.MjData,
                       cap_pressure: Sequence[float]) -> int:
    """Replace the geoms of ``scene`` (a viewer's ``user_scn`` or a renderer's scene, after its own geoms) by
    each cylinder's barrel and rod, from ``data``'s body poses (kinematics done) and cap pressures [Pa].

    Returns the number of geoms added (2 per cylinder, fewer when ``scene`` is full).
    Geometry and colour are :func:`sim.io.foxglove_scene.cylinder_primitives`'s: the barrel
    from the cap pin ``barrel_length`` towards the rod eye, the rod from the rod eye
    ``rod_length`` back.
    """
    cap, rod = pins.world(data.xpos, data.xquat)
    rows = cylinder_primitives(pins, cap, rod, np.asarray(cap_pressure, dtype=float), AMBIENT_PA)
    added = 0
    for i in range(len(pins.names)):
        u = rod[i] - cap[i]
        u = u / max(float(np.linalg.norm(u)), 1e-12)
        parts = ((cap[i], cap[i] + u * pins.barrel_length[i], 0.5 * pins.barrel_diameter[i], (*rows[i, 7:10], 1.0)),
                 (rod[i] - u * pins.rod_length[i], rod[i], 0.5 * pins.rod_diameter[i], ROD_COLOR))
        for start, end, radius, rgba in parts:
            if scene.ngeom >= scene.maxgeom:
                return added
            geom = scene.geoms[scene.ngeom]
            mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_CYLINDER, np.zeros(3), np.zeros(3), np.eye(3).ravel(),
                                np.asarray(rgba, dtype=np.float32))
            mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CYLINDER, float(radius), np.asarray(start, float),
                                 np.asarray(end, float))
            scene.ngeom += 1
            added += 1
    return added


class PressureChart:
    """A strip chart of every cylinder's cap pressure [bar] over the last ``frames`` frames, as a ``MjvFigure``
    for a viewer handle's ``set_figures`` (bottom-right quarter of the window)."""

    def __init__(self, names: Sequence[str], frames: int = 600):
        self.names = tuple(names)[:mujoco.mjMAXLINE]
        self.frames = max(2, min(int(frames), mujoco.mjMAXLINEPNT))
        self.time = np.full(self.frames, np.nan)
        self.history = np.full((len(self.names), self.frames), np.nan)
        self.count = 0
        self.figure = mujoco.MjvFigure()
        self.figure.title = "cap pressure [bar]"
        self.figure.xlabel = "time [s]"
        self.figure.flg_extend = 1
        for i, name in enumerate(self.names):
            self.figure.linename[i] = name

    def add(self, t: float, values: Mapping[str, float]) -> mujoco.MjvFigure:
        """Append the frame at ``t`` [s] (``<cylinder>/p_cap_bar`` of ``values``) and return the updated figure."""
        self.time = np.roll(self.time, -1)
        self.history = np.roll(self.history, -1, axis=1)
        self.time[-1] = t
        self.history[:, -1] = [values.get(f"{name}/p_cap_bar", np.nan) for name in self.names]
        self.count = min(self.count + 1, self.frames)
        n = self.count
        for i in range(len(self.names)):
            self.figure.linedata[i, 0:2 * n:2] = self.time[-n:]
            self.figure.linedata[i, 1:2 * n:2] = self.history[i, -n:]
            self.figure.linepnt[i] = n
        return self.figure


def cap_pressures(pins: CylinderPins, values: Mapping[str, float]) -> np.ndarray:
    """Cap pressures [Pa] of ``pins``'s cylinders from ``values``' ``<cylinder>/p_cap_bar`` (ambient when absent)."""
    return np.array([values.get(f"{name}/p_cap_bar", AMBIENT_PA / PA_PER_BAR) * PA_PER_BAR for name in pins.names])


class ViewerOverlay:
    """:class:`~sim.live.protocol.FrameSink` showing each frame in a MuJoCo passive viewer; see the module docstring.

    Parameters
    ----------
    model : mujoco.MjModel
        The scene's model (the viewer keeps its own ``MjData``).
    pins : CylinderPins or None, optional
        The cylinders to draw (None: none).
    key_callback : callable, optional
        Called with each key press in the window (e.g. :meth:`sim.live.devices.KeyboardSource.key`).
    show_ui : bool, optional
        Show the viewer's side panels.
    launch : callable, optional
        ``launch(model, data, key_callback=..., show_left_ui=..., show_right_ui=...)`` returning a
        viewer handle; ``mujoco.viewer.launch_passive`` by default.
    chart : bool, optional
        Show a strip chart of the cap pressures (:class:`PressureChart`) in the bottom-right corner.

    Attributes
    ----------
    missed : int
        Frames that missed their deadline so far.
    running : bool
        False once the window was closed (then :meth:`show` does nothing).
    """

    def __init__(self, model: mujoco.MjModel, pins: CylinderPins | None = None, *,
                 key_callback: Callable[[int], None] | None = None, show_ui: bool = False,
                 launch: Callable[..., Any] | None = None, chart: bool = True):
        if launch is None:
            from mujoco import viewer  # (a window: imported only when one is opened)

            launch = viewer.launch_passive
        self.model = model
        self.data = mujoco.MjData(model)
        self.pins = pins
        self.missed = 0
        self.running = True
        self.chart = PressureChart(pins.names) if pins is not None and chart else None
        self.handle = launch(model, self.data, key_callback=key_callback, show_left_ui=show_ui, show_right_ui=show_ui)
        if pins is not None:
            with self.handle.lock():
                self.handle.opt.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = 0  # the cylinders are drawn instead

    def show(self, t: float, qpos: np.ndarray, values: Mapping[str, float], stats: FrameStats) -> None:
        """Pose the viewer's copy at ``qpos``, draw the cylinders and the overlay, sync the window."""
        if not self.running or not self.handle.is_running():
            self.running = False
            return
        self.missed += bool(stats.missed)
        with self.handle.lock():
            self.data.qpos[:] = qpos
            self.data.time = t
            mujoco.mj_forward(self.model, self.data)
            if self.pins is not None:
                scene = self.handle.user_scn
                scene.ngeom = 0
                add_cylinder_geoms(scene, self.pins, self.data, cap_pressures(self.pins, values))
        self.handle.set_texts(overlay_texts(t, values, stats, self.missed))
        if self.chart is not None:
            figure = self.chart.add(t, values)
            window = self.handle.viewport
            if window is not None:
                width, height = window.width // 3, window.height // 3
                self.handle.set_figures((mujoco.MjrRect(window.width - width, 0, width, height), figure))
        self.handle.sync()

    def close(self) -> None:
        """Close the window (idempotent)."""
        if self.running:
            self.running = False
        self.handle.close()


def render_overlay(model: mujoco.MjModel, qpos: np.ndarray, pins: CylinderPins | None,
                   cap_pressure: Sequence[float] | None = None, *, size=(720, 1280),
                   camera: mujoco.MjvCamera | None = None) -> np.ndarray:
    """The frame :class:`ViewerOverlay` shows (without its text), rendered offscreen: RGB, shape (height, width, 3).

    Needs an offscreen OpenGL (``MUJOCO_GL=egl`` or ``osmesa``) and ``size`` within the model's
    ``<visual><global offwidth offheight>``.  ``pins``' cylinders are coloured by
    ``cap_pressure`` [Pa] (ambient when None).
    """
    height, width = size
    if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
        raise ValueError(f"render size {width}x{height} exceeds the model's offscreen buffer "
                         f"{model.vis.global_.offwidth}x{model.vis.global_.offheight} (<visual><global offwidth offheight>)")
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    option = mujoco.MjvOption()
    if pins is not None:
        option.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = 0
    with mujoco.Renderer(model, height, width) as renderer:
        renderer.update_scene(data, camera=camera if camera is not None else -1, scene_option=option)
        if pins is not None:
            pressure = np.full(len(pins.names), AMBIENT_PA) if cap_pressure is None else cap_pressure
            add_cylinder_geoms(renderer.scene, pins, data, pressure)
        return renderer.render().copy()


__all__ = ["PressureChart", "ViewerOverlay", "add_cylinder_geoms", "cap_pressures", "overlay_lines", "overlay_texts", "render_overlay"]
