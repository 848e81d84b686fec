"""Foxglove 3D view of a MuJoCo model: static scene geometry and per-step body transforms.

The pattern: one ``foxglove.SceneUpdate``
(JSON) at t = 0 with an entity per body (``frame_locked``, infinite lifetime, primitives in
the body frame), then a ``foxglove_msgs/msg/FrameTransforms`` message (ROS 2, CDR) per
logged step giving every body's pose in ``world``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np

from sim.io.mcap_log import (
    FRAME_TRANSFORMS,
    TIMESTAMP,
    Channel,
    Column,
    LogWriter,
    scene_update_schema,
)

__all__ = [
    "FrameTransformsChannel",
    "body_frame_ids",
    "log_scene",
    "scene_update_message",
]

WORLD_FRAME = "world"  # frame id of MuJoCo body 0
PLANE_DEFAULT_EXTENT = 20.0  # drawn side length of an infinite plane [m]
PLANE_THICKNESS = 1.0e-3  # drawn thickness of a plane, below its surface [m]


def body_frame_ids(model: mujoco.MjModel) -> list[str]:
    """Frame id of every body: its name, or ``"body<i>"`` when unnamed.

    Parameters
    ----------
    model : mujoco.MjModel
        Compiled model.

    Returns
    -------
    list of str, length nbody
        Entry 0 is ``"world"``.
    """
    ids = [model.body(i).name or f"body{i}" for i in range(model.nbody)]
    if len(set(ids)) != len(ids):
        raise ValueError(f"body frame ids are not unique: {ids}")
    return ids


def _pose(position: np.ndarray, quat_wxyz: np.ndarray) -> dict[str, dict[str, float]]:
    """Foxglove pose from a position [m] and a MuJoCo quaternion (w, x, y, z)."""
    return {
        "position": {"x": float(position[0]), "y": float(position[1]), "z": float(position[2])},
        "orientation": {"x": float(quat_wxyz[1]), "y": float(quat_wxyz[2]), "z": float(quat_wxyz[3]),
                        "w": float(quat_wxyz[0])},
    }


def _vec3(values: np.ndarray) -> dict[str, float]:
    return {"x": float(values[0]), "y": float(values[1]), "z": float(values[2])}


def _rotate(quat_wxyz: np.ndarray, vector: np.ndarray) -> np.ndarray:
    result = np.zeros(3)
    mujoco.mju_rotVecQuat(result, np.asarray(vector, dtype=np.float64), np.asarray(quat_wxyz, dtype=np.float64))
    return result


def _geom_primitives(model: mujoco.MjModel, geom: int) -> dict[str, list[dict[str, Any]]]:
    """Primitives drawing one geom, in its body's frame.

    Returns a dict with lists under ``"cubes"``, ``"spheres"`` and ``"cylinders"``.
    """
    kind = model.geom_type[geom]
    size = model.geom_size[geom]
    position = model.geom_pos[geom]
    quat = model.geom_quat[geom]
    rgba = model.geom_rgba[geom]
    color = {"r": float(rgba[0]), "g": float(rgba[1]), "b": float(rgba[2]), "a": float(rgba[3])}
    out: dict[str, list[dict[str, Any]]] = {"cubes": [], "spheres": [], "cylinders": []}

    def cube(center: np.ndarray, extent: np.ndarray) -> None:
        out["cubes"].append({"pose": _pose(center, quat), "size": _vec3(extent), "color": color})

    def sphere(center: np.ndarray, diameter: np.ndarray) -> None:
        out["spheres"].append({"pose": _pose(center, quat), "size": _vec3(diameter), "color": color})

    def cylinder(radius: float, half_length: float) -> None:
        out["cylinders"].append({
            "pose": _pose(position, quat),
            "size": _vec3(np.array([2 * radius, 2 * radius, 2 * half_length])),
            "bottom_scale": 1.0, "top_scale": 1.0, "color": color,
        })

    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        cube(position, 2.0 * size[:3])
    elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        sphere(position, np.full(3, 2.0 * size[0]))
    elif kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        sphere(position, 2.0 * size[:3])
    elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        cylinder(size[0], size[1])
    elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        radius, half_length = size[0], size[1]
        cylinder(radius, half_length)
        for sign in (1.0, -1.0):
            sphere(position + _rotate(quat, np.array([0.0, 0.0, sign * half_length])), np.full(3, 2.0 * radius))
    elif kind == mujoco.mjtGeom.mjGEOM_PLANE:
        extent = np.array([2.0 * size[0] if size[0] > 0 else PLANE_DEFAULT_EXTENT,
                           2.0 * size[1] if size[1] > 0 else PLANE_DEFAULT_EXTENT,
                           PLANE_THICKNESS])
        cube(position + _rotate(quat, np.array([0.0, 0.0, -0.5 * PLANE_THICKNESS])), extent)
    else:  # mesh, height field, SDF: drawn as their bounding box
        aabb = model.geom_aabb[geom]
        cube(position + _rotate(quat, aabb[:3]), 2.0 * aabb[3:])
    return out


def scene_update_message(model: mujoco.MjModel, *, timestamp_ns: int = 0) -> dict[str, Any]:
    """One ``foxglove.SceneUpdate`` drawing every body's geoms.

    Parameters
    ----------
    model : mujoco.MjModel
        Compiled model.
    timestamp_ns : int, optional
        Entity timestamp [ns].

    Returns
    -------
    dict
        ``{"deletions": [], "entities": [...]}`` with one entity per body (``nbody``
        entities, world included): ``frame_id`` and ``id`` from :func:`body_frame_ids`,
        ``frame_locked`` true, zero lifetime. Primitives are in the body frame, from
        ``geom_pos``/``geom_quat``: box -> cube of size 2·half-sizes; sphere, ellipsoid ->
        sphere; cylinder -> cylinder; capsule -> cylinder plus two end spheres; plane ->
        thin cube (``PLANE_DEFAULT_EXTENT`` when infinite); mesh/hfield/SDF -> bounding
        cube. Colors from ``geom_rgba``.
    """
    frame_ids = body_frame_ids(model)
    sec, nsec = divmod(int(timestamp_ns), 1_000_000_000)
    entities = []
    for body, frame_id in enumerate(frame_ids):
        primitives: dict[str, list] = {"cubes": [], "spheres": [], "cylinders": []}
        for geom in np.flatnonzero(model.geom_bodyid == body).tolist():
            for key, items in _geom_primitives(model, geom).items():
                primitives[key].extend(items)
        entities.append({
            "timestamp": {"sec": sec, "nsec": nsec},
            "frame_id": frame_id,
            "id": frame_id,
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": True,
            "metadata": [],
            "arrows": [],
            "cubes": primitives["cubes"],
            "spheres": primitives["spheres"],
            "cylinders": primitives["cylinders"],
            "lines": [],
            "triangles": [],
            "texts": [],
            "models": [],
        })
    return {"deletions": [], "entities": entities}


def log_scene(log: LogWriter, model: mujoco.MjModel, *, topic: str = "/hydroplant/scene",
              step_index: int = 0, metadata: Mapping[str, str] | None = None) -> Channel:
    """Register a ``foxglove.SceneUpdate`` channel and write the model's scene once.

    Parameters
    ----------
    log : LogWriter
        Open log.
    model : mujoco.MjModel
        Compiled model.
    topic : str, optional
        Scene topic.
    step_index : int, optional
        Step at which the scene is logged.
    metadata : Mapping[str, str], optional
        Channel metadata.

    Returns
    -------
    Channel
        The scene channel, for later updates.
    """
    channel = log.channel(topic, "foxglove.SceneUpdate", scene_update_schema(), metadata=metadata)
    channel.write(step_index, scene_update_message(model, timestamp_ns=log.log_time(step_index)))
    return channel


class FrameTransformsChannel:
    """Columnar ``foxglove_msgs/msg/FrameTransforms`` channel (CDR) with the world pose of every body.

    Each message holds one transform per body except the world body, parent
    ``parent_frame``, child :func:`body_frame_ids`, translation ``data.xpos`` [m] and
    rotation ``data.xquat`` reordered from MuJoCo's (w, x, y, z) to Foxglove's
    (x, y, z, w).

    Parameters
    ----------
    log : LogWriter
        Open log.
    model : mujoco.MjModel
        Compiled model.
    topic : str, optional
        Topic name.
    parent_frame : str, optional
        Parent frame of every transform.
    metadata : Mapping[str, str], optional
        Channel metadata.

    Attributes
    ----------
    channel : Channel
        Underlying columnar channel.
    frame_ids : list of str
        Child frame ids, in body order (world excluded).
    """

    def __init__(self, log: LogWriter, model: mujoco.MjModel, topic: str = "/tf", *,
                 parent_frame: str = WORLD_FRAME, metadata: Mapping[str, str] | None = None):
        if model.nbody < 2:
            raise ValueError(f"model must have a body besides the world, got nbody={model.nbody}")
        ids = body_frame_ids(model)
        self._position_columns = 3 * model.nbody
        self.frame_ids = ids[1:]
        position_base, quat_base = 0, 3 * model.nbody
        transforms = []
        for body in range(1, model.nbody):
            p, q = position_base + 3 * body, quat_base + 4 * body
            transforms.append({
                "timestamp": TIMESTAMP,
                "parent_frame_id": parent_frame,
                "child_frame_id": ids[body],
                "translation": {"x": Column(p), "y": Column(p + 1), "z": Column(p + 2)},
                "rotation": {"x": Column(q + 1), "y": Column(q + 2), "z": Column(q + 3), "w": Column(q)},
            })
        # Columns: xpos.ravel() then xquat.ravel(), world body included (unused) so that
        # append copies both arrays whole; the last quaternion column is 7 * nbody - 1.
        layout = {"transforms": transforms}
        self.channel = log.cdr_channel(topic, FRAME_TRANSFORMS, layout=layout, metadata=metadata)

    def append(self, step_index: int, xpos: np.ndarray, xquat: np.ndarray) -> None:
        """Buffer the body poses of one step.

        Parameters
        ----------
        step_index : int
            Physics step.
        xpos : ndarray, shape (nbody, 3)
            Body positions in world, ``data.xpos`` [m].
        xquat : ndarray, shape (nbody, 4)
            Body orientations in world, ``data.xquat`` (w, x, y, z).
        """
        row = self.channel.claim(step_index)
        split = self._position_columns
        row[:split] = np.ravel(xpos)
        row[split:] = np.ravel(xquat)
        self.channel.commit()
