"""Message types and encodings of the logs: JSON Schemas, ROS 2 ``.msg`` types and their CDR encoding, log times.

- **CDR** (:class:`MsgType`, :func:`flat_schema`, :func:`cdr_encode`, :func:`cdr_decode`): the
  numeric, fixed-layout topics are ROS 2 messages as rosbag2 writes them: schema encoding
  ``ros2msg`` (the ``.msg`` text of a :class:`MsgType`, nested types appended as ``MSG:
  pkg/Name`` sections), message encoding ``cdr`` (the little-endian encapsulation header ``00 01
  00 00``, then the fields in order, each primitive aligned to its size from the end of the
  header, strings and sequences with a uint32 count first). Joint states are
  ``foxglove_msgs/msg/JointStates`` and body poses ``foxglove_msgs/msg/FrameTransforms``, the
  ROS 2 forms of the Foxglove schemas.  A channel's messages are built from a byte template
  with slots (:class:`_CdrTemplate`).
- **JSON** (:func:`to_json_bytes`, :func:`log_schema`, :func:`scene_update_schema`): strict JSON,
  non-finite floats written as ``null``.
- **Time** (:func:`step_log_time`): ``log_time = publish_time`` is simulation time in integer
  nanoseconds computed from the integer step index.

Example::

    msg_type = flat_schema("hydroplant_msgs/msg/Pump", {"p_pa": "Outlet pressure [Pa]"})
    data = cdr_encode(msg_type, {"timestamp": {"sec": 0, "nanosec": 0}, "p_pa": 2e7})
    assert cdr_decode(msg_type, data)["p_pa"] == 2e7
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import json
import math
import re
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.io.mcap_file import NS_PER_S

# ---------------------------------------------------------------------------------------
# Time and JSON
# ---------------------------------------------------------------------------------------


def _integral_step_ns(dt: float) -> int | None:
    """Return ``dt`` in ns when it is an integer number of ns (within 1e-9 relative)."""
    dt_ns = dt * 1e9
    nearest = round(dt_ns)
    if nearest > 0 and abs(dt_ns - nearest) <= 1e-9 * nearest:
        return nearest
    return None


def step_log_time(step_index: int, dt: float) -> int:
    """Log time of a step: simulation time as integer nanoseconds.

    Parameters
    ----------
    step_index : int
        Index of the physics step (>= 0).
    dt : float
        Physics time step [s].

    Returns
    -------
    int
        ``step_index * dt_ns`` when ``dt`` is an integer number of nanoseconds
        (``dt_ns = round(dt * 1e9)``), else ``round(step_index * dt * 1e9)`` [ns]. Both
        depend only on the integer index, so runs of the same scenario share time stamps.
    """
    dt_ns = _integral_step_ns(dt)
    if dt_ns is not None:
        return int(step_index) * dt_ns
    return round(int(step_index) * dt * 1e9)


def _step_log_times(step_index: np.ndarray, dt: float) -> np.ndarray:
    """Vectorised :func:`step_log_time`; ``step_index`` is int64, result int64 [ns]."""
    dt_ns = _integral_step_ns(dt)
    if dt_ns is not None:
        return step_index * np.int64(dt_ns)
    # Same operation order as the scalar path; np.rint rounds half to even like round().
    return np.rint(step_index.astype(np.float64) * dt * 1e9).astype(np.int64)


def _timestamp(log_time: int) -> dict[str, int]:
    sec, nsec = divmod(log_time, NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def _strict(value: Any) -> Any:
    """Copy ``value`` into plain JSON types; non-finite floats become ``None``."""
    if isinstance(value, float):  # includes np.float64
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, Mapping):
        out = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError(f"JSON object keys must be str, got {key!r}")
            out[key] = _strict(item)
        return out
    if isinstance(value, (list, tuple)):
        return [_strict(item) for item in value]
    if isinstance(value, np.ndarray):
        return _strict(value.tolist())
    if isinstance(value, np.generic):
        return _strict(value.item())
    raise TypeError(f"cannot encode {type(value).__name__} as JSON: {value!r}")


def to_json_bytes(message: Mapping[str, Any]) -> bytes:
    """Encode a message as strict, compact JSON.

    Parameters
    ----------
    message : Mapping[str, Any]
        JSON-like object; numpy scalars and arrays are accepted.

    Returns
    -------
    bytes
        UTF-8 JSON with NaN/±inf written as ``null``.
    """
    try:  # finite plain data (e.g. the scene update, 12 kB) encodes in one pass; numpy goes through _strict
        return json.dumps(message, allow_nan=False, separators=(",", ":"), default=_strict).encode()
    except ValueError:  # a non-finite float: copy with null in its place
        return json.dumps(_strict(message), allow_nan=False, separators=(",", ":")).encode()


def _reject_constant(name: str) -> None:
    raise ValueError(f"non-finite JSON constant {name} in message")


def _loads(data: bytes) -> Any:
    return json.loads(data, parse_constant=_reject_constant)


# ---------------------------------------------------------------------------------------
# Schemas
# ---------------------------------------------------------------------------------------


def _time_schema(description: str) -> dict:
    return {
        "type": "object",
        "title": "time",
        "description": description,
        "properties": {
            "sec": {"type": "integer", "minimum": 0},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
        },
    }


def _duration_schema(description: str) -> dict:
    return {
        "type": "object",
        "title": "duration",
        "description": description,
        "properties": {
            "sec": {"type": "integer"},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
        },
    }


def _vector3_schema(description: str) -> dict:
    return {
        "title": "foxglove.Vector3",
        "description": description,
        "type": "object",
        "properties": {axis: {"type": "number", "description": f"{axis} component"} for axis in "xyz"},
        "required": ["x", "y", "z"],
    }


def _quaternion_schema(description: str) -> dict:
    return {
        "title": "foxglove.Quaternion",
        "description": description,
        "type": "object",
        "properties": {axis: {"type": "number", "description": f"{axis} value"} for axis in "xyzw"},
        "required": ["x", "y", "z", "w"],
    }


def _pose_schema(description: str) -> dict:
    return {
        "title": "foxglove.Pose",
        "description": description,
        "type": "object",
        "properties": {
            "position": _vector3_schema("Position [m]"),
            "orientation": _quaternion_schema("Orientation"),
        },
        "required": ["position", "orientation"],
    }


def _color_schema() -> dict:
    return {
        "title": "foxglove.Color",
        "description": "Color, components between 0 and 1",
        "type": "object",
        "properties": {c: {"type": "number"} for c in "rgba"},
        "required": ["r", "g", "b", "a"],
    }


def _primitive_schema(title: str, description: str, extra: Mapping[str, dict]) -> dict:
    properties = {"pose": _pose_schema("Pose of the primitive's center in the entity frame")}
    properties.update(extra)
    properties["color"] = _color_schema()
    return {
        "type": "array",
        "items": {
            "title": title,
            "description": description,
            "type": "object",
            "properties": properties,
            "required": list(properties),
        },
    }


def scene_update_schema() -> dict:
    """JSON Schema of ``foxglove.SceneUpdate``.

    Returns
    -------
    dict
        ``deletions[]`` and ``entities[]{timestamp, frame_id, id, lifetime, frame_locked,
        metadata, arrows, cubes, spheres, cylinders, lines, triangles, texts, models}``.
        Cubes, spheres and cylinders are described fully (sizes in m); the other
        primitive lists are declared as arrays of objects.
    """
    loose = {"type": "array", "items": {"type": "object"}}
    entity_properties = {
        "timestamp": _time_schema("Timestamp of the entity"),
        "frame_id": {"type": "string", "description": "Frame of reference"},
        "id": {"type": "string", "description": "Identifier of the entity on its topic"},
        "lifetime": _duration_schema("Lifetime after timestamp; zero means forever"),
        "frame_locked": {"type": "boolean", "description": "Follow frame_id as it moves"},
        "metadata": {
            "type": "array",
            "items": {
                "title": "foxglove.KeyValuePair",
                "type": "object",
                "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
                "required": ["key", "value"],
            },
        },
        "arrows": dict(loose),
        "cubes": _primitive_schema(
            "foxglove.CubePrimitive",
            "A cube or rectangular prism",
            {"size": _vector3_schema("Size along each axis [m]")},
        ),
        "spheres": _primitive_schema(
            "foxglove.SpherePrimitive",
            "A sphere or ellipsoid",
            {"size": _vector3_schema("Diameter along each axis [m]")},
        ),
        "cylinders": _primitive_schema(
            "foxglove.CylinderPrimitive",
            "A cylinder or truncated cone; flat faces perpendicular to z",
            {
                "size": _vector3_schema("Size of the bounding box [m]"),
                "bottom_scale": {"type": "number", "description": "Bottom diameter ratio, 0-1"},
                "top_scale": {"type": "number", "description": "Top diameter ratio, 0-1"},
            },
        ),
        "lines": dict(loose),
        "triangles": dict(loose),
        "texts": dict(loose),
        "models": dict(loose),
    }
    return {
        "title": "foxglove.SceneUpdate",
        "description": "An update to the entities displayed in a 3D scene",
        "type": "object",
        "properties": {
            "deletions": {
                "type": "array",
                "description": "Scene entities to delete",
                "items": {
                    "title": "foxglove.SceneEntityDeletion",
                    "type": "object",
                    "properties": {
                        "timestamp": _time_schema("Only matching entities earlier than this are deleted"),
                        "type": {"type": "integer", "description": "0 = MATCHING_ID, 1 = ALL"},
                        "id": {"type": "string"},
                    },
                    "required": ["timestamp", "type", "id"],
                },
            },
            "entities": {
                "type": "array",
                "description": "Scene entities to add or replace",
                "items": {
                    "title": "foxglove.SceneEntity",
                    "type": "object",
                    "properties": entity_properties,
                    "required": list(entity_properties),
                },
            },
        },
        "required": ["deletions", "entities"],
    }


class LogLevel(enum.IntEnum):
    """``foxglove.LogLevel`` values."""

    UNKNOWN = 0
    DEBUG = 1
    INFO = 2
    WARNING = 3
    ERROR = 4
    FATAL = 5


def log_schema() -> dict:
    """JSON Schema of ``foxglove.Log``.

    Returns
    -------
    dict
        ``timestamp, level (0..5), message, name, file, line``.
    """
    return {
        "title": "foxglove.Log",
        "description": "A log message",
        "type": "object",
        "properties": {
            "timestamp": _time_schema("Timestamp of log message"),
            "level": {
                "title": "foxglove.LogLevel",
                "description": "Log level",
                "oneOf": [{"title": level.name, "const": int(level)} for level in LogLevel],
            },
            "message": {"type": "string", "description": "Log message"},
            "name": {"type": "string", "description": "Process or node name"},
            "file": {"type": "string", "description": "Filename"},
            "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
        },
        "required": ["timestamp", "level", "message", "name", "file", "line"],
    }


def log_message(level: LogLevel | int, message: str, *, name: str = "hydroplant", file: str = "", line: int = 0) -> dict:
    """Build a ``foxglove.Log`` message body (the timestamp is added by :meth:`Channel.write`).

    Parameters
    ----------
    level : LogLevel or int
        Severity, 0..5.
    message : str
        Text of the event.
    name, file : str
        Emitting component and source file.
    line : int
        Source line (>= 0).
    """
    return {"level": int(LogLevel(level)), "message": message, "name": name, "file": file, "line": int(line)}


FOXGLOVE_SCHEMAS = {
    "foxglove.SceneUpdate": scene_update_schema,
    "foxglove.Log": log_schema,
}
"""Builders of the well-known Foxglove JSON schemas (the irregular topics), keyed by their exact schema name."""


# ---------------------------------------------------------------------------------------
# ROS 2 message types (ros2msg schemas) and CDR
# ---------------------------------------------------------------------------------------
#
# The numeric, fixed-layout topics are ROS 2 messages in CDR, as rosbag2 writes them: schema
# encoding "ros2msg" (the .msg text, dependencies appended after "=====" lines as
# "MSG: pkg/Name"), message encoding "cdr", each message the little-endian encapsulation
# header 00 01 00 00 followed by the fields in order, every primitive aligned to its size
# (counted from the end of the header), strings and sequences as a uint32 count first.

CDR_HEADER = b"\x00\x01\x00\x00"  # CDR little-endian encapsulation (CDR_LE), options 0
_CDR_BASE = len(CDR_HEADER)  # alignment is counted from the end of the header
_PRIMITIVES = {  # ros2msg primitive -> struct format (its size is its CDR alignment)
    "bool": "?", "byte": "B", "char": "B", "int8": "b", "uint8": "B", "int16": "<h", "uint16": "<H",
    "int32": "<i", "uint32": "<I", "int64": "<q", "uint64": "<Q", "float32": "<f", "float64": "<d",
}
_ROS_FIELD_NAME = re.compile(r"(?!.*__)(?!.*_$)[a-z][a-z0-9_]*")  # rosidl's field name pattern
_ROS_TYPE_NAME = re.compile(r"([a-z][a-z0-9_]*)/(?:msg/)?([A-Z][A-Za-z0-9]*)")
_DEFINITION_SEPARATOR = "=" * 80


@dataclass(frozen=True)
class MsgField:
    """One field of a :class:`MsgType`.

    Attributes
    ----------
    name : str
        Field name (ROS 2 pattern ``[a-z][a-z0-9_]*``, no ``__``, no trailing ``_``).
    type : str or MsgType
        A primitive (``"float64"``, ``"int32"``, ...), ``"string"``, or a nested message type.
    length : int or None
        None for a single value, 0 for an unbounded sequence (``T[]``), N > 0 for a fixed
        array (``T[N]``).
    comment : str
        Written after the field in the schema text (units go here).
    """

    name: str
    type: str | MsgType
    length: int | None = None
    comment: str = dataclasses.field(default="", compare=False)


@dataclass(frozen=True)
class MsgType:
    """A ROS 2 message type: its ``ros2msg`` schema text and its CDR layout.

    Attributes
    ----------
    name : str
        Full name ``"pkg/msg/Name"`` (the MCAP schema name).
    fields : tuple of MsgField
        Fields in wire order.
    """

    name: str
    fields: tuple[MsgField, ...]

    def __hash__(self) -> int:  # computed once (the types are cache keys of every channel of every run)
        try:
            return self._hash  # type: ignore[has-type]
        except AttributeError:
            object.__setattr__(self, "_hash", hash((self.name, self.fields)))
            return self._hash

    def __post_init__(self) -> None:
        if not _ROS_TYPE_NAME.fullmatch(self.name) or "/msg/" not in self.name:
            raise ValueError(f"message type name must be 'pkg/msg/Name', got {self.name!r}")
        names = [f.name for f in self.fields]
        for field in self.fields:
            if not _ROS_FIELD_NAME.fullmatch(field.name):
                raise ValueError(f"{self.name}: {field.name!r} is not a ROS 2 field name ([a-z][a-z0-9_]*, no '__')")
            if not isinstance(field.type, MsgType) and field.type != "string" and field.type not in _PRIMITIVES:
                raise ValueError(f"{self.name}.{field.name}: unknown type {field.type!r}")
            if field.length is not None and field.length < 0:
                raise ValueError(f"{self.name}.{field.name}: array length must be >= 0, got {field.length}")
        if len(set(names)) != len(names):
            raise ValueError(f"{self.name}: duplicate field names in {names}")

    @property
    def short_name(self) -> str:
        """``"pkg/Name"``, the form used inside schema texts."""
        return self.name.replace("/msg/", "/")

    def field(self, name: str) -> MsgField:
        for field in self.fields:
            if field.name == name:
                return field
        raise KeyError(f"{self.name} has no field {name!r}")

    def definition(self) -> str:
        """The ``ros2msg`` schema text: this type, then every nested type once (``MSG: pkg/Name``)."""
        sections = [self._body()]
        sections += [f"MSG: {dep.short_name}\n{dep._body()}" for dep in self._dependencies()]
        return f"\n{_DEFINITION_SEPARATOR}\n".join(sections)

    def _body(self) -> str:
        lines = []
        for field in self.fields:
            base = field.type.short_name if isinstance(field.type, MsgType) else field.type
            suffix = "" if field.length is None else ("[]" if field.length == 0 else f"[{field.length}]")
            comment = f"  # {field.comment}" if field.comment else ""
            lines.append(f"{base}{suffix} {field.name}{comment}")
        return "\n".join(lines)

    def _dependencies(self) -> list[MsgType]:
        out: dict[str, MsgType] = {}

        def visit(t: MsgType) -> None:
            for field in t.fields:
                if isinstance(field.type, MsgType):
                    previous = out.setdefault(field.type.name, field.type)
                    if previous != field.type:
                        raise ValueError(f"{self.name}: two different definitions of {field.type.name}")
                    visit(field.type)

        visit(self)
        return list(out.values())


def _float_fields(*names: str, comment: str = "") -> tuple[MsgField, ...]:
    return tuple(MsgField(n, "float64", comment=comment) for n in names)


TIME = MsgType("builtin_interfaces/msg/Time", (MsgField("sec", "int32"), MsgField("nanosec", "uint32")))
VECTOR3 = MsgType("geometry_msgs/msg/Vector3", _float_fields("x", "y", "z"))
QUATERNION = MsgType("geometry_msgs/msg/Quaternion", _float_fields("x", "y", "z", "w"))
FRAME_TRANSFORM = MsgType("foxglove_msgs/msg/FrameTransform", (
    MsgField("timestamp", TIME), MsgField("parent_frame_id", "string"), MsgField("child_frame_id", "string"),
    MsgField("translation", VECTOR3, comment="child origin in the parent frame [m]"),
    MsgField("rotation", QUATERNION, comment="child orientation in the parent frame (unit quaternion)")))
FRAME_TRANSFORMS = MsgType("foxglove_msgs/msg/FrameTransforms", (MsgField("transforms", FRAME_TRANSFORM, 0),))
"""``foxglove_msgs/msg/FrameTransforms``, the ROS 2 form Foxglove's 3D panel reads on ``/tf``."""
JOINT_STATE = MsgType("foxglove_msgs/msg/JointState", (
    MsgField("name", "string"), MsgField("position", "float64", comment="[rad] or [m]; NaN if not set"),
    MsgField("velocity", "float64", comment="[rad/s] or [m/s]; NaN if not set"),
    MsgField("acceleration", "float64", comment="[rad/s^2] or [m/s^2]; NaN if not set"),
    MsgField("effort", "float64", comment="[N*m] or [N]; NaN if not set")))
