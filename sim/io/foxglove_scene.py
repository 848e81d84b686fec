"""Foxglove 3D view of a MuJoCo model: static scene geometry and per-step body transforms.

The pattern: one ``foxglove.SceneUpdate``
(JSON) at t = 0 with an entity per body (``frame_locked``, infinite lifetime, primitives in
the body frame), then a ``foxglove_msgs/msg/FrameTransforms`` message (ROS 2, CDR) per
logged step giving every body's pose in ``world``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from sim.io.log_schemas import QUATERNION, TIME, VECTOR3, MsgField, MsgType
from sim.io.mcap_log import (
    FRAME_TRANSFORMS,
    TIMESTAMP,
    Channel,
    Column,
    LogWriter,
    scene_update_schema,
)

__all__ = [
    "CYLINDER_TOPIC",
    "SCENE_UPDATE",
    "CylinderPins",
    "CylinderScene",
    "FrameTransformsChannel",
    "cylinder_primitives",
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


# ---------------------------------------------------------------------------------------
# Hydraulic cylinders in the 3D scene: a columnar foxglove_msgs/msg/SceneUpdate (CDR)
# ---------------------------------------------------------------------------------------

def _floats(*names: str) -> tuple[MsgField, ...]:
    return tuple(MsgField(n, "float64") for n in names)


DURATION = MsgType("builtin_interfaces/msg/Duration", (MsgField("sec", "int32"), MsgField("nanosec", "uint32")))
POINT = MsgType("geometry_msgs/msg/Point", _floats("x", "y", "z"))
POSE = MsgType("geometry_msgs/msg/Pose", (MsgField("position", POINT), MsgField("orientation", QUATERNION)))
COLOR = MsgType("foxglove_msgs/msg/Color", _floats("r", "g", "b", "a"))
KEY_VALUE_PAIR = MsgType("foxglove_msgs/msg/KeyValuePair", (MsgField("key", "string"), MsgField("value", "string")))
ARROW_PRIMITIVE = MsgType("foxglove_msgs/msg/ArrowPrimitive", (
    MsgField("pose", POSE), *_floats("shaft_length", "shaft_diameter", "head_length", "head_diameter"),
    MsgField("color", COLOR)))
CUBE_PRIMITIVE = MsgType("foxglove_msgs/msg/CubePrimitive", (
    MsgField("pose", POSE), MsgField("size", VECTOR3), MsgField("color", COLOR)))
SPHERE_PRIMITIVE = MsgType("foxglove_msgs/msg/SpherePrimitive", (
    MsgField("pose", POSE), MsgField("size", VECTOR3), MsgField("color", COLOR)))
CYLINDER_PRIMITIVE = MsgType("foxglove_msgs/msg/CylinderPrimitive", (
    MsgField("pose", POSE, comment="center of the cylinder; its axis is the local z axis"),
    MsgField("size", VECTOR3, comment="bounding box: x and y diameters, z length [m]"),
    *_floats("bottom_scale", "top_scale"), MsgField("color", COLOR)))
LINE_PRIMITIVE = MsgType("foxglove_msgs/msg/LinePrimitive", (
    MsgField("type", "uint8"), MsgField("pose", POSE), MsgField("thickness", "float64"),
    MsgField("scale_invariant", "bool"), MsgField("points", POINT, 0), MsgField("color", COLOR),
    MsgField("colors", COLOR, 0), MsgField("indices", "uint32", 0)))
TRIANGLE_LIST_PRIMITIVE = MsgType("foxglove_msgs/msg/TriangleListPrimitive", (
    MsgField("pose", POSE), MsgField("points", POINT, 0), MsgField("color", COLOR), MsgField("colors", COLOR, 0),
    MsgField("indices", "uint32", 0)))
TEXT_PRIMITIVE = MsgType("foxglove_msgs/msg/TextPrimitive", (
    MsgField("pose", POSE), MsgField("billboard", "bool"), MsgField("font_size", "float64"),
    MsgField("scale_invariant", "bool"), MsgField("color", COLOR), MsgField("text", "string")))
MODEL_PRIMITIVE = MsgType("foxglove_msgs/msg/ModelPrimitive", (
    MsgField("pose", POSE), MsgField("scale", VECTOR3), MsgField("color", COLOR), MsgField("override_color", "bool"),
    MsgField("url", "string"), MsgField("media_type", "string"), MsgField("data", "uint8", 0)))
SCENE_ENTITY = MsgType("foxglove_msgs/msg/SceneEntity", (
    MsgField("timestamp", TIME), MsgField("frame_id", "string"), MsgField("id", "string"),
    MsgField("lifetime", DURATION), MsgField("frame_locked", "bool"), MsgField("metadata", KEY_VALUE_PAIR, 0),
    MsgField("arrows", ARROW_PRIMITIVE, 0), MsgField("cubes", CUBE_PRIMITIVE, 0),
    MsgField("spheres", SPHERE_PRIMITIVE, 0), MsgField("cylinders", CYLINDER_PRIMITIVE, 0),
    MsgField("lines", LINE_PRIMITIVE, 0), MsgField("triangles", TRIANGLE_LIST_PRIMITIVE, 0),
    MsgField("texts", TEXT_PRIMITIVE, 0), MsgField("models", MODEL_PRIMITIVE, 0)))
SCENE_ENTITY_DELETION = MsgType("foxglove_msgs/msg/SceneEntityDeletion", (
    MsgField("timestamp", TIME), MsgField("type", "uint8", comment="0: matching id, 1: all"), MsgField("id", "string")))
SCENE_UPDATE = MsgType("foxglove_msgs/msg/SceneUpdate", (
    MsgField("deletions", SCENE_ENTITY_DELETION, 0), MsgField("entities", SCENE_ENTITY, 0)))
"""``foxglove_msgs/msg/SceneUpdate``, the ROS 2 form of ``foxglove.SceneUpdate`` (Foxglove's schema text, without
its constants)."""

CYLINDER_TOPIC = "/hydroplant/scene/cylinders"
BARREL_GREY = np.array([0.55, 0.57, 0.62])  # barrel colour at ambient pressure
BARREL_RED = np.array([0.90, 0.12, 0.10])  # barrel colour at PRESSURE_FULL_SCALE
ROD_COLOR = (0.85, 0.85, 0.88, 1.0)
PRESSURE_FULL_SCALE = 35e6  # cap pressure above ambient drawn fully red [Pa] (350 bar)
_COLUMNS = 17  # per cylinder: barrel centre (3), orientation (4), colour (3); rod centre (3), orientation (4)


@dataclass(frozen=True)
class CylinderPins:
    """Where each hydraulic cylinder of a scene is pinned, and the sizes it is drawn at.

    A cylinder is the two-site spatial tendon of its actuator: the first site is the cap
    (barrel) pin, the second the rod eye.  It is drawn as two cylinders on the pin-to-pin
    line: the barrel from the cap pin, ``barrel_length = L_closed − 2 w`` long and ``2 w``
    across, and the rod from the rod eye, ``rod_length = min(stroke + 3 w, L_closed)`` long
    and ``w`` across (``w``: the tendon's ``width``; ``L_closed``: the lower end of the
    tendon's ``range``, fully retracted pin to pin), so the rod reaches a width ``w`` into
    the barrel at full extension.  Arrays are per cylinder, in the network's cylinder order.
    """

    names: tuple[str, ...]
    cap_body: np.ndarray
    """Body of each cap pin site."""
    cap_local: np.ndarray
    """Cap pin in its body's frame, shape (n, 3) [m]."""
    rod_body: np.ndarray
    rod_local: np.ndarray
    cap_site: np.ndarray
    """Site ids of the cap pins."""
    rod_site: np.ndarray
    barrel_length: np.ndarray
    """[m]"""
    barrel_diameter: np.ndarray
    rod_length: np.ndarray
    rod_diameter: np.ndarray

    @classmethod
    def of(cls, model: mujoco.MjModel, names: Sequence[str], tendons: Sequence[int], closed_length: Sequence[float],
           stroke: Sequence[float]) -> CylinderPins:
        """The pins of cylinders ``names`` on spatial ``tendons`` (ids; two sites each), fully retracted pin to pin
        ``closed_length`` [m], stroke ``stroke`` [m]."""
        sites = []
        for name, tendon in zip(names, tendons):
            adr, num = int(model.tendon_adr[tendon]), int(model.tendon_num[tendon])
            if num != 2 or any(int(w) != int(mujoco.mjtWrap.mjWRAP_SITE) for w in model.wrap_type[adr:adr + 2]):
                raise ValueError(f"cylinder {name!r}: tendon {tendon} is not a two-site spatial tendon")
            sites.append((int(model.wrap_objid[adr]), int(model.wrap_objid[adr + 1])))
        cap = np.array([s[0] for s in sites], dtype=np.intp).reshape(-1)
        rod = np.array([s[1] for s in sites], dtype=np.intp).reshape(-1)
        width = np.array([model.tendon_width[t] for t in tendons], dtype=float).reshape(-1)
        closed = np.asarray(closed_length, dtype=float).reshape(-1)
        return cls(tuple(names), model.site_bodyid[cap].copy(), model.site_pos[cap].copy(),
                   model.site_bodyid[rod].copy(), model.site_pos[rod].copy(), cap, rod,
                   np.maximum(closed - 2.0 * width, 0.5 * closed), 2.0 * width,
                   np.minimum(np.asarray(stroke, dtype=float) + 3.0 * width, closed), width)

    @classmethod
    def of_scene(cls, scene: Any) -> CylinderPins:
        """The pins of every cylinder of a :class:`~sim.io.scene.Scene` (its network's cylinder order)."""
        net, binding = scene.network, scene.binding
        cyl = np.asarray(net.cylinder_actuator, dtype=np.intp)
        return cls.of(scene.mjmodel, [net.actuator_names[a] for a in cyl], binding.tendon_id[cyl],
                      binding.closed_length[cyl], net.cylinder_stroke)

    def world(self, xpos: np.ndarray, xquat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cap and rod pins in world [m], shape (..., n, 3), from body poses ``xpos`` (..., nbody, 3) and ``xquat``
        (..., nbody, 4) (MuJoCo's w, x, y, z): ``p = xpos[body] + R(xquat[body]) · local``."""
        return (xpos[..., self.cap_body, :] + _rotate_rows(xquat[..., self.cap_body, :], self.cap_local),
                xpos[..., self.rod_body, :] + _rotate_rows(xquat[..., self.rod_body, :], self.rod_local))


def _rotate_rows(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` rotated by unit quaternions ``q`` (w, x, y, z), broadcast: v + 2 w (u × v) + 2 u × (u × v)."""
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b of 3-vectors along the last axis, broadcast: the products and differences of ``np.cross`` in its order
    (the same floats), without its axis handling, which costs more than the arithmetic on a batch's few rows."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def _z_to(direction: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) turning +z onto the unit vectors ``direction`` (..., 3) (half-way form;
    a turn of π about x for −z)."""
    x, y, z = direction[..., 0], direction[..., 1], direction[..., 2]
    q = np.stack([-y, x, np.zeros_like(x), 1.0 + z], axis=-1)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    flip = norm[..., 0] < 1e-9
    q = q / np.where(norm < 1e-9, 1.0, norm)
    q[flip] = (1.0, 0.0, 0.0, 0.0)
    return q


def cylinder_primitives(pins: CylinderPins, cap: np.ndarray, rod: np.ndarray, p_cap: np.ndarray,
                        ambient: float = 1.0e5) -> np.ndarray:
    """The varying fields of every cylinder's two primitives, rows (..., n, 17): barrel centre (3), orientation
    (x, y, z, w), colour (r, g, b); rod centre (3), orientation.

    ``cap``, ``rod``: pins in world (..., n, 3) [m]; ``p_cap``: cap pressures (..., n) [Pa].
    With ``u`` the unit vector cap → rod: the barrel's centre is ``cap + u·barrel_length/2``
    and the rod's ``rod − u·rod_length/2``, both with local z along ``u``; the barrel blends
    from grey to red as ``p_cap − ambient`` goes from 0 to :data:`PRESSURE_FULL_SCALE`.
    """
    axis = rod - cap
    u = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-12)
    q = _z_to(u)
    out = np.empty(axis.shape[:-1] + (_COLUMNS,))
    out[..., 0:3] = cap + u * (0.5 * pins.barrel_length)[:, None]
    out[..., 3:7] = q
    level = np.clip((np.asarray(p_cap, dtype=float) - ambient) / PRESSURE_FULL_SCALE, 0.0, 1.0)[..., None]
    out[..., 7:10] = BARREL_GREY + level * (BARREL_RED - BARREL_GREY)
    out[..., 10:13] = rod - u * (0.5 * pins.rod_length)[:, None]
    out[..., 13:17] = q
    return out


def _cylinder_layout(pins: CylinderPins) -> dict[str, Any]:
    """The SceneUpdate template: one entity ``cylinders`` in ``world`` holding barrel and rod of every cylinder, in
    the pins' order, columns as :func:`cylinder_primitives` lays them out (cylinder i at column 17 i)."""
    primitives = []
    for i, name in enumerate(pins.names):
        c = _COLUMNS * i

        def pose(first: int) -> dict[str, Any]:
            return {"position": {"x": Column(first), "y": Column(first + 1), "z": Column(first + 2)},
                    "orientation": {"x": Column(first + 3), "y": Column(first + 4), "z": Column(first + 5),
                                    "w": Column(first + 6)}}

        barrel_d, rod_d = float(pins.barrel_diameter[i]), float(pins.rod_diameter[i])
        primitives += [
            {"pose": pose(c), "size": {"x": barrel_d, "y": barrel_d, "z": float(pins.barrel_length[i])},
             "bottom_scale": 1.0, "top_scale": 1.0,
             "color": {"r": Column(c + 7), "g": Column(c + 8), "b": Column(c + 9), "a": 1.0}},
            {"pose": pose(c + 10), "size": {"x": rod_d, "y": rod_d, "z": float(pins.rod_length[i])},
             "bottom_scale": 1.0, "top_scale": 1.0, "color": dict(zip("rgba", ROD_COLOR))},
        ]
    entity = {"timestamp": TIMESTAMP, "frame_id": WORLD_FRAME, "id": "cylinders", "lifetime": {"sec": 0, "nanosec": 0},
              "frame_locked": False, "cylinders": primitives}
    return {"deletions": [], "entities": [entity]}


class CylinderScene:
    """The hydraulic cylinders on ``/hydroplant/scene/cylinders``: a ``foxglove_msgs/msg/SceneUpdate`` (CDR) per
    sample of a :class:`~sim.io.log_writer.Frame`, one entity ``cylinders`` in ``world`` whose cylinder primitives
    are barrel and rod of each cylinder between its pins (cylinder i: primitives 2 i and 2 i + 1).

    The channel reads ``17 × n`` columns of the frame (:meth:`fill` writes them from the body
    poses and cap pressures of a batch of rows), at the rows whose step is a multiple of
    ``every`` (the ``/tf`` rate: the scene moves with the bodies).  Encoded in the frame's
    batches like every columnar topic: no per-sample Python.

    Parameters
    ----------
    frame : Frame
        The log frame whose rows hold the columns.
    pins : CylinderPins
        The cylinders.
    columns : slice
        The ``17 × n`` frame columns of this channel.
    every : int, optional
        Steps between scene samples.
    topic : str, optional
        Topic name.
    """

    def __init__(self, frame: Any, pins: CylinderPins, columns: slice, *, every: int = 1,
                 topic: str = CYLINDER_TOPIC):
        self.pins = pins
        self.columns = columns
        self.every = int(every)
        self.channel = frame.channel(topic, SCENE_UPDATE, layout=_cylinder_layout(pins),
                                     columns=np.arange(columns.start, columns.stop), every=every,
                                     metadata={"units": "SI", "drawing": "barrel from the cap pin, rod from the rod eye"})

    @staticmethod
    def width(pins: CylinderPins) -> int:
        """Frame columns the channel needs."""
        return _COLUMNS * len(pins.names)

    def fill(self, rows: np.ndarray, steps: np.ndarray, xpos: np.ndarray, xquat: np.ndarray, p_cap: np.ndarray) -> None:
        """Write the columns of the ``rows`` (k, frame width) the channel takes (those whose ``steps`` are multiples
        of ``every``) from body poses (k, nbody, 3), (k, nbody, 4) and cap pressures (k, n) [Pa]."""
        taken = np.flatnonzero(np.asarray(steps) % self.every == 0) if self.every > 1 else np.arange(len(rows))
        if len(taken):
            cap, rod = self.pins.world(xpos[taken], xquat[taken])
            rows[taken, self.columns] = cylinder_primitives(self.pins, cap, rod, p_cap[taken]).reshape(len(taken), -1)
