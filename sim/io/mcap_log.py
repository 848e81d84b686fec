"""MCAP logging of simulation runs: ROS 2 CDR for the numeric topics, JSON for the irregular ones, zstd chunks, all indexes.

Two kinds of channels, both read by Foxglove natively:

- **CDR channels** (:meth:`LogWriter.cdr_channel`, :meth:`Frame.channel`) carry the numeric,
  fixed-layout topics as ROS 2 messages, as rosbag2 writes them: schema encoding
  ``ros2msg`` (the ``.msg`` text of a :class:`MsgType`, nested types appended as
  ``MSG: pkg/Name`` sections), message encoding ``cdr`` (the little-endian encapsulation
  header ``00 01 00 00``, then the fields in order, each primitive aligned to its size
  from the end of the header, strings and sequences with a uint32 count first). Flat
  topics are ``builtin_interfaces/Time timestamp`` plus float64 fields (:func:`flat_schema`;
  dotted field names become nested types); joint states are
  ``foxglove_msgs/msg/JointStates`` and body poses ``foxglove_msgs/msg/FrameTransforms``,
  the ROS 2 forms of the Foxglove schemas, with the same field names as the JSON ones.
- **JSON channels** (:meth:`LogWriter.channel`) with JSON Schema carry irregular messages
  (events, the scene update), written one by one with :meth:`Channel.write`.

The writer is built for a stepping loop. Samples are appended into numpy buffers
(:meth:`Channel.append`, or one row per sample for many topics with :class:`Frame`, a few
hundred ns) and encoded in batches, outside the loop body: the MCAP Message records of one
sample of every topic of a frame are one constant byte row (record headers, CDR templates
with their strings and padding) with slots, and a batch of samples is that row repeated and
its slots (sequences, log times, timestamps, float64 fields) filled row by row in one
compiled pass (:class:`_RecordRows`, numba). Batches of all channels are merged in log-time
order, sample by sample, and handed whole to the chunks of :class:`sim.io.mcap_file.ChunkedWriter`
(:meth:`~sim.io.mcap_file.ChunkedWriter.add_records`), so every file is globally ordered by
``log_time``. Chunks are compressed with zstd at level -2 and written, in order, by one
background thread (``chunk_thread``), while the caller goes on stepping.

:func:`read_log` reads both kinds back as numpy columns with the field names of the
messages (``"p_cap_pa"``, ``"pressure_pa.supply"``, ``"position/<joint>"``,
``"translation.x/<frame>"``, ``"timestamp.nanosec"``); a CDR topic whose messages share
one layout is read as strided views of the message bytes (bit-exact floats).

Conventions:

- ``log_time = publish_time`` is *simulation* time in integer nanoseconds computed from
  the integer step index, never from an accumulated float time (:func:`step_log_time`).
- Every sample carries a ``timestamp`` equal to its log time (``{sec, nanosec}`` in CDR,
  ``{sec, nsec}`` in JSON).
- NaN and ±inf are stored as they are in CDR (float64); JSON is strict: non-finite floats
  are written as ``null`` and read back as NaN.
- The file is written to ``PATH.partial``, created exclusively (two writers never share
  it; an existing one is never replaced unless asked), and published as ``PATH`` when it
  is finished, also when the ``with`` block raises; an existing ``PATH`` is replaced only
  with ``overwrite=True``. A file cut by SIGKILL or damaged can be rebuilt with
  :func:`recover`, which skips damaged chunks and keeps the others.

This module does not import MuJoCo; see :mod:`sim.io.foxglove_scene` for the model-specific
channels.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import heapq
import json
import math
import os
import re
import signal
import struct
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numba
import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Schema as McapSchema
from mcap.writer import CompressionType, Writer

from sim.io.log_recover import RecoverReport, recover, verify_log
from sim.io.mcap_file import (DEFAULT_CHUNK_SIZE, MCAP_MAGIC, MESSAGE_RECORD, NS_PER_S, PARTIAL_SUFFIX, RESULT_METADATA,
                              RUN_METADATA, ChunkedWriter, LogPathError, LogReadError, RecordStream, RunStatus,
                              library_string, publish, refuse_special)

__all__ = [
    "Attachment",
    "Channel",
    "Column",
    "FOXGLOVE_SCHEMAS",
    "FRAME_TRANSFORMS",
    "Frame",
    "JOINT_STATES",
    "JointStatesChannel",
    "LogLevel",
    "LogPathError",
    "LogReadError",
    "LogWriter",
    "MsgField",
    "MsgType",
    "RecoverReport",
    "RESULT_METADATA",
    "RUN_METADATA",
    "RunLog",
    "RunStatus",
    "TIME",
    "TIMESTAMP",
    "TopicData",
    "cdr_decode",
    "cdr_encode",
    "flat_schema",
    "inspect_log",
    "library_string",
    "log_info",
    "log_message",
    "log_schema",
    "merge_logs",
    "read_log",
    "recover",
    "ros2msg_type",
    "scene_update_schema",
    "step_log_time",
    "to_json_bytes",
]

# sim time between forced chunk ends [s]: at the default 100 Hz a sample is ≈ 2 kB, so a 512 KiB chunk fills in ≈ 2.6 s
# and a 2 s flush ends about one chunk early; each flush costs a batch derive and encode and a chunk end (≈ 1.5 ms
# on the excavator at 100 Hz), whatever the chunk holds
DEFAULT_FLUSH_INTERVAL = 2.0
DEFAULT_BATCH_SIZE = 1024  # buffered samples per channel before a batch encode
FRAME_ID_KEYS = ("frame_id", "parent_frame_id", "child_frame_id")  # rewritten by merge_logs
_PREFIX_PATTERN = re.compile(r"[A-Za-z0-9_.\-]+")


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


# ---------------------------------------------------------------------------------------
# MCAP Message records of many samples at once
# ---------------------------------------------------------------------------------------

_MESSAGE_RECORD = MESSAGE_RECORD
_MESSAGE_RECORD_OVERHEAD = _MESSAGE_RECORD.size  # 31 B before the message data


def _split_field(field_name: str) -> list[str]:
    parts = field_name.split(".")
    if not field_name or any(not p for p in parts):
        raise ValueError(f"invalid field name {field_name!r}")
    return parts


@dataclass(frozen=True)
class _RecordBlock:
    """Complete MCAP Message records of ``n`` units (samples), one row each, in log-time order.

    Row r holds one record per member channel (``channel_ids[i]`` at byte ``offsets[i]`` of
    the row), all at ``log_times[r]`` [ns]. ``order`` (channel order) and ``serial``
    (creation order) break ties between blocks at equal log times.
    """

    log_times: np.ndarray
    rows: np.ndarray
    channel_ids: np.ndarray
    offsets: np.ndarray
    order: int
    serial: int


class _RecordRows:
    """The Message records of one sample of several CDR channels as one constant row with slots.

    Parameters
    ----------
    members : list of (channel id, :class:`_CdrTemplate`, columns)
        ``columns`` maps a channel's column j to column ``columns[j]`` of the sample rows
        given to :meth:`encode` (an index array or a slice).
    """

    def __init__(self, members: Sequence[tuple[int, _CdrTemplate, np.ndarray | slice]]):
        template = bytearray()
        self.channel_ids = np.array([m[0] for m in members], dtype=np.int64)
        offsets, sequence_offsets, time_offsets, log_time_offsets, float_offsets, float_columns = [], [], [], [], [], []
        for channel_id, cdr, columns in members:
            start = len(template)
            offsets.append(start)
            template += _MESSAGE_RECORD.pack(0x05, _MESSAGE_RECORD_OVERHEAD - 9 + cdr.size, channel_id, 0, 0, 0)
            template += cdr.template.tobytes()
            sequence_offsets.append(start + 11)
            log_time_offsets += [start + 15, start + 23]  # log time, publish time (= log time)
            data = start + _MESSAGE_RECORD_OVERHEAD
            time_offsets += [data + offset for offset in cdr.time_offsets]
            sample_columns = np.arange(columns.start, columns.stop) if isinstance(columns, slice) else np.asarray(columns)
            float_offsets += [data + offset for offset, _ in cdr.float_slots]
            float_columns += [int(sample_columns[column]) for _, column in cdr.float_slots]
        self.offsets = np.array(offsets, dtype=np.int64)
        self.template = np.frombuffer(bytes(template), dtype=np.uint8)
        self.size = len(template)
        self._slots = tuple(np.array(a, dtype=np.int64) for a in (time_offsets, log_time_offsets, sequence_offsets,
                                                                   float_offsets, float_columns))

    def encode(self, values: np.ndarray, log_times: np.ndarray, first_sequences: Sequence[int]) -> np.ndarray:
        """Records of every row of ``values`` (float64 samples) at ``log_times`` (int64 [ns]); member i's
        sequence numbers start at ``first_sequences[i]``. Returns uint8, shape (rows, size)."""
        out = np.empty((len(values), self.size), dtype=np.uint8)
        out[:] = self.template  # (numpy's broadcast copy: a byte loop in the compiled pass was half its time)
        bits = np.ascontiguousarray(values, dtype=np.float64).view(np.uint64)
        _fill_records(out, bits, np.asarray(log_times, dtype=np.int64),
                      np.asarray(first_sequences, dtype=np.int64), *self._slots)
        return out


@numba.njit(cache=True, nogil=True)
def _put_le(row, offset, value, size):
    """``value`` (an unsigned integer) as ``size`` little-endian bytes at ``row[offset:]``."""
    for i in range(size):
        row[offset + i] = (value >> np.uint64(8 * i)) & np.uint64(0xFF)


@numba.njit(cache=True, nogil=True)
def _fill_records(out, bits, log_times, first_sequences, time_offsets, log_time_offsets, sequence_offsets,
                  float_offsets, float_columns):
    """Row r of ``out`` (a copy of the template): sample r's slots filled (timestamps, log times, sequences, float64
    bits).

    One pass per row, the row in cache while its ~200 slots are written (a column-wise numpy
    fill passes over a second of 1 kHz samples, 2 MB, once per slot run: 5x slower in a run).
    """
    for r in range(out.shape[0]):
        row = out[r]
        t = np.uint64(log_times[r])
        sec, nsec = t // np.uint64(1_000_000_000), t % np.uint64(1_000_000_000)
        for offset in time_offsets:
            _put_le(row, offset, sec, 4)
            _put_le(row, offset + 4, nsec, 4)
        for offset in log_time_offsets:
            _put_le(row, offset, t, 8)
        for m in range(sequence_offsets.size):
            _put_le(row, sequence_offsets[m], np.uint64(first_sequences[m] + r), 4)
        sample = bits[r]
        for k in range(float_offsets.size):
            _put_le(row, float_offsets[k], sample[float_columns[k]], 8)


def _as_slice(columns: np.ndarray) -> np.ndarray | slice:
    """``columns`` as a slice when they are consecutive (a view instead of a gather)."""
    columns = np.asarray(columns, dtype=np.intp)
    if len(columns) and np.array_equal(columns, np.arange(columns[0], columns[0] + len(columns))):
        return slice(int(columns[0]), int(columns[0]) + len(columns))
    return columns


def _message_record(channel_id: int, sequence: int, log_time: int, data: bytes) -> np.ndarray:
    """One Message record (publish time = log time) as uint8."""
    header = _MESSAGE_RECORD.pack(0x05, _MESSAGE_RECORD_OVERHEAD - 9 + len(data), channel_id, sequence, log_time, log_time)
    return np.frombuffer(header + data, dtype=np.uint8)


def _merge_blocks(blocks: Sequence[_RecordBlock]) -> RecordStream:
    """One record stream of ``blocks``, units ordered by (log time, channel order, block serial, row)."""
    counts = [len(b.log_times) for b in blocks]
    if len(blocks) == 1:  # (the usual drain: one frame's samples) already in order
        rows = blocks[0].rows
        data, unit_times = rows.reshape(-1), blocks[0].log_times
        unit_ends = np.arange(1, counts[0] + 1, dtype=np.int64) * rows.shape[1]
        positions = [np.arange(counts[0], dtype=np.int64)]
    else:
        times = np.concatenate([b.log_times for b in blocks])
        block_of = np.repeat(np.arange(len(blocks)), counts)
        row = np.concatenate([np.arange(c, dtype=np.int64) for c in counts])
        perm = np.lexsort((row, np.array([b.serial for b in blocks])[block_of],
                           np.array([b.order for b in blocks])[block_of], times))
        block_sorted, row_sorted = block_of[perm], row[perm]
        breaks = np.flatnonzero((np.diff(block_sorted) != 0) | (np.diff(row_sorted) != 1)) + 1
        runs = zip(np.concatenate(([0], breaks)).tolist(), np.concatenate((breaks, [len(perm)])).tolist())
        rows_of, first_row = [b.rows for b in blocks], row_sorted.tolist()
        block_list = block_sorted.tolist()
        pieces = [rows_of[block_list[s]][first_row[s]:first_row[e - 1] + 1].reshape(-1) for s, e in runs]
        # one contiguous copy (interleaved blocks, e.g. a frame's /tf every 10th sample, make a run per sample: one
        # memcpy is cheaper than a write per run)
        data = np.concatenate(pieces) if len(pieces) > 1 else pieces[0]
        unit_ends = np.cumsum(np.array([b.rows.shape[1] for b in blocks], dtype=np.int64)[block_sorted])
        unit_times = times[perm]
        position_of = np.empty(len(perm), dtype=np.int64)
        position_of[perm] = np.arange(len(perm))
        positions = np.split(position_of, np.cumsum(counts)[:-1])
    messages = [(where, b.channel_ids, (unit_ends[where] - b.rows.shape[1])[:, None] + b.offsets[None, :])
                for b, where in zip(blocks, positions)]
    return RecordStream(data, unit_ends, unit_times, messages)


# ---------------------------------------------------------------------------------------
# Writer
# ---------------------------------------------------------------------------------------


class _DeferredSigint:
    """Hold back SIGINT (Ctrl-C) while the MCAP writer is mid-record.

    A batch is merged, added to the chunk in progress and its message indexes extended in
    several Python steps, so a ``KeyboardInterrupt`` among them would leave the chunk and its
    indexes out of step. Inside this context a SIGINT is recorded and the previous handler is called on
    exit. The handler is swapped only in the main thread and only when the current one was
    installed from Python; it is always restored.
    """

    def __enter__(self) -> _DeferredSigint:
        self._previous: Any = None
        self._received: tuple[int, Any] | None = None
        if threading.current_thread() is threading.main_thread():
            current = signal.getsignal(signal.SIGINT)
            if current is not None:
                self._previous = current
                signal.signal(signal.SIGINT, self._record)
        return self

    def _record(self, signum: int, frame: Any) -> None:
        self._received = (signum, frame)

    def __exit__(self, *exc_info: Any) -> None:
        if self._previous is None:
            return
        signal.signal(signal.SIGINT, self._previous)
        if self._received is None:
            return
        if callable(self._previous):
            self._previous(*self._received)  # default_int_handler raises KeyboardInterrupt here
        elif self._previous == signal.SIG_DFL:
            signal.raise_signal(signal.SIGINT)


@dataclass(frozen=True)
class Attachment:
    """A file embedded in the log.

    Attributes
    ----------
    name : str
        Attachment name, e.g. ``"model.xml"``.
    media_type : str
        MIME type, e.g. ``"application/xml"``.
    data : bytes
        Content.
    """

    name: str
    media_type: str
    data: bytes


def _str_dict(name: str, values: Mapping[str, Any] | None) -> dict[str, str]:
    out: dict[str, str] = {}
    for key, value in (values or {}).items():
        if not isinstance(key, str) or not isinstance(value, str):
            raise TypeError(f"`{name}` keys and values must be str, got {key!r}: {value!r}")
        out[key] = value
    return out


class Channel:
    """One MCAP channel of a :class:`LogWriter`; create it with :meth:`LogWriter.channel` (JSON)
    or :meth:`LogWriter.cdr_channel` (ROS 2 CDR).

    A CDR channel is *columnar*: :meth:`append` stores a sample of ``column_count`` floats
    in a numpy buffer and the CDR messages are produced later in batches. Any channel
    accepts irregular messages through :meth:`write`.

    Attributes
    ----------
    topic : str
        Channel topic.
    schema_name : str
        Name of the channel's schema (JSON Schema title, or ROS 2 type ``pkg/msg/Name``).
    msg_type : MsgType or None
        Message type of a CDR channel (None for JSON).
    column_count : int
        Floats per sample for :meth:`append` (0 for a JSON channel).
    """

    def __init__(self, writer: LogWriter, channel_id: int, order: int, topic: str, schema_name: str,
                 msg_type: MsgType | None, template: _CdrTemplate | None, capacity: int):
        self.topic = topic
        self.schema_name = schema_name
        self.msg_type = msg_type
        self.column_count = template.column_count if template is not None else 0
        column_count = self.column_count
        self._writer = writer
        self._channel_id = channel_id
        self._order = order
        self._template = template
        self._records: _RecordRows | None = None  # its own samples' records, built at their first encode
        self._capacity = capacity if template is not None else 0
        self._values = np.empty((self._capacity, column_count), dtype=np.float64)
        self._steps = np.empty(self._capacity, dtype=np.int64)
        self._count = 0
        self._last_step = -1
        self._sequence = 0
        self._encoded: list[_RecordBlock] = []
        self._frame: Frame | None = None  # set for the channels of a Frame (their samples live there)

    def append(self, step_index: int, values: Sequence[float] | np.ndarray) -> None:
        """Buffer one sample of a columnar channel.

        Parameters
        ----------
        step_index : int
            Physics step of the sample; non-decreasing per channel.
        values : sequence of float or ndarray, shape (column_count,)
            Field values in the order of the channel's ``fields`` (SI units); NaN and inf
            are stored as they are (float64).
        """
        n = self._count
        if n == self._capacity or step_index >= self._writer._next_flush_step:
            n = self._prepare(step_index)
        if step_index < self._last_step:
            raise ValueError(f"{self.topic}: step_index {step_index} is before the previous one {self._last_step}")
        self._values[n] = values
        self._steps[n] = step_index
        self._last_step = step_index
        self._count = n + 1

    def claim(self, step_index: int) -> np.ndarray:
        """Return the buffer row for a sample at ``step_index``, to be filled in place.

        The row becomes part of the log only after :meth:`commit`; claiming again
        without a commit returns the same row. This is the zero-copy form of
        :meth:`append` for callers that assemble a sample from several arrays.

        Parameters
        ----------
        step_index : int
            Physics step of the sample; non-decreasing per channel.

        Returns
        -------
        ndarray, shape (column_count,)
            Writable view of the next buffer row.
        """
        n = self._count
        if n == self._capacity or step_index >= self._writer._next_flush_step:
            n = self._prepare(step_index)
        if step_index < self._last_step:
            raise ValueError(f"{self.topic}: step_index {step_index} is before the previous one {self._last_step}")
        self._steps[n] = step_index
        return self._values[n]

    def commit(self) -> None:
        """Accept the row returned by the last :meth:`claim`."""
        n = self._count
        self._last_step = int(self._steps[n])
        self._count = n + 1

    def write(self, step_index: int, message: Mapping[str, Any]) -> None:
        """Log one irregular message (event, scene update, ...).

        Parameters
        ----------
        step_index : int
            Physics step the message belongs to; non-decreasing per channel.
        message : Mapping[str, Any]
            Body. On a JSON channel a ``timestamp {sec, nsec}`` equal to the log time is put
            first unless present and non-finite floats become ``null``; on a CDR channel the
            fields of its :class:`MsgType` (missing ones NaN, 0, "" or empty; a missing
            top-level ``timestamp`` is the log time). The caller's object is not modified.
        """
        writer = self._writer
        writer._check_open()
        if self._frame is not None:
            raise TypeError(f"{self.topic}: a channel of a Frame takes its samples from Frame.append(); use another channel")
        if step_index < self._last_step:
            raise ValueError(f"{self.topic}: step_index {step_index} is before the previous one {self._last_step}")
        if step_index >= writer._next_flush_step:
            writer._periodic_flush(step_index)
        log_time = writer.log_time(step_index)
        body = dict(message)
        if self.msg_type is None:
            if "timestamp" not in body:
                body = {"timestamp": _timestamp(log_time), **body}
            data = to_json_bytes(body)
        else:
            if "timestamp" not in body and any(f.name == "timestamp" and f.type == TIME for f in self.msg_type.fields):
                sec, nsec = divmod(log_time, NS_PER_S)
                body["timestamp"] = {"sec": sec, "nanosec": nsec}
            data = cdr_encode(self.msg_type, body)
        self._encode_buffer()  # keep buffered samples ahead of this message
        self._sequence += 1
        record = _message_record(self._channel_id, self._sequence, log_time, data)
        self._encoded.append(_RecordBlock(np.array([log_time], np.int64), record.reshape(1, -1),
                                          np.array([self._channel_id], np.int64), np.zeros(1, np.int64), self._order,
                                          writer._next_serial()))
        self._last_step = step_index

    # -- internals -------------------------------------------------------------------

    def _prepare(self, step_index: int) -> int:
        """Flush before a new sample when the buffer is full or a periodic flush is due."""
        writer = self._writer
        writer._check_open()
        if self._template is None:
            raise TypeError(f"{self.topic}: a JSON channel takes irregular messages; use write()")
        if self._frame is not None:
            raise TypeError(f"{self.topic}: a channel of a Frame takes its samples from Frame.append()")
        if step_index >= writer._next_flush_step:
            writer._periodic_flush(step_index)
        if self._count == self._capacity:
            writer._drain(end_chunk=False)
        return self._count

    def _encode_buffer(self) -> None:
        """Encode buffered samples into Message records (one block of the channel's encoded list)."""
        n = self._count
        if n == 0:
            return
        log_times = _step_log_times(self._steps[:n], self._writer.dt)
        if self._records is None:
            self._records = _RecordRows([(self._channel_id, self._template, slice(0, self.column_count))])
        rows = self._records.encode(self._values[:n], log_times, [self._sequence + 1])
        self._sequence += n
        self._encoded.append(_RecordBlock(log_times, rows, self._records.channel_ids, self._records.offsets, self._order,
                                          self._writer._next_serial()))
        self._count = 0

    def _take_encoded(self) -> list[_RecordBlock]:
        """Encoded record blocks, buffered samples included."""
        self._encode_buffer()
        encoded, self._encoded = self._encoded, []
        return encoded


class JointStatesChannel(Channel):
    """Columnar ``foxglove.JointStates`` channel; create it with :meth:`LogWriter.joint_states_channel`.

    Attributes
    ----------
    joint_names : tuple of str
        Joint names, fixed at creation.
    """

    def __init__(self, *args: Any, joint_names: tuple[str, ...], **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.joint_names = joint_names

    def append(self, step_index: int, position: Sequence[float] | np.ndarray,  # type: ignore[override]
               velocity: Sequence[float] | np.ndarray | None = None,
               effort: Sequence[float] | np.ndarray | None = None) -> None:
        """Buffer the joint states of one step.

        Parameters
        ----------
        step_index : int
            Physics step of the sample.
        position : array_like, shape (joint_count,)
            Joint positions [rad] or [m].
        velocity : array_like, shape (joint_count,), optional
            Joint velocities [rad/s] or [m/s]; NaN (not set) when omitted.
        effort : array_like, shape (joint_count,), optional
            Joint efforts [N·m] or [N]; NaN (not set) when omitted.
        """
        joint_count = len(self.joint_names)
        row = self.claim(step_index)
        row[:joint_count] = position
        row[joint_count:2 * joint_count] = np.nan if velocity is None else velocity
        row[2 * joint_count:] = np.nan if effort is None else effort
        self.commit()


def _check_every(topic: str, every: Any) -> None:
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise ValueError(f"{topic}: `every` must be an integer >= 1 (steps), got {every!r}")


class Frame:
    """One row of floats per sample that feeds several columnar channels; create it with :meth:`LogWriter.frame`.

    A loop that logs many topics per step pays one :meth:`append` (or :meth:`claim` +
    :meth:`commit`) per sample instead of one per topic.  Each channel of the frame names
    the frame columns its fields come from (:meth:`channel`, :meth:`joint_states_channel`);
    in the log they are ordinary channels, encoded from the frame's rows in the same
    batches.  Columns no channel reads, and columns never written, cost nothing; the rows
    start as NaN, so a column that is never written is logged as NaN.  A channel joined
    with ``every=k`` takes only the rows whose step index is a multiple of ``k`` (e.g.
    Foxglove's ``/tf`` at a display rate while the data topics take every sample); a row
    is still committed whole, so an interrupt never splits a sample.

    Attributes
    ----------
    column_count : int
        Floats per row.
    """

    def __init__(self, writer: LogWriter, column_count: int, capacity: int):
        self.column_count = int(column_count)
        if self.column_count < 1:
            raise ValueError(f"`column_count` must be >= 1, got {column_count!r}")
        self._writer = writer
        self._capacity = capacity
        self._values = np.full((capacity, self.column_count), np.nan)
        self._steps = np.empty(capacity, dtype=np.int64)
        self._count = 0
        self._last_step = -1
        self._members: list[tuple[Channel, np.ndarray | slice, int]] = []  # (channel, columns, every)
        self._records: dict[tuple[int, ...], _RecordRows] = {}  # per set of members fed together, their records
        self._encoded: list[_RecordBlock] = []

    def _columns(self, columns: Sequence[int] | np.ndarray, count: int, topic: str) -> np.ndarray:
        columns = np.asarray(columns, dtype=np.intp).ravel()
        if len(columns) != count:
            raise ValueError(f"{topic}: {len(columns)} frame columns given for {count} fields")
        if len(columns) and (columns.min() < 0 or columns.max() >= self.column_count):
            raise ValueError(f"{topic}: frame columns must be in [0, {self.column_count}), got {columns.tolist()}")
        return columns

    def channel(self, topic: str, msg_type: MsgType, *, columns: Sequence[int] | np.ndarray,
                fields: Sequence[str] | None = None, layout: Mapping[str, Any] | None = None,
                metadata: Mapping[str, str] | None = None, every: int = 1) -> Channel:
        """Register a CDR channel (as :meth:`LogWriter.cdr_channel`) whose column i is frame column ``columns[i]``,
        fed the rows at step indexes that are multiples of ``every``."""
        _check_every(topic, every)
        channel = self._writer.cdr_channel(topic, msg_type, fields=fields, layout=layout, metadata=metadata)
        self._adopt(channel, columns, every)
        return channel

    def joint_states_channel(self, topic: str, joint_names: Sequence[str], *, columns: Sequence[int] | np.ndarray,
                             metadata: Mapping[str, str] | None = None, every: int = 1) -> JointStatesChannel:
        """A ``foxglove_msgs/msg/JointStates`` channel (as :meth:`LogWriter.joint_states_channel`) from frame ``columns``:
        positions, then velocities, then efforts (3 × joint count); ``every`` as in :meth:`channel`."""
        _check_every(topic, every)
        channel = self._writer.joint_states_channel(topic, joint_names, metadata=metadata)
        self._adopt(channel, columns, every)
        return channel

    def adopt(self, channel: Channel, columns: Sequence[int] | np.ndarray, *, every: int = 1) -> None:
        """Make an existing columnar channel of this writer (with no samples yet) take its samples from ``columns``,
        at the rows whose step index is a multiple of ``every`` (≥ 1)."""
        if channel._writer is not self._writer or channel._template is None or channel._count or channel._encoded:
            raise ValueError(f"{channel.topic}: only an empty columnar channel of the same log can join a frame")
        _check_every(channel.topic, every)
        self._adopt(channel, columns, every)

    def _adopt(self, channel: Channel, columns: Sequence[int] | np.ndarray, every: int) -> None:
        channel._frame = self
        channel._capacity = 0  # its own append() now always reaches _prepare(), which refuses
        columns = self._columns(columns, channel.column_count, channel.topic)
        if self._count:
            self._encode()  # rows buffered so far belong to the members they were buffered for
        self._members.append((channel, _as_slice(columns), int(every)))
        self._records = {}

    def append(self, step_index: int, values: Sequence[float] | np.ndarray) -> None:
        """Buffer one row (``column_count`` floats, SI units) for step ``step_index`` (non-decreasing)."""
        self.claim(step_index)[:] = values
        self.commit()

    def claim(self, step_index: int) -> np.ndarray:
        """The buffer row for a sample at ``step_index``, to be filled in place, then :meth:`commit`.

        The row holds what an earlier sample left in it (NaN at first): write every column a channel reads.
        """
        writer = self._writer
        if self._count == self._capacity or step_index >= writer._next_flush_step:
            writer._check_open()
            if step_index >= writer._next_flush_step:
                writer._periodic_flush(step_index)
            if self._count == self._capacity:
                writer._drain(end_chunk=False)
        if step_index < self._last_step:
            raise ValueError(f"frame: step_index {step_index} is before the previous one {self._last_step}")
        self._steps[self._count] = step_index
        return self._values[self._count]

    def commit(self) -> None:
        """Accept the row returned by the last :meth:`claim`."""
        self._last_step = int(self._steps[self._count])
        self._count += 1

    def extend(self, step_index: Sequence[int] | np.ndarray, values: np.ndarray) -> None:
        """Buffer many rows at once: row i of ``values`` (shape (rows, column_count), SI) for step ``step_index[i]``.

        The same as :meth:`append` row by row (periodic flushes and batch drains happen
        before the same rows), in a few array copies; a Ctrl-C is held back until every
        row is buffered, so a batch is never half in the log.
        """
        steps = np.asarray(step_index, dtype=np.int64).ravel()
        values = np.asarray(values, dtype=np.float64)
        k = len(steps)
        if values.shape != (k, self.column_count):
            raise ValueError(f"frame: `values` must have shape ({k}, {self.column_count}), got {values.shape}")
        if k == 0:
            return
        if steps[0] < self._last_step or (k > 1 and np.any(steps[1:] < steps[:-1])):
            raise ValueError(f"frame: step indexes must be non-decreasing and >= {self._last_step}")
        writer = self._writer
        with _DeferredSigint():
            i = 0
            while i < k:
                first = int(steps[i])
                if self._count == self._capacity or first >= writer._next_flush_step:
                    writer._check_open()
                    if first >= writer._next_flush_step:
                        writer._periodic_flush(first)
                    if self._count == self._capacity:
                        writer._drain(end_chunk=False)
                j = min(k, i + self._capacity - self._count)
                if math.isfinite(writer._next_flush_step):  # stop before the next periodic flush
                    j = min(j, i + int(np.searchsorted(steps[i:j], writer._next_flush_step, side="left")))
                j = max(j, i + 1)
                n = self._count
                self._values[n:n + j - i] = values[i:j]
                self._steps[n:n + j - i] = steps[i:j]
                self._count = n + j - i
                self._last_step = int(steps[j - 1])
                i = j

    def _encode(self) -> None:
        """Encode the buffered rows into record blocks: one of the members fed by every buffered row (those with
        ``every`` 1 or dividing every row's step, as /tf at the log rate) and one per other ``every``, of its
        members' messages at the rows at multiples of it; each channel is in one block, in log-time order."""
        n = self._count
        if n == 0 or not self._members:
            self._count = 0
            return
        steps = self._steps[:n]
        log_times = _step_log_times(steps, self._writer.dt)
        every_row: list[int] = []
        groups: list[tuple[tuple[int, ...], Any]] = []
        for every in sorted({k for _, _, k in self._members}):
            fed = [m for m, (_, _, k) in enumerate(self._members) if k == every]
            rows = np.flatnonzero(steps % every == 0) if every > 1 else None
            if rows is None or len(rows) == n:
                every_row += fed
            elif len(rows):
                groups.append((tuple(fed), rows))
        if every_row:
            groups.insert(0, (tuple(sorted(every_row)), slice(None)))
        for group, rows in groups:
            members = [self._members[m][:2] for m in group]
            records = self._records.get(group)
            if records is None:
                records = self._records[group] = _RecordRows([(c._channel_id, c._template, columns) for c, columns in members])
            times = log_times[rows]
            encoded = records.encode(self._values[:n][rows], times, [c._sequence + 1 for c, _ in members])
            last = int(steps[rows][-1])
            for channel, _ in members:
                channel._sequence += len(times)
                channel._last_step = last
            self._encoded.append(_RecordBlock(times, encoded, records.channel_ids, records.offsets,
                                              min(c._order for c, _ in members), self._writer._next_serial()))
        self._count = 0

    def _take_encoded(self) -> list[_RecordBlock]:
        """Encoded record blocks, buffered rows included."""
        self._encode()
        encoded, self._encoded = self._encoded, []
        return encoded


def _locked_by_other(partial: Path) -> bool:
    """Whether another writer holds ``partial`` (its exclusive lock); False where locks are not available."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return False
    try:
        fd = os.open(partial, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # (closing releases a lock taken here)
    return False


def _create_partial(path: Path, partial: Path, overwrite: bool) -> BinaryIO:
    """Create ``partial`` exclusively (``O_CREAT | O_EXCL``) and lock it; the checks of :class:`LogWriter`."""
    for target in (path, partial):
        refuse_special(target)
    if os.path.lexists(path) and not overwrite:
        raise LogPathError(f"{path} exists; pass --overwrite (overwrite=True) to replace it")
    if os.path.lexists(partial):
        if _locked_by_other(partial):
            raise LogPathError(f"{partial} is being written by another run; choose another output")
        if not overwrite:
            raise LogPathError(f"{partial} exists (left by an interrupted run): recover it with "
                               f"'hydroplant log recover {partial}', or pass --overwrite (overwrite=True) to replace it")
        partial.unlink()
    try:
        fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
    except FileExistsError:
        raise LogPathError(f"{partial} is being written by another run; choose another output") from None
    except OSError as error:
        raise LogPathError(f"{partial}: cannot create the log ({error.strerror or error})") from None
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        pass
    else:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # held until the file is closed
    return os.fdopen(fd, "wb")


class LogWriter:
    """Write a simulation run to an MCAP file.

    Parameters
    ----------
    path : str or Path
        Final file name. Data goes to ``path + ".partial"`` until :meth:`close` renames it.
    dt : float
        Physics time step [s]; log times are :func:`step_log_time` of the step index.
    run_metadata : Mapping[str, str], optional
        Written at once as the ``hydroplant.run`` metadata record (all values str). The
        writer adds ``dt_s`` and ``time_epoch``.
    attachments : iterable of Attachment or (name, media_type, bytes), optional
        Written at once, after the run metadata.
    chunk_size : int, optional
        Uncompressed bytes after which a chunk is compressed and written [B].
    flush_interval : float, optional
        Simulation time between forced flushes (encode all buffers, end the chunk, flush
        the file) [s]; ``math.inf`` disables it.
    batch_size : int, optional
        Samples buffered per columnar channel; when one channel is full all channels are
        encoded into the current chunk and the file object is flushed.
    compression : {"zstd", "lz4", "none"}, optional
        Chunk compression.
    overwrite : bool, optional
        Replace an existing regular file ``path``, and an existing ``path.partial`` that no
        other writer holds; otherwise :class:`LogPathError` (a ``CircuitError``) naming it.
        A ``path`` that exists and is not a regular file (folder, device, FIFO) is refused
        either way, as is a ``path.partial`` another writer is writing.
    chunk_thread : bool, optional
        Compress and write finished zstd chunks on a background thread (zstd, crc32, the
        file writes and MuJoCo's ``mj_step`` all release the GIL, so they overlap the
        stepping on a second core). The file is byte for byte the same either way;
        ``False`` does all the work in the caller's thread.

    Notes
    -----
    What a SIGKILL can lose is bounded by the larger of ``flush_interval`` of simulation
    time and ``chunk_size`` bytes of messages plus ``batch_size`` samples per channel,
    plus, with the chunk thread, the chunks handed to it and not yet written (at most
    ``ChunkedWriter.MAX_PENDING_CHUNKS``; a periodic flush does not wait for them, an
    explicit :meth:`flush` does); everything before is in complete chunks on disk and
    comes back with :func:`recover`. A write that fails on the chunk thread is raised by
    the next call that hands it work or waits for it (at the latest :meth:`close`, which
    then leaves the ``.partial``).
    Use the writer as a context manager: on an exception (``KeyboardInterrupt``
    included) the file is still finished, with ``status="incomplete"`` and the reason in
    the ``hydroplant.result`` record, and the exception propagates. A SIGINT arriving while
    a batch is being encoded and written is held back until the batch is complete, so a
    Ctrl-C never leaves a half-written record or a hole in the data. SIGTERM is not
    handled here; a runner that wants the same treatment can turn it into an exception.
    """

    def __init__(self, path: str | os.PathLike, *, dt: float, run_metadata: Mapping[str, str] | None = None,
                 attachments: Iterable[Attachment | tuple[str, str, bytes]] = (),
                 chunk_size: int = DEFAULT_CHUNK_SIZE, flush_interval: float = DEFAULT_FLUSH_INTERVAL,
                 batch_size: int = DEFAULT_BATCH_SIZE, compression: str = "zstd", overwrite: bool = False,
                 chunk_thread: bool = True):
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"`dt` must be positive and finite, got {dt!r} s")
        if not (flush_interval > 0):
            raise ValueError(f"`flush_interval` must be positive, got {flush_interval!r} s")
        if int(batch_size) < 1:
            raise ValueError(f"`batch_size` must be >= 1, got {batch_size!r}")
        if int(chunk_size) < 1:
            raise ValueError(f"`chunk_size` must be >= 1, got {chunk_size!r} B")
        if compression not in ("zstd", "lz4", "none"):
            raise ValueError(f"`compression` must be one of ['lz4', 'none', 'zstd'], got {compression!r}")
        metadata = _str_dict("run_metadata", run_metadata)
        own = {"dt_s": repr(dt), "time_epoch": "sim_time_from_zero"}
        for key, value in own.items():
            if metadata.setdefault(key, value) != value:
                raise ValueError(f"`run_metadata[{key!r}]` is set by the writer to {value!r}, got {metadata[key]!r}")
        files = [a if isinstance(a, Attachment) else Attachment(*a) for a in attachments]
        for attachment in files:
            if not isinstance(attachment.data, (bytes, bytearray)):
                raise TypeError(f"attachment {attachment.name!r} data must be bytes, got {type(attachment.data).__name__}")

        self.path = Path(path)
        self.partial_path = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.dt = dt
        self._batch_size = int(batch_size)
        if math.isinf(flush_interval):
            self._flush_steps = None
        else:
            self._flush_steps = max(1, round(flush_interval / dt))
        self._next_flush_step: float = self._flush_steps if self._flush_steps is not None else math.inf
        self._channels: list[Channel] = []
        self._frames: list[Frame] = []
        self._topics: set[str] = set()
        self._schema_ids: dict[tuple[str, str, bytes], int] = {}
        self._status = RunStatus.COMPLETE.value
        self._result_info: dict[str, str] = {}
        self._last_step = -1
        self._serial = 0
        self._closed = False
        self._close_hooks: list[Callable[[], None]] = []
        self._overwrite = bool(overwrite)

        self._file: BinaryIO = _create_partial(self.path, self.partial_path, self._overwrite)
        try:
            self._writer = ChunkedWriter(self._file, chunk_size=int(chunk_size), compression=compression,
                                         chunk_thread=chunk_thread)
            self._writer.start(library=library_string())
            self._writer.add_metadata(RUN_METADATA, metadata)
            for attachment in files:
                self._writer.add_attachment(0, 0, attachment.name, attachment.media_type, bytes(attachment.data))
            self._writer.flush()
        except BaseException:
            self._writer_failed_at_start()
            raise

    def _writer_failed_at_start(self) -> None:
        """Remove the ``.partial`` this writer created and holds, when its start failed (it holds no run yet)."""
        try:
            self._file.close()
        finally:
            self.partial_path.unlink(missing_ok=True)

    # -- channels --------------------------------------------------------------------

    def channel(self, topic: str, schema_name: str, schema: Mapping[str, Any] | MsgType, *,
                fields: Sequence[str] | None = None, layout: Mapping[str, Any] | None = None,
                metadata: Mapping[str, str] | None = None) -> Channel:
        """Register a JSON channel, for irregular messages (:meth:`Channel.write`), or a CDR one.

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``"/hydroplant/events"``; unique per file.
        schema_name : str
            Schema name (``"foxglove.Log"`` etc. for the well-known ones).
        schema : Mapping or MsgType
            JSON Schema of the messages, e.g. from :func:`log_schema`; a :class:`MsgType`
            (e.g. from :func:`flat_schema`, named by ``schema_name`` in either form) makes the
            channel :meth:`cdr_channel` ``(topic, schema, fields=fields, layout=layout)``.
        fields, layout
            Of a CDR channel, see :meth:`cdr_channel`.
        metadata : Mapping[str, str], optional
            Channel metadata, e.g. ``{"units": "SI"}``.

        Returns
        -------
        Channel
        """
        if isinstance(schema, MsgType):
            if _ros_type_name(schema_name) != schema.name:
                raise ValueError(f"{topic}: schema name {schema_name!r} does not name message type {schema.name!r}")
            return self.cdr_channel(topic, schema, fields=fields, layout=layout, metadata=metadata)
        if fields is not None or layout is not None:
            raise TypeError(f"{topic}: columnar channels are ROS 2 CDR; give a MsgType (e.g. flat_schema(...))")
        schema_bytes = json.dumps(schema, separators=(",", ":")).encode()
        return self._add_channel(Channel, topic, schema_name, "jsonschema", schema_bytes, "json", None, None, metadata)

    def cdr_channel(self, topic: str, msg_type: MsgType, *, fields: Sequence[str] | None = None,
                    layout: Mapping[str, Any] | None = None, metadata: Mapping[str, str] | None = None) -> Channel:
        """Register a columnar ROS 2 channel (schema encoding ``ros2msg``, messages in ``cdr``).

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``"/hydroplant/cylinders/boom"``; unique per file.
        msg_type : MsgType
            Message type, e.g. from :func:`flat_schema`; its name is the schema name.
        fields : sequence of str, optional
            :meth:`Channel.append` takes one float per field, in this order (float64 fields of
            ``msg_type``, dotted for nested ones); ``timestamp`` is the sample's log time.
        layout : Mapping, optional
            General message template instead of ``fields``: the message as nested dicts and
            lists with :class:`Column` at float64 fields and :data:`TIMESTAMP` at Time fields,
            constants elsewhere (missing fields: NaN, 0, "" or empty).
        metadata : Mapping[str, str], optional
            Channel metadata, e.g. ``{"units": "SI"}``.

        Returns
        -------
        Channel
        """
        if not isinstance(msg_type, MsgType):
            raise TypeError(f"{topic}: `msg_type` must be a MsgType, got {type(msg_type).__name__}")
        if (fields is None) == (layout is None):
            raise ValueError(f"{topic}: give either `fields` or `layout`")
        if fields is not None:
            template = _fields_template(msg_type, tuple(fields))
        else:
            template = _cdr_template(msg_type, _LayoutKey(layout))
        return self._add_channel(Channel, topic, msg_type.name, "ros2msg", _definition_bytes(msg_type), "cdr",
                                 msg_type, template, metadata)

    def joint_states_channel(self, topic: str, joint_names: Sequence[str], *,
                             metadata: Mapping[str, str] | None = None) -> JointStatesChannel:
        """Register a columnar ``foxglove_msgs/msg/JointStates`` channel (CDR).

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``"/hydroplant/joint_states"``.
        joint_names : sequence of str
            Joint names, in the order of the arrays given to :meth:`JointStatesChannel.append`.
        metadata : Mapping[str, str], optional
            Channel metadata.
        """
        names = tuple(joint_names)
        if not names or len(set(names)) != len(names) or not all(isinstance(n, str) for n in names):
            raise ValueError(f"`joint_names` must be unique non-empty strings, got {names!r}")
        count = len(names)
        layout = {
            "timestamp": TIMESTAMP,
            "joints": [
                {"name": name, "position": Column(i), "velocity": Column(count + i), "effort": Column(2 * count + i)}
                for i, name in enumerate(names)
            ],
        }
        template = _cdr_template(JOINT_STATES, _LayoutKey(layout))
        return self._add_channel(JointStatesChannel, topic, JOINT_STATES.name, "ros2msg", _definition_bytes(JOINT_STATES),
                                 "cdr", JOINT_STATES, template, metadata, extra={"joint_names": names})

    def on_close(self, hook: Callable[[], None]) -> None:
        """Call ``hook()`` when the log closes, before its last samples are written.

        For callers that buffer samples themselves (e.g. :class:`sim.run.recorder.RunRecorder`):
        the hook hands them over, so an exception or Ctrl-C that closes the log keeps
        them.  An exception in a hook is recorded in ``hydroplant.result``
        (``close_hook_error``) and the log is still finished.
        """
        self._close_hooks.append(hook)

    def frame(self, column_count: int) -> Frame:
        """A :class:`Frame`: one row of ``column_count`` floats per sample feeding several channels."""
        self._check_open()
        frame = Frame(self, column_count, self._batch_size)
        self._frames.append(frame)
        return frame

    def _add_channel(self, cls: type[Channel], topic: str, schema_name: str, schema_encoding: str, schema_bytes: bytes,
                     message_encoding: str, msg_type: MsgType | None, template: _CdrTemplate | None,
                     metadata: Mapping[str, str] | None, extra: Mapping[str, Any] | None = None) -> Channel:
        self._check_open()
        if not isinstance(topic, str) or not topic:
            raise ValueError(f"`topic` must be a non-empty str, got {topic!r}")
        if topic in self._topics:
            raise ValueError(f"topic {topic!r} is already registered")
        key = (schema_name, schema_encoding, schema_bytes)
        schema_id = self._schema_ids.get(key)
        if schema_id is None:
            schema_id = self._writer.register_schema(schema_name, schema_encoding, schema_bytes)
            self._schema_ids[key] = schema_id
        channel_id = self._writer.register_channel(topic, message_encoding, schema_id, _str_dict("metadata", metadata))
        channel = cls(self, channel_id, len(self._channels), topic, schema_name, msg_type, template, self._batch_size,
                      **(extra or {}))
        self._channels.append(channel)
        self._topics.add(topic)
        return channel

    # -- time, status, flushing ------------------------------------------------------

    def log_time(self, step_index: int) -> int:
        """Log time of ``step_index`` [ns]; see :func:`step_log_time`."""
        return step_log_time(step_index, self.dt)

    def mark(self, status: str, **info: Any) -> None:
        """Set the run result written as ``hydroplant.result`` at close.

        Parameters
        ----------
        status : {"complete", "diverged", "incomplete"}
            Outcome of the run.
        **info
            Extra entries (str, int or float; floats are stored with ``repr``), e.g.
            ``time_s="1.234"``, ``component="boom_cylinder"``.
        """
        allowed = (RunStatus.COMPLETE.value, RunStatus.DIVERGED.value, RunStatus.INCOMPLETE.value)
        if status not in allowed:
            raise ValueError(f"`status` must be one of {allowed}, got {status!r}")
        converted = {}
        for key, value in info.items():
            if isinstance(value, bool) or not isinstance(value, (str, int, float)):
                raise TypeError(f"info {key!r} must be str, int or float, got {value!r}")
            converted[key] = value if isinstance(value, str) else repr(value)
        self._status = status
        self._result_info.update(converted)

    @property
    def status(self) -> str:
        """Status that :meth:`close` will record."""
        return self._status

    def flush(self) -> None:
        """Encode all buffered samples, end the current chunk and flush the file (on return, all is in the file)."""
        self._check_open()
        self._drain(end_chunk=True)

    def _periodic_flush(self, step_index: int) -> None:
        self._drain(end_chunk=True, wait=False)  # the chunk thread compresses and writes it while the run goes on
        steps = self._flush_steps
        self._next_flush_step = (step_index // steps + 1) * steps

    def _drain(self, *, end_chunk: bool, wait: bool = True) -> None:
        with _DeferredSigint():
            self._drain_now(end_chunk=end_chunk, wait=wait)

    def _drain_now(self, *, end_chunk: bool, wait: bool = True) -> None:
        blocks = [block for frame in self._frames for block in frame._take_encoded()]
        blocks += [block for channel in self._channels for block in channel._take_encoded()]
        if blocks:
            self._writer.add_records(_merge_blocks(blocks))
            self._last_step = max(self._last_step, max(c._last_step for c in self._channels))
        if end_chunk:
            self._writer.flush(wait=wait)
        else:
            self._writer.flush_stream()

    def _next_serial(self) -> int:
        """A new block serial number (creation order, the last tie-break of the log-time merge)."""
        self._serial += 1
        return self._serial

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"log {self.path} is closed")

    # -- closing ---------------------------------------------------------------------

    def close(self) -> None:
        """Flush, write ``hydroplant.result``, finish the summary and rename to ``path``.

        Idempotent. If finishing fails, the ``.partial`` file is left for :func:`recover`.
        """
        if self._closed:
            return
        with _DeferredSigint():
            hooks, self._close_hooks = self._close_hooks, []
            for hook in hooks:
                try:
                    hook()
                except Exception as error:  # noqa: BLE001 - finishing the log matters more
                    self._result_info["close_hook_error"] = f"{type(error).__name__}: {error}"
        self._closed = True
        self._next_flush_step = -math.inf  # any later append() reaches _check_open()
        with _DeferredSigint():
            try:
                self._drain_now(end_chunk=True)
                result = {"status": self._status, **self._result_info}
                if self._last_step >= 0:
                    result.setdefault("last_step", str(self._last_step))
                    result.setdefault("end_time_s", repr(self.log_time(self._last_step) / NS_PER_S))
                self._writer.add_metadata(RESULT_METADATA, result)
                self._writer.finish()
            finally:
                try:
                    self._writer.stop_thread()  # (done by finish(); here for a close that failed before it)
                finally:
                    self._file.close()  # (also releases the lock on the partial)
            publish(self.partial_path, self.path, self._overwrite)

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: Any) -> None:
        if exc_type is not None and not self._closed:
            if issubclass(exc_type, KeyboardInterrupt):
                reason = "interrupted"
            else:
                reason = f"{exc_type.__name__}: {exc}"
            self._status = RunStatus.INCOMPLETE.value
            self._result_info["reason"] = reason
        self.close()


# ---------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------

# Foxglove arrays whose elements are keyed "<field>/<element name>" (list name dropped).
_NAMED_ARRAYS = {
    "foxglove.JointStates": ("joints", "name"),
    "foxglove.FrameTransforms": ("transforms", "child_frame_id"),
    JOINT_STATES.name: ("joints", "name"),
    FRAME_TRANSFORMS.name: ("transforms", "child_frame_id"),
}


def _flatten(obj: Mapping[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for key, value in obj.items():
        path = prefix + key
        if isinstance(value, Mapping):
            _flatten(value, path + ".", out)
        elif isinstance(value, list):
            for index, item in enumerate(value):
                if isinstance(item, Mapping):
                    _flatten(item, f"{path}[{index}].", out)
                else:
                    out[f"{path}[{index}]"] = item
        else:
            out[path] = value


def _flatten_message(message: Mapping[str, Any], named_array: tuple[str, str] | None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if named_array is None:
        _flatten(message, "", out)
        return out
    list_key, name_key = named_array
    rest = {k: v for k, v in message.items() if k != list_key}
    _flatten(rest, "", out)
    for element in message.get(list_key, ()):
        label = element.get(name_key)
        flat: dict[str, Any] = {}
        _flatten({k: v for k, v in element.items() if k != name_key}, "", flat)
        for key, value in flat.items():
            out[f"{key}/{label}"] = value
    return out


def _is_number(value: Any) -> bool:
    return value is None or (isinstance(value, (int, float)) and not isinstance(value, str))


def _message_columns(messages: list[dict], named: tuple[str, str] | None) -> tuple[dict, dict]:
    """Numeric (float64, ``None`` -> NaN) and text columns of decoded messages, by flattened field name."""
    count = len(messages)
    columns: dict[str, list] = {}
    for i, message in enumerate(messages):
        for key, value in _flatten_message(message, named).items():
            column = columns.get(key)
            if column is None:
                column = columns[key] = [None] * count
            column[i] = value
    numeric: dict[str, np.ndarray] = {}
    text: dict[str, list] = {}
    for key, column in columns.items():
        if all(_is_number(v) for v in column):
            numeric[key] = np.array([np.nan if v is None else float(v) for v in column], dtype=np.float64)
        else:
            text[key] = column
    return numeric, text


def _cdr_columns(t: MsgType, datas: list[bytes], named: tuple[str, str] | None) -> tuple[dict, dict]:
    """:func:`_message_columns` of CDR messages, read as arrays when all share the first one's layout.

    The layout of a CDR message is fixed by its non-numeric bytes (header, counts, strings,
    padding): when every message has the length and those bytes of the first, each numeric
    field is one strided view of the messages' bytes (bit-exact); otherwise each message is
    decoded on its own.
    """
    if not datas:
        return {}, {}
    first = datas[0]
    flat = _flatten_message(_cdr_get(t, first, _CDR_BASE, True)[0], named)
    size = len(first)
    if all(len(d) == size for d in datas):
        rows = np.frombuffer(b"".join(datas), dtype=np.uint8).reshape(len(datas), size)
        structural = np.ones(size, dtype=bool)
        leaves = {key: leaf for key, leaf in flat.items() if isinstance(leaf, _Leaf)}
        for leaf in leaves.values():
            structural[leaf.offset:leaf.offset + struct.calcsize(leaf.fmt)] = False
        if np.array_equal(rows[:, structural], np.broadcast_to(rows[0, structural], (len(datas), int(structural.sum())))):
            numeric = {key: _leaf_column(rows, leaf) for key, leaf in leaves.items()}
            text = {key: [value] * len(datas) for key, value in flat.items() if key not in leaves}
            return numeric, text
    return _message_columns([cdr_decode(t, d) for d in datas], named)


def _nan_to_none(value: Any) -> Any:
    """A decoded message with every NaN replaced by ``None`` (the JSON topics' ``null``)."""
    if isinstance(value, float):
        return None if value != value else value
    if isinstance(value, dict):
        return {key: _nan_to_none(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_nan_to_none(item) for item in value]
    return value


def _leaf_column(rows: np.ndarray, leaf: _Leaf) -> np.ndarray:
    size = struct.calcsize(leaf.fmt)
    return np.ascontiguousarray(rows[:, leaf.offset:leaf.offset + size]).view(np.dtype(leaf.fmt))[:, 0].astype(np.float64)


class TopicData:
    """Messages of one topic as columns.

    Attributes
    ----------
    topic : str
        Topic name.
    schema_name : str
        Schema name of the topic.
    log_time : ndarray of int64, shape (message_count,)
        Log times [ns].
    t : ndarray of float64, shape (message_count,)
        Log times [s].
    messages : list of dict
        Decoded messages, in log-time order, JSON-like: NaN is ``None`` in CDR messages too,
        as ``null`` in JSON ones (CDR messages are decoded when first asked for; the columns
        are the bit-exact values).
    fields : list of str
        Numeric field names (nested objects joined with dots; for joint states
        ``"position/<joint>"`` etc., for frame transforms ``"translation.x/<child_frame_id>"``
        etc.; other arrays ``"name[i]..."``).
    text_fields : list of str
        Non-numeric (string) field names, see :meth:`text`.
    """

    def __init__(self, topic: str, schema_name: str, log_time: np.ndarray, numeric: dict[str, np.ndarray],
                 text: dict[str, list], messages: list[dict] | Callable[[], list[dict]]):
        self.topic = topic
        self.schema_name = schema_name
        self.log_time = log_time
        self.t = log_time / NS_PER_S
        self._messages = messages
        self._numeric = numeric
        self._text = text
        self.fields = list(self._numeric)
        self.text_fields = list(self._text)

    @classmethod
    def from_messages(cls, topic: str, schema_name: str, log_time: np.ndarray, messages: list[dict]) -> TopicData:
        """Columns of decoded (e.g. JSON) messages."""
        numeric, text = _message_columns(messages, _NAMED_ARRAYS.get(schema_name))
        return cls(topic, schema_name, log_time, numeric, text, messages)

    @classmethod
    def from_cdr(cls, topic: str, msg_type: MsgType, log_time: np.ndarray, datas: list[bytes]) -> TopicData:
        """Columns of CDR messages of type ``msg_type``."""
        numeric, text = _cdr_columns(msg_type, datas, _NAMED_ARRAYS.get(msg_type.name))
        return cls(topic, msg_type.name, log_time, numeric, text,
                   lambda: [_nan_to_none(cdr_decode(msg_type, d)) for d in datas])

    @property
    def messages(self) -> list[dict]:
        if callable(self._messages):
            self._messages = self._messages()
        return self._messages

    def field(self, name: str) -> np.ndarray:
        """Numeric column ``name`` as float64, shape (message_count,); JSON ``null``/missing -> NaN."""
        try:
            return self._numeric[name]
        except KeyError:
            raise KeyError(f"topic {self.topic!r} has no numeric field {name!r}; fields: {self.fields}") from None

    def text(self, name: str) -> list:
        """Non-numeric column ``name`` as a list (``None`` where missing)."""
        return self._text[name]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.field(name)

    def __contains__(self, name: object) -> bool:
        return name in self._numeric or name in self._text

    def __len__(self) -> int:
        return len(self.log_time)


class RunLog:
    """A finished MCAP log opened with :func:`read_log`.

    Attributes
    ----------
    path : Path
        File name.
    library : str
        Header library string.
    metadata : dict of str to dict of str to str
        Metadata records by name.
    attachments : dict of str to bytes
        Attachment contents by name.
    attachment_media_types : dict of str to str
        Attachment media types by name.
    attachment_list : list of (str, str, int)
        Every attachment in file order: name, media type, size [B] (names may repeat).
    topics : list of str
        Topics in channel order.
    schema_names : dict of str to str
        Schema name of each topic.
    message_counts : dict of str to int
        Messages per topic.
    start_time_ns, end_time_ns : int
        First and last log time [ns] (0 when there are no messages).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        try:
            with open(self.path, "rb") as stream:
                if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                    raise LogReadError(f"{self.path}: not an MCAP file (no MCAP magic at its start)")
                stream.seek(0)
                reader = make_reader(stream, validate_crcs=True)
                summary = reader.get_summary()
                if summary is None or summary.statistics is None:
                    raise LogReadError(f"{self.path}: has no summary; it was not finished; "
                                       f"run 'hydroplant log recover {self.path}'")
                self.library = reader.get_header().library
                self.metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
                self.attachments: dict[str, bytes] = {}
                self.attachment_media_types: dict[str, str] = {}
                self.attachment_list: list[tuple[str, str, int]] = []
                for attachment in reader.iter_attachments():
                    self.attachments[attachment.name] = bytes(attachment.data)
                    self.attachment_media_types[attachment.name] = attachment.media_type
                    self.attachment_list.append((attachment.name, attachment.media_type, len(attachment.data)))
        except LogReadError:
            raise
        except (McapError, EOFError, LookupError, ValueError, struct.error) as error:
            raise LogReadError(f"{self.path}: not a finished, readable MCAP log ({type(error).__name__}: {error}); "
                               f"run 'hydroplant log recover {self.path}'") from None
        stats = summary.statistics
        self.topics: list[str] = []
        self.schema_names: dict[str, str] = {}
        self.message_counts: dict[str, int] = {}
        for channel_id, channel in sorted(summary.channels.items()):
            if channel.topic not in self.message_counts:
                self.topics.append(channel.topic)
                self.message_counts[channel.topic] = 0
                schema = summary.schemas.get(channel.schema_id)
                self.schema_names[channel.topic] = schema.name if schema is not None else ""
            self.message_counts[channel.topic] += stats.channel_message_counts.get(channel_id, 0)
        self.message_count = stats.message_count
        self.start_time_ns = stats.message_start_time
        self.end_time_ns = stats.message_end_time
        self._topic_cache: dict[str, TopicData] = {}

    @property
    def status(self) -> str:
        """``status`` of the ``hydroplant.result`` record, or ``"unknown"``."""
        return self.metadata.get(RESULT_METADATA, {}).get("status", "unknown")

    def topic(self, name: str) -> TopicData:
        """All messages of topic ``name`` as columns (cached on this object)."""
        cached = self._topic_cache.get(name)
        if cached is not None:
            return cached
        if name not in self.message_counts:
            raise KeyError(f"{self.path} has no topic {name!r}; topics: {self.topics}")
        log_times: list[int] = []
        datas: list[bytes] = []
        encoding, msg_type = "json", None
        try:
            with open(self.path, "rb") as stream:
                reader = make_reader(stream, validate_crcs=True)
                for schema, channel, message in reader.iter_messages(topics=[name], log_time_order=True):
                    if channel.message_encoding != encoding:
                        if channel.message_encoding != "cdr" or schema is None or schema.encoding != "ros2msg" or datas:
                            raise ValueError(f"topic {name!r} uses {channel.message_encoding!r}; json and cdr "
                                             "(ros2msg) are supported, one per topic")
                        encoding, msg_type = "cdr", ros2msg_type(schema.name, schema.data.decode())
                    log_times.append(message.log_time)
                    datas.append(message.data)
        except (McapError, EOFError, LookupError, struct.error) as error:
            raise LogReadError(f"{self.path}: topic {name!r} cannot be read, the log is damaged "
                               f"({type(error).__name__}: {error}); 'hydroplant log recover {self.path}' keeps "
                               "every chunk that checks") from None
        except Exception as error:  # zstandard raises its own ZstdError on a damaged chunk
            if type(error).__module__.split(".")[0] not in ("zstandard", "lz4", "_lz4"):
                raise
            raise LogReadError(f"{self.path}: topic {name!r} cannot be read, a chunk does not decompress "
                               f"({error}); 'hydroplant log recover {self.path}' keeps every chunk that "
                               "checks") from None
        times = np.array(log_times, dtype=np.int64)
        if msg_type is not None:
            data = TopicData.from_cdr(name, msg_type, times, datas)
        else:
            data = TopicData.from_messages(name, self.schema_names[name], times, [_loads(d) for d in datas])
        self._topic_cache[name] = data
        return data

    def __contains__(self, name: object) -> bool:
        return name in self.message_counts


def read_log(path: str | os.PathLike) -> RunLog:
    """Open a finished log for analysis; see :class:`RunLog`."""
    return RunLog(path)


def log_info(path: str | os.PathLike, *, verify: bool = True) -> str:
    """Human-readable summary of a log: run metadata, status, span, topics and counts, attachments, damage.

    See :func:`inspect_log`, which also gives the exit status of ``hydroplant log info``.
    """
    return inspect_log(path, verify=verify)[0]


def inspect_log(path: str | os.PathLike, *, verify: bool = True) -> tuple[str, int]:
    """Summary of a log and its state: ``(text, code)`` with code 0 for a finished log whose chunks all check, 1 for
    a damaged or unfinished one.

    Parameters
    ----------
    path : str or Path
        A log; an unfinished file yields a note instead of the summary.
    verify : bool, optional
        Decompress every chunk and check its CRC (:func:`sim.io.log_recover.verify_log`).

    Raises
    ------
    LogReadError
        The file is not an MCAP file.
    """
    check = verify_log(path) if verify else None
    damage = [] if check is None else [check.summary_text()]
    try:
        log = RunLog(path)
    except LogReadError as error:
        if check is not None and check.damage and not check.footer:
            return "\n".join([f"{path}: UNFINISHED: no footer; run 'hydroplant log recover {path}'", *damage]), 1
        if check is None and "not an MCAP file" in str(error):
            raise
        return "\n".join([f"{path}: UNFINISHED: {error}", *damage]), 1
    lines = [f"file: {log.path}", f"library: {log.library}"]
    result = log.metadata.get(RESULT_METADATA)
    if result is None:
        lines.append("status: unknown (no hydroplant.result record)")
    else:
        extra = ", ".join(f"{k}={v}" for k, v in result.items() if k != "status")
        lines.append(f"status: {result.get('status', 'unknown')}" + (f" ({extra})" if extra else ""))
    run = log.metadata.get(RUN_METADATA, {})
    for key in ("scene", "scenario", "mode", "duration_s"):
        if key in run:
            lines.append(f"{key}: {run[key]}")
    if run:
        lines.append("run: " + ", ".join(f"{k}={v}" for k, v in sorted(run.items())))
    span = (log.end_time_ns - log.start_time_ns) / NS_PER_S
    lines.append(f"logged: {log.start_time_ns / NS_PER_S:.6g} s .. {log.end_time_ns / NS_PER_S:.6g} s "
                 f"({span:.6g} s), {log.message_count} messages")
    lines.append("topics:")
    width = max((len(t) for t in log.topics), default=0)
    for topic in log.topics:
        lines.append(f"  {topic:<{width}}  {log.message_counts[topic]:>8d}  {log.schema_names[topic]}")
    other = [name for name in log.metadata if name not in (RUN_METADATA, RESULT_METADATA)]
    if other:
        lines.append("metadata: " + ", ".join(other))
    lines.append(f"attachments: {len(log.attachment_list)}")
    lines += [f"  {name}  {media_type}  {size} B" for name, media_type, size in log.attachment_list]
    lines += damage if check is not None else ["verified: no (--no-verify)"]
    return "\n".join(lines), 1 if check is not None and check.damage else 0


# ---------------------------------------------------------------------------------------
# Merging
# ---------------------------------------------------------------------------------------


def _prefix_frames(node: Any, prefix: str, shared: frozenset[str]) -> Any:
    if isinstance(node, dict):
        out = {}
        for key, value in node.items():
            if key in FRAME_ID_KEYS and isinstance(value, str) and value not in shared:
                out[key] = f"{prefix}/{value}"
            else:
                out[key] = _prefix_frames(value, prefix, shared)
        return out
    if isinstance(node, list):
        return [_prefix_frames(item, prefix, shared) for item in node]
    return node


def _frame_rewriter(schema: McapSchema | None, message_encoding: str, prefix: str,
                    shared: frozenset[str]) -> Callable[[bytes], bytes] | None:
    """The function prefixing the frame ids of one channel's messages (Foxglove schemas, JSON or CDR), or None."""
    if schema is None:
        return None
    if message_encoding == "json" and schema.name.startswith("foxglove."):
        return lambda data: to_json_bytes(_prefix_frames(_loads(data), prefix, shared))
    if message_encoding == "cdr" and schema.encoding == "ros2msg" and schema.name.startswith("foxglove_msgs/"):
        msg_type = ros2msg_type(schema.name, bytes(schema.data).decode())
        return lambda data: cdr_encode(msg_type, _prefix_frames(cdr_decode(msg_type, data), prefix, shared))
    return None


def merge_logs(inputs: Mapping[str, str | os.PathLike], out_path: str | os.PathLike, *,
               shared_frames: Iterable[str] = ("world",), overwrite: bool = False) -> None:
    """Merge finished logs into one file with prefixed topics, e.g. to compare runs in Foxglove.

    Parameters
    ----------
    inputs : Mapping[str, path]
        Prefix -> log file, e.g. ``{"mujoco": a, "pbd": b}``. Prefixes are
        ``[A-Za-z0-9_.-]+``.
    out_path : str or Path
        Output file (written via ``out_path.partial`` and renamed).
    shared_frames : iterable of str, optional
        Frame ids left unprefixed so that both trees hang off a common root.
    overwrite : bool, optional
        Replace an existing ``out_path``; otherwise ``FileExistsError``.

    Notes
    -----
    Topic ``/x`` of input ``p`` becomes ``/p/x``. In messages with a Foxglove schema (JSON
    ``foxglove.*`` or CDR ``foxglove_msgs/*``), ``frame_id``, ``parent_frame_id`` and
    ``child_frame_id`` become ``p/<id>`` (except ``shared_frames``; CDR messages are decoded
    and encoded again); other messages are copied byte for byte. Messages are
    merged in log-time order (ties: input order). Metadata records and attachments are
    renamed ``p/<name>``.
    """
    shared = frozenset(shared_frames)
    for prefix in inputs:
        if not isinstance(prefix, str) or not _PREFIX_PATTERN.fullmatch(prefix):
            raise ValueError(f"merge prefix must match [A-Za-z0-9_.-]+, got {prefix!r}")
    out_path = Path(out_path)
    if out_path.exists() and not overwrite:
        raise FileExistsError(f"{out_path} exists; pass overwrite=True")
    tmp_path = out_path.with_name(out_path.name + PARTIAL_SUFFIX)
    streams = [open(path, "rb") for path in inputs.values()]
    try:
        readers = [make_reader(stream, validate_crcs=True) for stream in streams]
        with open(tmp_path, "xb") as out:
            writer = Writer(out, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD)
            writer.start(profile="", library=library_string())
            writer.add_metadata("hydroplant.merge", {prefix: Path(path).name for prefix, path in inputs.items()})
            schema_ids: dict[tuple[str, str, bytes], int] = {}
            channel_maps: list[dict[int, tuple[int, Callable[[bytes], bytes] | None]]] = []
            for prefix, reader in zip(inputs, readers):
                summary = reader.get_summary()
                if summary is None:
                    raise ValueError(f"input {prefix!r} has no summary; recover() it first")
                for record in reader.iter_metadata():
                    writer.add_metadata(f"{prefix}/{record.name}", dict(record.metadata))
                for attachment in reader.iter_attachments():
                    writer.add_attachment(attachment.create_time, attachment.log_time, f"{prefix}/{attachment.name}",
                                          attachment.media_type, attachment.data)
                channel_map: dict[int, tuple[int, Callable[[bytes], bytes] | None]] = {}
                for channel_id, channel in sorted(summary.channels.items()):
                    schema = summary.schemas.get(channel.schema_id)
                    new_schema = 0
                    if schema is not None:
                        key = (schema.name, schema.encoding, bytes(schema.data))
                        new_schema = schema_ids.get(key, 0)
                        if not new_schema:
                            new_schema = schema_ids[key] = writer.register_schema(*key)
                    topic = channel.topic if channel.topic.startswith("/") else "/" + channel.topic
                    new_id = writer.register_channel(f"/{prefix}{topic}", channel.message_encoding, new_schema,
                                                     dict(channel.metadata))
                    channel_map[channel_id] = (new_id, _frame_rewriter(schema, channel.message_encoding, prefix, shared))
                channel_maps.append(channel_map)

            def tagged(index: int):
                for _, channel, message in readers[index].iter_messages(log_time_order=True):
                    yield message.log_time, index, channel.id, message

            for _, index, channel_id, message in heapq.merge(*(tagged(i) for i in range(len(readers))),
                                                              key=lambda entry: (entry[0], entry[1])):
                new_id, rewrite = channel_maps[index][channel_id]
                data = message.data if rewrite is None else rewrite(message.data)
                writer.add_message(new_id, message.log_time, data, message.publish_time, message.sequence)
            writer.finish()
    finally:
        for stream in streams:
            stream.close()
    os.replace(tmp_path, out_path)