JOINT_STATES = MsgType("foxglove_msgs/msg/JointStates", (MsgField("timestamp", TIME), MsgField("joints", JOINT_STATE, 0)))
"""``foxglove_msgs/msg/JointStates``: ``timestamp``, ``joints[]{name, position, velocity, acceleration, effort}``."""


def flat_schema(name: str, fields: Mapping[str, str]) -> MsgType:
    """ROS 2 message type of a flat message: ``timestamp`` (``builtin_interfaces/Time``) and float64 fields.

    Parameters
    ----------
    name : str
        Type name ``"pkg/msg/Name"`` (e.g. ``"hydroplant_msgs/msg/CylinderState"``); the JSON
        schema names of earlier logs, ``"pkg.Name"``, stand for ``"pkg_msgs/msg/Name"``.
    fields : Mapping[str, str]
        Field name -> description including the unit, e.g. ``{"position_m": "Rod extension [m]"}``.
        Dotted names (``"force.x"``) become nested types named after the path
        (``pkg/msg/NameForce``). Names follow ROS 2: ``[a-z][a-z0-9_]*``.

    Returns
    -------
    MsgType
        Every field a ``float64`` (NaN and ±inf are stored as they are), the description as
        the field's comment.
    """
    if not fields:
        raise ValueError(f"`fields` of schema {name!r} must not be empty")
    name = _ros_type_name(name)
    tree: dict[str, Any] = {}
    for field_name, description in fields.items():
        if not isinstance(description, str):
            raise TypeError(f"description of field {field_name!r} must be str, got {description!r}")
        parts = _split_field(field_name)
        if parts[0] == "timestamp":
            raise ValueError("field 'timestamp' is added by the writer; do not declare it")
        node = tree
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"field {field_name!r} conflicts with another field of schema {name!r}")
        if parts[-1] in node:
            raise ValueError(f"field {field_name!r} is declared twice or conflicts in schema {name!r}")
        node[parts[-1]] = description
    return _tree_type(name, tree, top=True)


def _ros_type_name(name: str) -> str:
    """``"pkg.Name"`` (a JSON schema name of earlier logs) as ``"pkg_msgs/msg/Name"``; other names unchanged."""
    match = re.fullmatch(r"([a-z][a-z0-9_]*)\.([A-Z][A-Za-z0-9]*)", name)
    return f"{match.group(1)}_msgs/msg/{match.group(2)}" if match else name


def _tree_type(name: str, tree: Mapping[str, Any], *, top: bool = False) -> MsgType:
    fields = [MsgField("timestamp", TIME, comment="simulation time of the sample")] if top else []
    for key, node in tree.items():
        if isinstance(node, str):
            fields.append(MsgField(key, "float64", comment=node))
        else:
            nested = name + "".join(part.capitalize() for part in key.split("_"))
            fields.append(MsgField(key, _tree_type(nested, node)))
    return MsgType(name, tuple(fields))


def ros2msg_type(schema_name: str, text: str) -> MsgType:
    """Parse a ``ros2msg`` schema text (as written by :meth:`MsgType.definition` or rosbag2) into a :class:`MsgType`.

    Comments and constants are skipped; ``builtin_interfaces/Time`` and ``Duration`` are known
    without a definition; a bare type name refers to the package of the message using it.
    """
    bodies: dict[str, list[tuple[str, str]]] = {}
    current = _short_type_name(schema_name, "")
    for section in re.split(r"^={3,}\s*$", text, flags=re.MULTILINE):
        lines = []
        for raw in section.splitlines():
            header = re.match(r"^MSG:\s+(\S+)\s*$", raw)
            if header:
                current = _short_type_name(header.group(1), "")
                continue
            line = raw.split("#", 1)[0].strip()
            parts = line.split()
            if len(parts) < 2 or "=" in parts[1] or (len(parts) > 2 and parts[2].startswith("=")):
                continue  # empty, or a constant
            lines.append((parts[0], parts[1]))
        bodies.setdefault(current, lines)
    bodies.setdefault("builtin_interfaces/Time", [("int32", "sec"), ("uint32", "nanosec")])
    bodies.setdefault("builtin_interfaces/Duration", [("int32", "sec"), ("uint32", "nanosec")])
    built: dict[str, MsgType] = {}

    def build(short: str) -> MsgType:
        if short not in built:
            if short not in bodies:
                raise ValueError(f"schema {schema_name!r}: no definition of {short!r}")
            package = short.split("/")[0]
            fields = []
            for type_text, field_name in bodies[short]:
                base, length = _array_suffix(type_text)
                base = re.sub(r"<=\d+$", "", base)  # bounded string
                if base in _PRIMITIVES or base in ("string", "wstring"):
                    field_type: str | MsgType = "string" if base == "wstring" else base
                else:
                    field_type = build(_short_type_name(base, package))
                fields.append(MsgField(field_name, field_type, length))
            pkg, name = short.split("/")
            built[short] = MsgType(f"{pkg}/msg/{name}", tuple(fields))
        return built[short]

    return build(_short_type_name(schema_name, ""))


def _short_type_name(name: str, package: str) -> str:
    if "/" not in name:
        name = f"{package}/{name}"
    match = _ROS_TYPE_NAME.fullmatch(name)
    if not match:
        raise ValueError(f"invalid ROS 2 type name {name!r}")
    return f"{match.group(1)}/{match.group(2)}"


def _array_suffix(type_text: str) -> tuple[str, int | None]:
    match = re.fullmatch(r"(.+?)\[(<=)?(\d*)\]", type_text)
    if not match:
        return type_text, None
    bounded_or_open = match.group(2) or not match.group(3)
    return match.group(1), 0 if bounded_or_open else int(match.group(3))


@dataclass(frozen=True)
class Column:
    """Placeholder for column ``index`` of a sample in a channel ``layout`` (a float64 field)."""

    index: int


class _TimestampSlot:
    """Placeholder for a ``builtin_interfaces/Time`` field holding the sample's log time."""

    def __repr__(self) -> str:
        return "TIMESTAMP"


TIMESTAMP = _TimestampSlot()
"""Placeholder for the sample timestamp inside a channel ``layout`` (nested timestamps)."""


def _align(out: bytearray, size: int) -> None:
    out.extend(bytes(-(len(out) - _CDR_BASE) % size))


def _cdr_put(t: MsgType, value: Any, out: bytearray, slots: list | None) -> None:
    """Append message ``value`` (a mapping; missing fields: NaN, 0, "" or empty) of type ``t`` to ``out``.

    With ``slots`` (a list), :class:`Column` and :data:`TIMESTAMP` placeholders are allowed at
    float64 and Time fields: they are written as zeros and ``("f8", offset, column)`` or
    ``("time", offset)`` is appended to ``slots`` (offsets from the message start).
    """
    if not isinstance(value, Mapping):
        raise TypeError(f"{t.name}: expected a mapping, got {value!r}")
    unknown = set(value) - {f.name for f in t.fields}
    if unknown:
        raise ValueError(f"{t.name} has no field(s) {sorted(unknown)}")
    for field in t.fields:
        item = value.get(field.name)
        if field.length is None:
            _cdr_put_item(field.type, item, out, slots, f"{t.name}.{field.name}")
            continue
        items = [] if item is None else list(item)
        if field.length == 0:
            _align(out, 4)
            out.extend(struct.pack("<I", len(items)))
        elif len(items) not in (0, field.length):
            raise ValueError(f"{t.name}.{field.name}: {field.length} elements expected, got {len(items)}")
        elif not items:
            items = [None] * field.length
        for element in items:
            _cdr_put_item(field.type, element, out, slots, f"{t.name}.{field.name}")


def _cdr_put_item(t: str | MsgType, item: Any, out: bytearray, slots: list | None, where: str) -> None:
    if isinstance(t, MsgType):
        if item is TIMESTAMP:
            if t.name != TIME.name or slots is None:
                raise ValueError(f"{where}: TIMESTAMP only fills a builtin_interfaces/Time field of a layout")
            _align(out, 4)
            slots.append(("time", len(out)))
            out.extend(bytes(8))
        else:
            _cdr_put(t, {} if item is None else item, out, slots)
    elif t == "string":
        data = ("" if item is None else str(item)).encode()
        _align(out, 4)
        out.extend(struct.pack("<I", len(data) + 1) + data + b"\x00")
    else:
        fmt = _PRIMITIVES[t]
        size = struct.calcsize(fmt)
        _align(out, size)
        if isinstance(item, Column):
            if t != "float64" or slots is None:
                raise ValueError(f"{where}: a Column fills a float64 field of a layout, not {t}")
            if not isinstance(item.index, int) or item.index < 0:
                raise ValueError(f"Column index must be a non-negative int, got {item.index!r}")
            slots.append(("f8", len(out), item.index))
            item = 0.0
        elif item is None:
            item = math.nan if t.startswith("float") else 0
        out.extend(struct.pack(fmt, item))


def cdr_encode(t: MsgType, message: Mapping[str, Any]) -> bytes:
    """One message as CDR (with its encapsulation header); fields missing from ``message`` are NaN, 0, "" or empty."""
    out = bytearray(CDR_HEADER)
    _cdr_put(t, message, out, None)
    return bytes(out)


class _Leaf:
    """A numeric field found while decoding: its byte offset in the message and struct format."""

    __slots__ = ("offset", "fmt")

    def __init__(self, offset: int, fmt: str):
        self.offset, self.fmt = offset, fmt


def _cdr_get(t: MsgType, data: bytes, pos: int, leaves: bool) -> tuple[dict, int]:
    """Decode a message of type ``t`` at ``data[pos:]``; numeric values as :class:`_Leaf` when ``leaves``."""
    out: dict[str, Any] = {}
    for field in t.fields:
        if field.length is None:
            out[field.name], pos = _cdr_get_item(field.type, data, pos, leaves)
            continue
        count = field.length
        if count == 0:
            pos += -(pos - _CDR_BASE) % 4
            (count,) = struct.unpack_from("<I", data, pos)
            pos += 4
        items = []
        for _ in range(count):
            item, pos = _cdr_get_item(field.type, data, pos, leaves)
            items.append(item)
        out[field.name] = items
    return out, pos


def _cdr_get_item(t: str | MsgType, data: bytes, pos: int, leaves: bool) -> tuple[Any, int]:
    if isinstance(t, MsgType):
        return _cdr_get(t, data, pos, leaves)
    if t == "string":
        pos += -(pos - _CDR_BASE) % 4
        (size,) = struct.unpack_from("<I", data, pos)
        end = pos + 4 + size
        if size < 1 or end > len(data) or data[end - 1] != 0:
            raise ValueError(f"bad CDR string at byte {pos}")
        return bytes(data[pos + 4:end - 1]).decode(), end
    fmt = _PRIMITIVES[t]
    size = struct.calcsize(fmt)
    pos += -(pos - _CDR_BASE) % size
    if pos + size > len(data):
        raise ValueError("CDR message ends inside a field")
    if leaves:
        return _Leaf(pos, fmt), pos + size
    (value,) = struct.unpack_from(fmt, data, pos)
    return value, pos + size


def cdr_decode(t: MsgType, data: bytes) -> dict:
    """Decode one CDR message (little-endian encapsulation) of type ``t`` into plain Python values."""
    if bytes(data[:2]) != CDR_HEADER[:2]:
        raise ValueError(f"not a little-endian CDR message (header {bytes(data[:4]).hex()})")
    message, _ = _cdr_get(t, data, _CDR_BASE, False)
    return message


class _CdrTemplate:
    """A columnar channel's messages as one constant CDR message with float64 and timestamp slots.

    Attributes
    ----------
    template : ndarray of uint8
        The message with zeros in its slots (strings, counts, padding and constants in place).
    time_offsets : list of int
        Byte offsets of the ``builtin_interfaces/Time`` slots (the sample's log time).
    float_slots : list of (int, int)
        (byte offset, sample column) of every float64 slot, by offset.
    column_count : int
        Floats per sample (the largest column + 1).
    """

    def __init__(self, t: MsgType, layout: Mapping[str, Any]):
        out = bytearray(CDR_HEADER)
        slots: list = []
        _cdr_put(t, layout, out, slots)
        self.template = np.frombuffer(bytes(out), dtype=np.uint8)
        self.size = len(out)
        self.time_offsets = [s[1] for s in slots if s[0] == "time"]
        self.float_slots = sorted((s[1], s[2]) for s in slots if s[0] == "f8")
        self.column_count = max((c for _, c in self.float_slots), default=-1) + 1


@functools.lru_cache(maxsize=1024)
def _cdr_template(t: MsgType, key: _LayoutKey) -> _CdrTemplate:
    """The :class:`_CdrTemplate` of a type and layout (cached on the layout's repr: its arrays are only read)."""
    return _CdrTemplate(t, key.layout)


class _LayoutKey:
    """Wraps a layout so that the template cache hashes and compares it by its repr (layouts hold dicts)."""

    __slots__ = ("layout", "key")

    def __init__(self, layout: Any):
        self.layout, self.key = layout, repr(layout)

    def __hash__(self) -> int:
        return hash(self.key)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _LayoutKey) and other.key == self.key


@functools.lru_cache(maxsize=1024)
def _fields_template(t: MsgType, fields: tuple[str, ...]) -> _CdrTemplate:
    """The :class:`_CdrTemplate` of a flat channel (cached on the field names: no layout to print)."""
    return _CdrTemplate(t, _fields_layout(fields))


@functools.lru_cache(maxsize=256)
def _definition_bytes(t: MsgType) -> bytes:
    """UTF-8 ``ros2msg`` schema text of a type (cached: every run registers the same types)."""
    return t.definition().encode()


def _fields_layout(fields: Sequence[str]) -> dict:
    """Layout of a flat channel: ``timestamp`` then field i (dotted: nested) from column i."""
    layout: dict[str, Any] = {"timestamp": TIMESTAMP}
    for index, field_name in enumerate(fields):
        parts = _split_field(field_name)
        if parts[0] == "timestamp":
            raise ValueError("field 'timestamp' is added by the writer; do not declare it")
        node = layout
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"field {field_name!r} conflicts with another field")
        if parts[-1] in node:
            raise ValueError(f"field {field_name!r} is declared twice or conflicts with another field")
        node[parts[-1]] = Column(index)
    return layout

def _split_field(field_name: str) -> list[str]:
    parts = field_name.split(".")
    if not field_name or any(not p for p in parts):
        raise ValueError(f"invalid field name {field_name!r}")
    return parts
