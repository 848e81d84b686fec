"""MCAP logging of simulation runs: JSON messages with JSON Schema, zstd chunks, all indexes.

The writer is built for a stepping loop. Samples are appended into per-channel numpy
buffers (:meth:`Channel.append`, a few hundred ns) and encoded in batches, outside the
loop body: each channel's JSON template (built once from its fields or layout, next to
its pre-built JSON schema) is filled for all buffered samples by a compiled encoder
(numba; floats exact to the last bit, see ``_encode_rows``), or by ``str.format`` without
numba. Irregular messages (events, scene updates) go through :meth:`Channel.write`.
Buffered messages of all channels are merged in log-time order and their MCAP records
built in one compiled pass (:meth:`_BulkWriter.add_messages`) before they reach the
chunks of :class:`mcap.writer.Writer`, so every file is globally ordered by ``log_time``
and every batch is written whole, within a chunk or across a chunk boundary.

Conventions (see ``/work/shared/notes/mcap-logging.md``):

- ``log_time = publish_time`` is *simulation* time in integer nanoseconds computed from
  the integer step index, never from an accumulated float time (:func:`step_log_time`).
- Every message carries ``timestamp {sec, nsec}`` equal to its log time.
- Strict JSON: non-finite floats are written as ``null`` and read back as NaN.
- The file is written to ``PATH.partial`` and renamed to ``PATH`` when it is finished,
  also when the ``with`` block raises. A file cut by SIGKILL can be rebuilt with
  :func:`recover`.

This module does not import MuJoCo; see :mod:`sim.foxglove_scene` for the model-specific
channels.
"""

from __future__ import annotations

import enum
import functools
import heapq
import importlib.metadata
import io
import json
import math
import os
import re
import signal
import struct
import threading
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import mcap
import numpy as np
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment as _McapAttachment
from mcap.records import Channel as _McapChannel
from mcap.records import Chunk as _McapChunk
from mcap.records import ChunkIndex as _McapChunkIndex
from mcap.records import Header as _McapHeader
from mcap.records import Message as _McapMessage
from mcap.records import MessageIndex as _McapMessageIndex
from mcap.records import Metadata as _McapMetadata
from mcap.records import Schema as _McapSchema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, IndexType, Writer

__all__ = [
    "Attachment",
    "Channel",
    "Column",
    "FOXGLOVE_SCHEMAS",
    "Frame",
    "JointStatesChannel",
    "LogLevel",
    "LogWriter",
    "RecoverReport",
    "RESULT_METADATA",
    "RUN_METADATA",
    "RunLog",
    "RunStatus",
    "TIMESTAMP",
    "TopicData",
    "flat_schema",
    "frame_transforms_schema",
    "joint_states_schema",
    "library_string",
    "log_info",
    "log_message",
    "log_schema",
    "merge_logs",
    "read_log",
    "recover",
    "scene_update_schema",
    "step_log_time",
    "to_json_bytes",
]

RUN_METADATA = "hydroplant.run"  # metadata record written at construction
RESULT_METADATA = "hydroplant.result"  # metadata record written at close
PARTIAL_SUFFIX = ".partial"  # suffix of the file while it is being written
NS_PER_S = 1_000_000_000  # nanoseconds per second
DEFAULT_CHUNK_SIZE = 512 * 1024  # uncompressed bytes per chunk [B]
DEFAULT_FLUSH_INTERVAL = 1.0  # sim time between forced chunk ends [s]
DEFAULT_BATCH_SIZE = 1024  # buffered samples per channel before a batch encode
MCAP_MAGIC = b"\x89MCAP0\r\n"
RECORD_PREFIX = struct.Struct("<BQ")  # opcode (uint8) + record length (uint64)
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
    return json.dumps(_strict(message), allow_nan=False, separators=(",", ":")).encode()


def _reject_constant(name: str) -> None:
    raise ValueError(f"non-finite JSON constant {name} in message")


def _loads(data: bytes) -> Any:
    return json.loads(data, parse_constant=_reject_constant)


def library_string() -> str:
    """Header library string ``"hydroplant/<version> mcap-python/<version>"``."""
    try:
        version = importlib.metadata.version("hydroplant")
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    return f"hydroplant/{version} mcap-python/{mcap.__version__}"


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


def joint_states_schema() -> dict:
    """JSON Schema of ``foxglove.JointStates``.

    Returns
    -------
    dict
        ``timestamp``, ``joints[]{name, position, velocity, acceleration, effort}``;
        positions in rad or m, velocities in rad/s or m/s, efforts in N·m or N.
    """
    return {
        "title": "foxglove.JointStates",
        "description": "The state of a set of joints at a given time.",
        "type": "object",
        "properties": {
            "timestamp": _time_schema("Timestamp of the joint states"),
            "joints": {
                "type": "array",
                "description": "Joint states",
                "items": {
                    "title": "foxglove.JointState",
                    "type": "object",
                    "properties": {
                        "name": {"type": "string", "description": "Joint name"},
                        "position": {"type": "number", "description": "Position [rad] or [m]; null if absent"},
                        "velocity": {"type": "number", "description": "Velocity [rad/s] or [m/s]; null if absent"},
                        "acceleration": {
                            "type": "number",
                            "description": "Acceleration [rad/s²] or [m/s²]; null if absent",
                        },
                        "effort": {"type": "number", "description": "Effort [N·m] or [N]; null if absent"},
                    },
                    "required": ["name"],
                },
            },
        },
        "required": ["timestamp", "joints"],
    }


def frame_transforms_schema() -> dict:
    """JSON Schema of ``foxglove.FrameTransforms``.

    Returns
    -------
    dict
        ``transforms[]{timestamp, parent_frame_id, child_frame_id, translation{x,y,z},
        rotation{x,y,z,w}}``; translation in m, rotation a unit quaternion.
    """
    return {
        "title": "foxglove.FrameTransforms",
        "description": "An array of FrameTransform messages",
        "type": "object",
        "properties": {
            "transforms": {
                "type": "array",
                "description": "Array of transforms",
                "items": {
                    "title": "foxglove.FrameTransform",
                    "description": "A transform between two reference frames in 3D space",
                    "type": "object",
                    "properties": {
                        "timestamp": _time_schema("Timestamp of transform"),
                        "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
                        "child_frame_id": {"type": "string", "description": "Name of the child frame"},
                        "translation": _vector3_schema("Child origin in the parent frame [m]"),
                        "rotation": _quaternion_schema("Rotation of the child frame in the parent frame"),
                    },
                    "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
                },
            }
        },
        "required": ["transforms"],
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
    "foxglove.JointStates": joint_states_schema,
    "foxglove.FrameTransforms": frame_transforms_schema,
    "foxglove.SceneUpdate": scene_update_schema,
    "foxglove.Log": log_schema,
}
"""Builders of the well-known Foxglove JSON schemas, keyed by their exact schema name."""


def flat_schema(name: str, fields: Mapping[str, str]) -> dict:
    """JSON Schema for a flat message of scalar fields plus ``timestamp``.

    Parameters
    ----------
    name : str
        Schema name, also used as ``title`` (e.g. ``"hydroplant.CylinderState"``).
    fields : Mapping[str, str]
        Field name -> description including the unit, e.g.
        ``{"position_m": "Rod extension [m]"}``. Dotted names (``"force.x"``) become
        nested objects.

    Returns
    -------
    dict
        Object schema; every field is a ``number`` (``null`` when non-finite).
    """
    if not fields:
        raise ValueError(f"`fields` of schema {name!r} must not be empty")
    properties: dict[str, Any] = {"timestamp": _time_schema("Simulation time of the sample")}
    for field_name, description in fields.items():
        if not isinstance(description, str):
            raise TypeError(f"description of field {field_name!r} must be str, got {description!r}")
        parts = _split_field(field_name)
        node = properties
        for part in parts[:-1]:
            child = node.setdefault(part, {"type": "object", "properties": {}})
            if "properties" not in child or part == "timestamp":
                raise ValueError(f"field {field_name!r} conflicts with another field of schema {name!r}")
            node = child["properties"]
        if parts[-1] in node:
            raise ValueError(f"field {field_name!r} is declared twice or conflicts in schema {name!r}")
        node[parts[-1]] = {"type": "number", "description": f"{description} (null if non-finite)"}
    return {"title": name, "type": "object", "properties": properties, "required": list(properties)}


def _split_field(field_name: str) -> list[str]:
    parts = field_name.split(".")
    if not field_name or any(not p for p in parts):
        raise ValueError(f"invalid field name {field_name!r}")
    return parts


# ---------------------------------------------------------------------------------------
# Message templates for the columnar path
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Column:
    """Placeholder for column ``index`` of a sample in a channel ``layout``.

    Column values are float64 and are written with ``repr`` (exact round trip) or
    ``null`` when non-finite.
    """

    index: int


class _TimestampSlot:
    """Placeholder expanding to the sample's ``{"sec": ..., "nsec": ...}``."""

    def __repr__(self) -> str:
        return "TIMESTAMP"


TIMESTAMP = _TimestampSlot()
"""Placeholder for the sample timestamp inside a channel ``layout`` (nested timestamps)."""


class _JsonNull:
    """Object whose ``repr`` is the JSON literal ``null`` (substituted for NaN/inf)."""

    __slots__ = ()

    def __repr__(self) -> str:
        return "null"


_NULL = _JsonNull()


def _escape_braces(text: str) -> str:
    return text.replace("{", "{{").replace("}", "}}")


def _compile_layout(node: Any, columns: set[int]) -> str:
    """Turn a layout (dicts, lists, constants, :class:`Column`, TIMESTAMP) into a format string.

    Format slot 0 is the timestamp ``sec``, slot 1 ``nsec`` and slot ``i + 2`` column ``i``.
    """
    if isinstance(node, Column):
        if not isinstance(node.index, int) or node.index < 0:
            raise ValueError(f"Column index must be a non-negative int, got {node.index!r}")
        columns.add(node.index)
        return "{%d!r}" % (node.index + 2)
    if node is TIMESTAMP:
        return '{{"sec":{0},"nsec":{1}}}'
    if isinstance(node, Mapping):
        items = []
        for key, value in node.items():
            if not isinstance(key, str):
                raise TypeError(f"layout keys must be str, got {key!r}")
            items.append(_escape_braces(json.dumps(key)) + ":" + _compile_layout(value, columns))
        return "{{" + ",".join(items) + "}}"
    if isinstance(node, (list, tuple)):
        return "[" + ",".join(_compile_layout(item, columns) for item in node) + "]"
    return _escape_braces(json.dumps(_strict(node), allow_nan=False, separators=(",", ":")))


def _fields_layout(fields: Sequence[str]) -> dict:
    layout: dict[str, Any] = {}
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


def _template_of(layout: Mapping[str, Any]) -> tuple[str, int]:
    """A layout's ``str.format`` template (timestamp added first unless present) and its column count."""
    if "timestamp" not in layout:
        layout = {"timestamp": TIMESTAMP, **layout}
    columns: set[int] = set()
    template = _compile_layout(layout, columns)
    return template, (max(columns) + 1 if columns else 0)


# Templates are pure functions of the fields or layout; cached, since every run registers the same channels.
@functools.lru_cache(maxsize=1024)
def _fields_template(fields: tuple[str, ...]) -> tuple[str, int]:
    return _template_of(_fields_layout(fields))


_LAYOUT_TEMPLATES: dict[str, tuple[str, int]] = {}


def _layout_template(layout: Mapping[str, Any]) -> tuple[str, int]:
    key = repr(layout)  # constants, Column(index=i) and TIMESTAMP: the repr determines the template
    cached = _LAYOUT_TEMPLATES.get(key)
    if cached is None:
        cached = _template_of(layout)
        if len(_LAYOUT_TEMPLATES) >= 1024:
            _LAYOUT_TEMPLATES.clear()
        _LAYOUT_TEMPLATES[key] = cached
    return cached


# ---------------------------------------------------------------------------------------
# Compiled batch encoder: a channel's template filled with many samples at once
# ---------------------------------------------------------------------------------------
#
# Python's ``repr(float)`` costs ~0.4 µs, and a sample of the excavator holds ~140 floats,
# so the JSON of one sample cost more than the coupled steps between two samples. The
# batch encoder below writes the same JSON from numpy arrays in compiled code: floats with
# Grisu2 (Loitsch 2010, "Printing floating-point numbers quickly and accurately with
# integers"), which always yields digits that read back to the identical float (exact round
# trip) and, for all but ~0.25 % of values, exactly Python's shortest ``repr`` digits
# (otherwise a longer digit string of the same float, e.g. 9.999999999999999e+22 for
# 1e+23); the layout (fixed or exponent notation, ``.0``, ``e+16``, ``e-05``) follows
# ``repr``; NaN and ±inf are written as ``null``.

try:  # pragma: no branch
    import numba as _numba

    _NUMBA = True
except ImportError:  # pragma: no cover
    _NUMBA = False


def _njit(function):
    if not _NUMBA:  # pragma: no cover
        return function
    return _numba.njit(cache=True, nogil=True)(function)


def _cached_powers() -> tuple[np.ndarray, np.ndarray]:
    """10^k for k = -348, -340, ..., 340 as (64-bit normalised significand f, binary exponent e): 10^k ≈ f·2^e.

    f is 10^k·2^-e rounded to the nearest integer, with 2^63 ≤ f < 2^64 (exact integer arithmetic).
    """
    fs, es = [], []
    for i in range(87):
        k = -348 + 8 * i
        num, den = (10**k, 1) if k >= 0 else (1, 10**-k)
        e = num.bit_length() - den.bit_length() - 64
        while True:
            n, d = (num, den << e) if e >= 0 else (num << -e, den)
            q, r = divmod(n, d)
            if q >= 2**64:
                e += 1
            elif q < 2**63:
                e -= 1
            else:
                break
        f = q + (2 * r >= d)
        if f == 2**64:
            f, e = f // 2, e + 1
        fs.append(f)
        es.append(e)
    return np.array(fs, dtype=np.uint64), np.array(es, dtype=np.int64)


_POW_F, _POW_E = _cached_powers()
_POW10 = np.array([10**i for i in range(20)], dtype=np.uint64)
_U = np.uint64
_M32 = np.uint64(0xFFFFFFFF)
_FLOAT_CHARS = 24  # longest repr of a float64: "-2.2250738585072014e-308"
_INT_CHARS = 20  # longest non-negative int64


@_njit
def _mul_hi(a_f, b_f):
    """Upper 64 bits of the 128-bit product, rounded (Grisu's DiyFp multiply)."""
    a, b, c, d = a_f >> _U(32), a_f & _M32, b_f >> _U(32), b_f & _M32
    ac, bc, ad, bd = a * c, b * c, a * d, b * d
    tmp = (bd >> _U(32)) + (ad & _M32) + (bc & _M32) + (_U(1) << _U(31))
    return ac + (ad >> _U(32)) + (bc >> _U(32)) + (tmp >> _U(32))


@_njit
def _grisu2(x, digits, scratch, scratch_bits):
    """Decimal digits of a finite x > 0 into ``digits``; returns (count, K) with x = digits·10^K on reading."""
    scratch[0] = x
    bits = scratch_bits[0]
    hidden = _U(1) << _U(52)
    fraction = bits & (hidden - _U(1))
    biased = np.int64((bits >> _U(52)) & _U(0x7FF))
    if biased != 0:
        f, e = fraction + hidden, biased - 1075
    else:
        f, e = fraction, np.int64(-1074)
    # the rounding interval's upper (p) and lower (m) boundaries, on a common exponent
    p_f, p_e = (f << _U(1)) + _U(1), e - 1
    while (p_f & (hidden << _U(1))) == _U(0):
        p_f = p_f << _U(1)
        p_e -= 1
    p_f = p_f << _U(10)
    p_e -= 10
    if f == hidden:
        m_f, m_e = (f << _U(2)) - _U(1), e - 2
    else:
        m_f, m_e = (f << _U(1)) - _U(1), e - 1
    m_f = m_f << _U(m_e - p_e)
    v_f, v_e = f, e
    while (v_f & (_U(1) << _U(63))) == _U(0):
        v_f = v_f << _U(1)
        v_e -= 1
    dk = (-61 - p_e) * 0.30102999566398114 + 347.0
    k = np.int64(dk)
    if dk - k > 0.0:
        k += 1
    index = (k >> 3) + 1
    K = 348 - index * 8
    c_f = _POW_F[index]
    w_f = _mul_hi(v_f, c_f)
    wp_f = _mul_hi(p_f, c_f) - _U(1)
    wp_e = p_e + _POW_E[index] + 64
    wm_f = _mul_hi(m_f, c_f) + _U(1)
    delta = wp_f - wm_f
    shift = _U(-wp_e)
    one_f = _U(1) << shift
    wp_w = wp_f - w_f
    p1 = np.int64(wp_f >> shift)
    p2 = wp_f & (one_f - _U(1))
    kappa = 1
    while kappa < 10 and p1 >= np.int64(_POW10[kappa]):
        kappa += 1
    n = 0
    while kappa > 0:
        div = np.int64(_POW10[kappa - 1])
        d = p1 // div
        p1 = p1 % div
        if d != 0 or n != 0:
            digits[n] = 48 + d
            n += 1
        kappa -= 1
        rest = (_U(p1) << shift) + p2
        if rest <= delta:
            K += kappa
            ten_kappa = _POW10[kappa] << shift
            while rest < wp_w and delta - rest >= ten_kappa and (
                    rest + ten_kappa < wp_w or wp_w - rest > rest + ten_kappa - wp_w):
                digits[n - 1] -= 1
                rest += ten_kappa
            return n, K
    while True:
        p2 = p2 * _U(10)
        delta = delta * _U(10)
        d = np.int64(p2 >> shift)
        if d != 0 or n != 0:
            digits[n] = 48 + d
            n += 1
        p2 = p2 & (one_f - _U(1))
        kappa -= 1
        if p2 < delta:
            K += kappa
            w = wp_w * _POW10[-kappa] if -kappa < 20 else _U(0)
            rest = p2
            while rest < w and delta - rest >= one_f and (rest + one_f < w or w - rest > rest + one_f - w):
                digits[n - 1] -= 1
                rest += one_f
            return n, K


@_njit
def _put_float(x, out, pos, digits, scratch, scratch_bits):
    """Write x at out[pos:] as JSON in ``repr`` layout (``null`` if not finite); returns the new position."""
    if not math.isfinite(x):
        out[pos], out[pos + 1], out[pos + 2], out[pos + 3] = 110, 117, 108, 108
        return pos + 4
    if x < 0 or (x == 0 and math.copysign(1.0, x) < 0):
        out[pos] = 45
        pos += 1
        x = -x
    if x == 0:
        out[pos], out[pos + 1], out[pos + 2] = 48, 46, 48
        return pos + 3
    n, K = _grisu2(x, digits, scratch, scratch_bits)
    point = n + K  # x = 0.d1d2...·10^point
    if point <= -4 or point > 16:  # exponent notation, as repr
        out[pos] = digits[0]
        pos += 1
        if n > 1:
            out[pos] = 46
            pos += 1
            for i in range(1, n):
                out[pos] = digits[i]
                pos += 1
        exponent = point - 1
        out[pos] = 101
        out[pos + 1] = 45 if exponent < 0 else 43
        pos += 2
        exponent = abs(exponent)
        if exponent >= 100:
            out[pos] = 48 + exponent // 100
            pos += 1
        out[pos], out[pos + 1] = 48 + (exponent // 10) % 10, 48 + exponent % 10
        return pos + 2
    if point <= 0:
        out[pos], out[pos + 1] = 48, 46
        pos += 2
        for _ in range(-point):
            out[pos] = 48
            pos += 1
        for i in range(n):
            out[pos] = digits[i]
            pos += 1
        return pos
    if point < n:
        for i in range(point):
            out[pos] = digits[i]
            pos += 1
        out[pos] = 46
        pos += 1
        for i in range(point, n):
            out[pos] = digits[i]
            pos += 1
        return pos
    for i in range(n):
        out[pos] = digits[i]
        pos += 1
    for _ in range(point - n):
        out[pos] = 48
        pos += 1
    out[pos], out[pos + 1] = 46, 48
    return pos + 2


@_njit
def _put_int(value, out, pos, digits):
    """Write a non-negative integer at out[pos:]; returns the new position."""
    n = 0
    while True:
        digits[n] = 48 + value % 10
        value //= 10
        n += 1
        if value == 0:
            break
    for i in range(n):
        out[pos + i] = digits[n - 1 - i]
    return pos + n


@_njit
def _encode_rows(values, sec, nsec, text, text_start, slots, out, ends):
    """Fill a template for every row: text piece j, slot j, ..., last piece; ``ends[r]`` = end of message r in ``out``.

    ``slots[j]`` is -2 for the timestamp's sec, -1 for its nsec, else a column of ``values``.
    """
    digits = np.empty(32, np.uint8)
    scratch = np.empty(1, np.float64)
    scratch_bits = scratch.view(np.uint64)
    pos = 0
    for r in range(values.shape[0]):
        for j in range(slots.size + 1):
            for i in range(text_start[j], text_start[j + 1]):
                out[pos] = text[i]
                pos += 1
            if j == slots.size:
                break
            slot = slots[j]
            if slot == -2:
                pos = _put_int(sec[r], out, pos, digits)
            elif slot == -1:
                pos = _put_int(nsec[r], out, pos, digits)
            else:
                pos = _put_float(values[r, slot], out, pos, digits, scratch, scratch_bits)
        ends[r] = pos
    return pos


class _BatchTemplate:
    """A channel's ``str.format`` template split for :func:`_encode_rows` (constant text and slots)."""

    def __init__(self, template: str):
        import string

        pieces, slots, text = [], [], ""
        for literal, field, _, _ in string.Formatter().parse(template):
            text += literal  # (an escaped brace ends a literal without a field)
            if field is not None:
                pieces.append(text.encode())
                slots.append(int(field) - 2)  # format slot 0 = sec, 1 = nsec, i + 2 = column i
                text = ""
        pieces.append(text.encode())
        self.text = np.frombuffer(b"".join(pieces), dtype=np.uint8).copy()
        self.text_start = np.cumsum([0] + [len(p) for p in pieces]).astype(np.int64)
        self.slots = np.array(slots, dtype=np.int64)
        self.max_length = len(self.text) + sum(_INT_CHARS if s < 0 else _FLOAT_CHARS for s in slots)

    def encode(self, values: np.ndarray, sec: np.ndarray, nsec: np.ndarray) -> tuple[bytes, np.ndarray]:
        """JSON of every row, concatenated, and the end offset of each message."""
        n = len(values)
        out = np.empty(n * self.max_length, dtype=np.uint8)
        ends = np.empty(n, dtype=np.int64)
        end = _encode_rows(values, sec, nsec, self.text, self.text_start, self.slots, out, ends)
        return out[:end].tobytes(), ends


@functools.lru_cache(maxsize=1024)
def _batch_template(template: str) -> _BatchTemplate:
    """The :class:`_BatchTemplate` of a template (cached: its arrays are only read)."""
    return _BatchTemplate(template)


if _NUMBA:
    from numba import types as _nbtypes
    from numba.core import cgutils as _cgutils
    from numba.extending import intrinsic as _intrinsic

    @_intrinsic
    def _copy_bytes(typingctx, dst, dst_start, src, src_start, count):
        """``dst[dst_start:dst_start + count] = src[src_start:src_start + count]`` for uint8 arrays, as one memcpy
        (a slice assignment costs ~0.4 µs per message in compiled code, a byte loop ~1 ns per byte)."""
        signature = _nbtypes.void(dst, _nbtypes.intp, src, _nbtypes.intp, _nbtypes.intp)

        def codegen(context, builder, sig, args):
            destination, d0, source, s0, n = args
            d = context.make_array(sig.args[0])(context, builder, destination)
            s = context.make_array(sig.args[2])(context, builder, source)
            _cgutils.raw_memcpy(builder, builder.gep(d.data, [d0]), builder.gep(s.data, [s0]), n, 1)
            return context.get_dummy_value()

        return signature, codegen


@_njit
def _put_le(out, pos, value, size):
    for i in range(size):
        out[pos + i] = (value >> (8 * i)) & 0xFF


@_njit
def _assemble_messages(buffer, starts, ends, channel_ids, sequences, log_times, out, offsets, base):
    """MCAP Message records (opcode 5) of messages k = 0..n-1 into ``out``; ``offsets[k]`` = base + record start."""
    pos = 0
    for k in range(starts.size):
        length = ends[k] - starts[k]
        out[pos] = 0x05
        _put_le(out, pos + 1, 22 + length, 8)
        _put_le(out, pos + 9, channel_ids[k], 2)
        _put_le(out, pos + 11, sequences[k], 4)
        _put_le(out, pos + 15, log_times[k], 8)
        _put_le(out, pos + 23, log_times[k], 8)  # publish_time = log_time
        _copy_bytes(out, pos + 31, buffer, starts[k], length)
        offsets[k] = base + pos
        pos += 31 + length
    return pos


_MESSAGE_RECORD_OVERHEAD = 31  # opcode 1 + length 8 + channel 2 + sequence 4 + log time 8 + publish time 8 [B]


class _MessageIndexArrays(_McapMessageIndex):
    """A chunk's message index of one channel, kept as numpy (log_time, offset) blocks and written in one piece."""

    def write(self, stream) -> None:
        blocks = [np.asarray(r, dtype=np.uint64).reshape(-1, 2) for r in self.records]
        pairs = np.concatenate(blocks) if blocks else np.empty((0, 2), np.uint64)
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write(struct.pack("<HI", self.channel_id, pairs.size * 8))
        stream.write(pairs.astype("<u8").tobytes())
        stream.finish_record()


class _BulkWriter(Writer):
    """:class:`mcap.writer.Writer` that also takes many messages at once (:meth:`add_messages`).

    The records, chunks, indexes and statistics are those the base class writes
    message by message; the bulk path builds the Message records of a batch in
    compiled code and hands them to the base class's chunk builder, finishing a
    chunk wherever the base class would (after the message that takes it past
    ``chunk_size``).  If this version of ``mcap`` lays its writer out differently,
    the bulk path falls back to ``add_message`` per message.
    """

    ZSTD_LEVEL = 1  # measured on run logs: faster than zstd's default level 3 and compresses this JSON as well

    def _Writer__finalize_chunk(self) -> None:  # noqa: N802 - overrides the base class's private method
        """The base class's chunk finalisation, with a reused zstd compressor at :attr:`ZSTD_LEVEL`."""
        try:
            chunks = self._Writer__chunk_builder  # type: ignore[attr-defined]
            zstd = self._Writer__compression == CompressionType.ZSTD  # type: ignore[attr-defined]
        except AttributeError:  # pragma: no cover - other mcap versions
            chunks, zstd = None, False
        if not zstd or chunks is None or chunks.num_messages == 0 or not hasattr(self, "_Writer__chunk_indices"):
            return Writer._Writer__finalize_chunk(self)  # type: ignore[attr-defined]
        if not hasattr(self, "_zstd"):
            import zstandard

            self._zstd = zstandard.ZstdCompressor(level=self.ZSTD_LEVEL)
        stats, builder = self._Writer__statistics, self._Writer__record_builder  # type: ignore[attr-defined]
        stats.chunk_count += 1
        chunk_data = chunks.end()
        compressed = self._zstd.compress(chunk_data)
        chunk = _McapChunk(compression="zstd", data=compressed, message_start_time=chunks.message_start_time,
                           message_end_time=chunks.message_end_time,
                           uncompressed_crc=zlib.crc32(chunk_data) if self._Writer__enable_crcs else 0,  # type: ignore[attr-defined]
                           uncompressed_size=len(chunk_data))
        self._Writer__flush()  # type: ignore[attr-defined]
        stream = self._Writer__stream  # type: ignore[attr-defined]
        chunk_start = stream.tell()
        chunk.write(builder)
        chunk_index = _McapChunkIndex(message_start_time=chunk.message_start_time, message_end_time=chunk.message_end_time,
                                      chunk_start_offset=chunk_start, chunk_length=builder.count, message_index_offsets={},
                                      message_index_length=0, compression=chunk.compression, compressed_size=len(compressed),
                                      uncompressed_size=chunk.uncompressed_size)
        self._Writer__flush()  # type: ignore[attr-defined]
        index_start = stream.tell()
        if self._Writer__index_types & IndexType.MESSAGE:  # type: ignore[attr-defined]
            for channel_id, index in chunks.message_indices.items():
                chunk_index.message_index_offsets[channel_id] = index_start + builder.count
                index.write(builder)
        chunk_index.message_index_length = builder.count
        self._Writer__flush()  # type: ignore[attr-defined]
        self._Writer__chunk_indices.append(chunk_index)  # type: ignore[attr-defined]
        chunks.reset()

    def _bulk_parts(self):
        try:
            return (self._Writer__chunk_builder, self._Writer__statistics, self._Writer__chunk_size,  # type: ignore[attr-defined]
                    self._Writer__maybe_finalize_chunk)  # type: ignore[attr-defined]
        except AttributeError:  # pragma: no cover - other mcap versions
            return None

    def add_messages(self, buffer: bytes, starts: np.ndarray, ends: np.ndarray, channel_ids: np.ndarray,
                     sequences: np.ndarray, log_times: np.ndarray) -> None:
        """Add messages k = 0..n-1 (data ``buffer[starts[k]:ends[k]]``) in this order; ``publish_time = log_time``."""
        n = len(starts)
        if n == 0:
            return
        parts = self._bulk_parts()
        if parts is None or parts[0] is None or not _NUMBA:  # pragma: no cover
            view = memoryview(buffer)
            for k in range(n):
                t = int(log_times[k])
                self.add_message(int(channel_ids[k]), t, bytes(view[starts[k]:ends[k]]), t, int(sequences[k]))
            return
        chunks, stats, chunk_size, maybe_finalize = parts
        source = np.frombuffer(buffer, dtype=np.uint8)
        sizes = (ends - starts) + _MESSAGE_RECORD_OVERHEAD
        if stats.message_count == 0:
            stats.message_start_time = int(log_times.min())
        else:
            stats.message_start_time = min(stats.message_start_time, int(log_times.min()))
        stats.message_end_time = max(stats.message_end_time, int(log_times.max()))
        ids, counts = np.unique(channel_ids, return_counts=True)
        for channel_id, count in zip(ids.tolist(), counts.tolist()):
            stats.channel_message_counts[channel_id] += count
        stats.message_count += n
        done = 0
        while done < n:
            # messages up to and including the one that takes the chunk past chunk_size
            filled = chunks.count + np.cumsum(sizes[done:])
            over = int(np.searchsorted(filled, chunk_size, side="right"))
            stop = min(n, done + over + 1)
            piece = slice(done, stop)
            out = np.empty(int(sizes[piece].sum()), dtype=np.uint8)
            offsets = np.empty(stop - done, dtype=np.int64)
            _assemble_messages(source, starts[piece], ends[piece], channel_ids[piece], sequences[piece], log_times[piece],
                               out, offsets, chunks.count)
            times = log_times[piece]
            if chunks.num_messages == 0:
                chunks.message_start_time = int(times.min())
            else:
                chunks.message_start_time = min(chunks.message_start_time, int(times.min()))
            chunks.message_end_time = max(chunks.message_end_time, int(times.max()))
            piece_ids = channel_ids[piece]
            pairs = np.stack([times.astype(np.uint64), offsets.astype(np.uint64)], axis=1)
            for channel_id in np.unique(piece_ids).tolist():
                index = chunks.message_indices.get(channel_id)
                if index is None:
                    index = chunks.message_indices[channel_id] = _MessageIndexArrays(channel_id=channel_id, records=[])
                elif not isinstance(index, _MessageIndexArrays):  # pragma: no cover - filled by add_message before
                    index = chunks.message_indices[channel_id] = _MessageIndexArrays(channel_id, [list(index.records)])
                index.records.append(pairs[piece_ids == channel_id])
            chunks.num_messages += stop - done
            chunks.record_writer.write(out.data)
            maybe_finalize()
            done = stop


# ---------------------------------------------------------------------------------------
# Writer
# ---------------------------------------------------------------------------------------


class _DeferredSigint:
    """Hold back SIGINT (Ctrl-C) while the MCAP writer is mid-record.

    ``mcap.writer.Writer`` builds records in several Python steps, so a
    ``KeyboardInterrupt`` inside ``add_message`` would leave a half-written record in the
    chunk. Inside this context a SIGINT is recorded and the previous handler is called on
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


class RunStatus(str, enum.Enum):
    """Values of ``status`` in the ``hydroplant.result`` metadata record."""

    COMPLETE = "complete"
    DIVERGED = "diverged"
    INCOMPLETE = "incomplete"
    RECOVERED = "recovered"


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
    """One MCAP channel of a :class:`LogWriter`; create it with :meth:`LogWriter.channel`.

    A channel created with ``fields`` or ``layout`` is *columnar*: :meth:`append` stores a
    sample of ``column_count`` floats in a numpy buffer and the JSON is produced later in
    batches. Any channel accepts irregular messages through :meth:`write`.

    Attributes
    ----------
    topic : str
        Channel topic.
    schema_name : str
        Name of the channel's JSON schema.
    column_count : int
        Floats per sample for :meth:`append` (0 for a channel without a layout).
    """

    def __init__(self, writer: LogWriter, channel_id: int, order: int, topic: str, schema_name: str,
                 template: str | None, column_count: int, capacity: int):
        self.topic = topic
        self.schema_name = schema_name
        self.column_count = column_count
        self._writer = writer
        self._channel_id = channel_id
        self._order = order
        self._format = template.format if template is not None else None
        self._batch = _batch_template(template) if template is not None and _NUMBA else None
        self._capacity = capacity if template is not None else 0
        self._values = np.empty((self._capacity, column_count), dtype=np.float64)
        self._steps = np.empty(self._capacity, dtype=np.int64)
        self._count = 0
        self._last_step = -1
        self._sequence = 0
        self._encoded: list[tuple[np.ndarray, np.ndarray, bytes, np.ndarray]] = []
        self._frame: Frame | None = None  # set for the channels of a Frame (their samples live there)

    def append(self, step_index: int, values: Sequence[float] | np.ndarray) -> None:
        """Buffer one sample of a columnar channel.

        Parameters
        ----------
        step_index : int
            Physics step of the sample; non-decreasing per channel.
        values : sequence of float or ndarray, shape (column_count,)
            Field values in the order of the channel's ``fields`` (SI units); NaN and inf
            are logged as ``null``.
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
            JSON-like body. A ``timestamp {sec, nsec}`` equal to the log time is put first
            unless present; non-finite floats become ``null``. The caller's object is not
            modified.
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
        if "timestamp" not in body:
            body = {"timestamp": _timestamp(log_time), **body}
        data = to_json_bytes(body)
        self._encode_buffer()  # keep buffered samples ahead of this message
        self._sequence += 1
        self._encoded.append((np.array([log_time], np.int64), np.array([self._sequence], np.int64), data,
                              np.array([len(data)], np.int64)))
        self._last_step = step_index

    # -- internals -------------------------------------------------------------------

    def _prepare(self, step_index: int) -> int:
        """Flush before a new sample when the buffer is full or a periodic flush is due."""
        writer = self._writer
        writer._check_open()
        if self._format is None:
            raise TypeError(f"{self.topic}: channel was created without `fields` or `layout`; use write()")
        if self._frame is not None:
            raise TypeError(f"{self.topic}: a channel of a Frame takes its samples from Frame.append()")
        if step_index >= writer._next_flush_step:
            writer._periodic_flush(step_index)
        if self._count == self._capacity:
            writer._drain(end_chunk=False)
        return self._count

    def _encode_buffer(self) -> None:
        """Encode buffered samples into JSON (one block of the channel's encoded list)."""
        n = self._count
        if n == 0:
            return
        log_times = _step_log_times(self._steps[:n], self._writer.dt)
        self._encode_block(self._values[:n], log_times, *np.divmod(log_times, NS_PER_S))
        self._count = 0

    def _encode_block(self, values: np.ndarray, log_times: np.ndarray, sec: np.ndarray, nsec: np.ndarray) -> None:
        """JSON of the rows ``values`` at ``log_times`` [ns] (= ``sec``·1e9 + ``nsec``), added as one encoded block."""
        n = len(values)
        if self._batch is not None:
            buffer, ends = self._batch.encode(values, sec, nsec)
        else:  # pragma: no cover - without numba
            rows = values.tolist()
            finite = np.isfinite(values).all(axis=1)
            if not finite.all():
                for i in np.flatnonzero(~finite).tolist():
                    rows[i] = [v if math.isfinite(v) else _NULL for v in rows[i]]
            fmt = self._format
            datas = [fmt(s, ns, *row).encode() for s, ns, row in zip(sec.tolist(), nsec.tolist(), rows)]
            buffer = b"".join(datas)
            ends = np.cumsum([len(d) for d in datas]).astype(np.int64)
        first = self._sequence + 1
        self._sequence += n
        self._encoded.append((log_times, np.arange(first, first + n, dtype=np.int64), buffer, ends))

    def _take_encoded(self) -> list[tuple[np.ndarray, np.ndarray, bytes, np.ndarray]]:
        """Encoded blocks (log times, sequences, concatenated JSON, end offsets), buffered samples included."""
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
            Joint velocities [rad/s] or [m/s]; ``null`` when omitted.
        effort : array_like, shape (joint_count,), optional
            Joint efforts [N·m] or [N]; ``null`` when omitted.
        """
        joint_count = len(self.joint_names)
        row = self.claim(step_index)
        row[:joint_count] = position
        row[joint_count:2 * joint_count] = np.nan if velocity is None else velocity
        row[2 * joint_count:] = np.nan if effort is None else effort
        self.commit()


class Frame:
    """One row of floats per sample that feeds several columnar channels; create it with :meth:`LogWriter.frame`.

    A loop that logs many topics per step pays one :meth:`append` (or :meth:`claim` +
    :meth:`commit`) per sample instead of one per topic.  Each channel of the frame names
    the frame columns its fields come from (:meth:`channel`, :meth:`joint_states_channel`);
    in the log they are ordinary channels, encoded from the frame's rows in the same
    batches.  Columns no channel reads, and columns never written, cost nothing; the rows
    start as NaN, so a column that is never written is logged as ``null``.

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
        self._members: list[tuple[Channel, np.ndarray]] = []

    def _columns(self, columns: Sequence[int] | np.ndarray, count: int, topic: str) -> np.ndarray:
        columns = np.asarray(columns, dtype=np.intp).ravel()
        if len(columns) != count:
            raise ValueError(f"{topic}: {len(columns)} frame columns given for {count} fields")
        if len(columns) and (columns.min() < 0 or columns.max() >= self.column_count):
            raise ValueError(f"{topic}: frame columns must be in [0, {self.column_count}), got {columns.tolist()}")
        return columns

    def channel(self, topic: str, schema_name: str, schema: Mapping[str, Any], *, columns: Sequence[int] | np.ndarray,
                fields: Sequence[str] | None = None, layout: Mapping[str, Any] | None = None,
                metadata: Mapping[str, str] | None = None) -> Channel:
        """Register a columnar channel (as :meth:`LogWriter.channel`) whose field i is frame column ``columns[i]``."""
        if fields is None and layout is None:
            raise ValueError(f"{topic}: a frame channel needs `fields` or `layout`")
        channel = self._writer.channel(topic, schema_name, schema, fields=fields, layout=layout, metadata=metadata)
        self._adopt(channel, columns)
        return channel

    def joint_states_channel(self, topic: str, joint_names: Sequence[str], *, columns: Sequence[int] | np.ndarray,
                             metadata: Mapping[str, str] | None = None) -> JointStatesChannel:
        """A ``foxglove.JointStates`` channel (as :meth:`LogWriter.joint_states_channel`) from frame ``columns``:
        positions, then velocities, then efforts (3 × joint count)."""
        channel = self._writer.joint_states_channel(topic, joint_names, metadata=metadata)
        self._adopt(channel, columns)
        return channel

    def adopt(self, channel: Channel, columns: Sequence[int] | np.ndarray) -> None:
        """Make an existing columnar channel of this writer (with no samples yet) take its samples from ``columns``."""
        if channel._writer is not self._writer or channel._format is None or channel._count or channel._encoded:
            raise ValueError(f"{channel.topic}: only an empty columnar channel of the same log can join a frame")
        self._adopt(channel, columns)

    def _adopt(self, channel: Channel, columns: Sequence[int] | np.ndarray) -> None:
        channel._frame = self
        channel._capacity = 0  # its own append() now always reaches _prepare(), which refuses
        columns = self._columns(columns, channel.column_count, channel.topic)
        if len(columns) and np.array_equal(columns, np.arange(columns[0], columns[0] + len(columns))):
            columns = slice(int(columns[0]), int(columns[0]) + len(columns))  # a view instead of a gather
        self._members.append((channel, columns))

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
        """Encode the buffered rows into every member channel's encoded blocks."""
        n = self._count
        if n == 0:
            return
        steps = self._steps[:n]
        log_times = _step_log_times(steps, self._writer.dt)
        sec, nsec = np.divmod(log_times, NS_PER_S)
        rows = self._values[:n]
        last = int(steps[-1])
        for channel, columns in self._members:
            channel._encode_block(rows[:, columns], log_times, sec, nsec)
            channel._last_step = last
        self._count = 0


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
        Replace an existing ``path`` or ``path.partial``; otherwise ``FileExistsError``.

    Notes
    -----
    What a SIGKILL can lose is bounded by the larger of ``flush_interval`` of simulation
    time and ``chunk_size`` bytes of messages plus ``batch_size`` samples per channel;
    everything before is in complete chunks on disk and comes back with :func:`recover`.
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
                 batch_size: int = DEFAULT_BATCH_SIZE, compression: str = "zstd", overwrite: bool = False):
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"`dt` must be positive and finite, got {dt!r} s")
        if not (flush_interval > 0):
            raise ValueError(f"`flush_interval` must be positive, got {flush_interval!r} s")
        if int(batch_size) < 1:
            raise ValueError(f"`batch_size` must be >= 1, got {batch_size!r}")
        if int(chunk_size) < 1:
            raise ValueError(f"`chunk_size` must be >= 1, got {chunk_size!r} B")
        compressions = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in compressions:
            raise ValueError(f"`compression` must be one of {sorted(compressions)}, got {compression!r}")
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
        self._schema_ids: dict[tuple[str, bytes], int] = {}
        self._status = RunStatus.COMPLETE.value
        self._result_info: dict[str, str] = {}
        self._last_step = -1
        self._closed = False
        self._close_hooks: list[Callable[[], None]] = []

        if not overwrite:
            for existing in (self.path, self.partial_path):
                if existing.exists():
                    raise FileExistsError(f"{existing} exists; pass overwrite=True, or recover() a .partial first")
        self._file: BinaryIO = open(self.partial_path, "wb")
        try:
            self._writer = _BulkWriter(self._file, chunk_size=int(chunk_size), compression=compressions[compression],
                                  index_types=IndexType.ALL)
            self._writer.start(profile="", library=library_string())
            self._writer.add_metadata(RUN_METADATA, metadata)
            for attachment in files:
                self._writer.add_attachment(0, 0, attachment.name, attachment.media_type, bytes(attachment.data))
            self._file.flush()
        except BaseException:
            self._file.close()
            self.partial_path.unlink()
            raise

    # -- channels --------------------------------------------------------------------

    def channel(self, topic: str, schema_name: str, schema: Mapping[str, Any], *,
                fields: Sequence[str] | None = None, layout: Mapping[str, Any] | None = None,
                metadata: Mapping[str, str] | None = None) -> Channel:
        """Register a JSON channel.

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``"/hydroplant/cylinders/boom"``; unique per file.
        schema_name : str
            Schema name (``"foxglove.JointStates"`` etc. for the well-known ones).
        schema : Mapping
            JSON Schema of the messages, e.g. from :func:`flat_schema`.
        fields : sequence of str, optional
            Makes the channel columnar: :meth:`Channel.append` takes one float per field,
            in this order. Dotted names become nested objects.
        layout : Mapping, optional
            General columnar message template: JSON-like constants with :class:`Column`
            and :data:`TIMESTAMP` placeholders. Exclusive with ``fields``.
        metadata : Mapping[str, str], optional
            Channel metadata, e.g. ``{"units": "SI"}``.

        Returns
        -------
        Channel
        """
        return self._add_channel(Channel, topic, schema_name, schema, fields=fields, layout=layout,
                                 metadata=metadata)

    def joint_states_channel(self, topic: str, joint_names: Sequence[str], *,
                             metadata: Mapping[str, str] | None = None) -> JointStatesChannel:
        """Register a columnar ``foxglove.JointStates`` channel.

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
        return self._add_channel(JointStatesChannel, topic, "foxglove.JointStates", joint_states_schema(),
                                 layout=layout, metadata=metadata, extra={"joint_names": names})

    def on_close(self, hook: Callable[[], None]) -> None:
        """Call ``hook()`` when the log closes, before its last samples are written.

        For callers that buffer samples themselves (e.g. :class:`sim.recorder.RunRecorder`):
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

    def _add_channel(self, cls: type[Channel], topic: str, schema_name: str, schema: Mapping[str, Any], *,
                     fields: Sequence[str] | None = None, layout: Mapping[str, Any] | None = None,
                     metadata: Mapping[str, str] | None = None, extra: Mapping[str, Any] | None = None) -> Channel:
        self._check_open()
        if not isinstance(topic, str) or not topic:
            raise ValueError(f"`topic` must be a non-empty str, got {topic!r}")
        if topic in self._topics:
            raise ValueError(f"topic {topic!r} is already registered")
        if fields is not None and layout is not None:
            raise ValueError("give either `fields` or `layout`, not both")
        template = None
        column_count = 0
        if fields is not None:
            fields = tuple(fields)
            properties = schema.get("properties")
            if isinstance(properties, Mapping):
                missing = [f for f in fields if f.split(".")[0] not in properties]
                if missing:
                    raise ValueError(f"fields {missing} of topic {topic!r} are not in schema {schema_name!r}")
            template, column_count = _fields_template(fields)
        elif layout is not None:
            template, column_count = _layout_template(layout)
        schema_bytes = json.dumps(schema, separators=(",", ":")).encode()
        key = (schema_name, schema_bytes)
        schema_id = self._schema_ids.get(key)
        if schema_id is None:
            schema_id = self._writer.register_schema(schema_name, "jsonschema", schema_bytes)
            self._schema_ids[key] = schema_id
        channel_id = self._writer.register_channel(topic, "json", schema_id, _str_dict("metadata", metadata))
        channel = cls(self, channel_id, len(self._channels), topic, schema_name, template, column_count,
                      self._batch_size, **(extra or {}))
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
        """Encode all buffered samples, end the current chunk and flush the file."""
        self._check_open()
        self._drain(end_chunk=True)

    def _periodic_flush(self, step_index: int) -> None:
        self._drain(end_chunk=True)
        steps = self._flush_steps
        self._next_flush_step = (step_index // steps + 1) * steps

    def _drain(self, *, end_chunk: bool) -> None:
        with _DeferredSigint():
            self._drain_now(end_chunk=end_chunk)

    def _drain_now(self, *, end_chunk: bool) -> None:
        for frame in self._frames:
            frame._encode()
        times, orders, sequences, channel_ids, buffers, starts, ends = [], [], [], [], [], [], []
        offset = 0
        for channel in self._channels:
            for log_times, seqs, buffer, block_ends in channel._take_encoded():
                n = len(log_times)
                times.append(log_times)
                sequences.append(seqs)
                orders.append(np.full(n, channel._order, np.int64))
                channel_ids.append(np.full(n, channel._channel_id, np.int64))
                buffers.append(buffer)
                ends.append(block_ends + offset)
                starts.append(np.concatenate(([0], block_ends[:-1])) + offset)
                offset += len(buffer)
        if times:
            log_times = np.concatenate(times)
            sequence = np.concatenate(sequences)
            # (log_time, channel order, sequence) is unique: a total order, the same as sorting tuples
            order = np.lexsort((sequence, np.concatenate(orders), log_times))
            self._writer.add_messages(b"".join(buffers), np.concatenate(starts)[order], np.concatenate(ends)[order],
                                      np.concatenate(channel_ids)[order], sequence[order], log_times[order])
            self._last_step = max(self._last_step, max(c._last_step for c in self._channels))
        if end_chunk:
            self._writer.flush()
        else:
            self._file.flush()

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
                self._file.close()
            os.replace(self.partial_path, self.path)

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
# Recovery
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RecoverReport:
    """Outcome of :func:`recover`.

    Attributes
    ----------
    message_count : int
        Messages copied to the new file.
    chunk_count : int
        Complete chunks read from the damaged file.
    schema_count, channel_count, metadata_count, attachment_count : int
        Records of each kind copied.
    end_time_ns : int or None
        Largest log time recovered [ns].
    bytes_read : int
        Bytes of complete records read.
    bytes_total : int
        Size of the damaged file [B].
    stop_reason : str
        Why reading stopped (``"footer"`` for an intact file, else the error at the cut).
    original_status : str or None
        ``status`` of a ``hydroplant.result`` record found in the input, if any.
    """

    message_count: int
    chunk_count: int
    schema_count: int
    channel_count: int
    metadata_count: int
    attachment_count: int
    end_time_ns: int | None
    bytes_read: int
    bytes_total: int
    stop_reason: str
    original_status: str | None


class _BoundedReader(io.RawIOBase):
    """Read-only view of the first ``limit`` bytes of a binary file."""

    def __init__(self, stream: BinaryIO, limit: int):
        self._stream = stream
        self._remaining = limit

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        size = min(len(buffer), self._remaining)
        if size <= 0:
            return 0
        data = self._stream.read(size)
        buffer[: len(data)] = data
        self._remaining -= len(data)
        return len(data)


def _complete_prefix(stream: BinaryIO, size: int) -> int:
    """Byte offset after the last record that lies entirely in the file."""
    if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        raise ValueError("not an MCAP file (bad magic)")
    offset = len(MCAP_MAGIC)
    while offset + RECORD_PREFIX.size <= size:
        stream.seek(offset)
        opcode, length = RECORD_PREFIX.unpack(stream.read(RECORD_PREFIX.size))
        end = offset + RECORD_PREFIX.size + length
        if end > size:
            break
        offset = end
        if opcode == Opcode.FOOTER:
            if offset + len(MCAP_MAGIC) <= size:
                offset += len(MCAP_MAGIC)
            break
    stream.seek(0)
    return offset


def recover(partial_path: str | os.PathLike, out_path: str | os.PathLike, *,
            overwrite: bool = False) -> RecoverReport:
    """Rebuild a valid, indexed MCAP from the complete records of a truncated file.

    Parameters
    ----------
    partial_path : str or Path
        Damaged file, typically ``run.mcap.partial`` left by a killed process.
    out_path : str or Path
        Output file (written via ``out_path.recovering`` and renamed). It may be the
        name the killed writer was aiming for, e.g. ``recover("run.mcap.partial", "run.mcap")``.
    overwrite : bool, optional
        Replace an existing ``out_path``; otherwise ``FileExistsError``.

    Returns
    -------
    RecoverReport

    Notes
    -----
    Reads sequentially with :class:`mcap.stream_reader.StreamReader` (chunk CRCs checked)
    up to the last complete record and copies schemas, channels, messages, metadata and
    attachments. Any ``hydroplant.result`` record is replaced by one with
    ``status="recovered"``.
    """
    partial_path = Path(partial_path)
    out_path = Path(out_path)
    if out_path.exists() and not overwrite:
        raise FileExistsError(f"{out_path} exists; pass overwrite=True")
    bytes_total = partial_path.stat().st_size
    schemas: dict[int, _McapSchema] = {}
    channels: dict[int, _McapChannel] = {}
    messages: list[_McapMessage] = []
    metadata: list[_McapMetadata] = []
    attachments: list[_McapAttachment] = []
    chunk_count = 0
    stop_reason = "end of data"
    library = ""
    with open(partial_path, "rb") as stream:
        limit = _complete_prefix(stream, bytes_total)
        reader = StreamReader(_BoundedReader(stream, limit), emit_chunks=True, validate_crcs=True)
        try:
            for record in reader.records:
                if isinstance(record, _McapChunk):
                    inner = breakup_chunk(record, validate_crc=True)  # all or nothing per chunk
                    chunk_count += 1
                else:
                    inner = [record]
                for item in inner:
                    if isinstance(item, _McapMessage):
                        messages.append(item)
                    elif isinstance(item, _McapSchema):
                        schemas.setdefault(item.id, item)
                    elif isinstance(item, _McapChannel):
                        channels.setdefault(item.id, item)
                    elif isinstance(item, _McapMetadata):
                        metadata.append(item)
                    elif isinstance(item, _McapAttachment):
                        attachments.append(item)
                    elif isinstance(item, _McapHeader):
                        library = item.library
            stop_reason = "footer"
        except EndOfFile:
            if limit == bytes_total:
                stop_reason = f"no footer: data ends at a record boundary after {limit} bytes"
            else:
                stop_reason = f"truncated record: {limit} of {bytes_total} bytes are complete records"
        except (McapError, ValueError, struct.error) as error:  # CRC mismatch, bad compression
            stop_reason = f"{type(error).__name__}: {error}"

    original_status = None
    kept_metadata = []
    for record in metadata:
        if record.name == RESULT_METADATA:
            original_status = record.metadata.get("status")
        else:
            kept_metadata.append(record)

    # Not ".partial": recover("run.mcap.partial", "run.mcap") must not overwrite its input.
    tmp_path = out_path.with_name(out_path.name + ".recovering")
    schema_map: dict[int, int] = {0: 0}
    channel_map: dict[int, int] = {}
    copied = 0
    end_time = None
    with open(tmp_path, "wb") as out:
        writer = Writer(out, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD)
        writer.start(profile="", library=library_string())
        for record in kept_metadata:
            writer.add_metadata(record.name, record.metadata)
        for record in attachments:
            writer.add_attachment(record.create_time, record.log_time, record.name, record.media_type, record.data)
        for schema_id, schema in schemas.items():
            schema_map[schema_id] = writer.register_schema(schema.name, schema.encoding, schema.data)
        for channel_id, channel in channels.items():
            if channel.schema_id in schema_map:
                channel_map[channel_id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schema_map[channel.schema_id], dict(channel.metadata))
        for message in messages:
            new_id = channel_map.get(message.channel_id)
            if new_id is None:
                continue
            writer.add_message(new_id, message.log_time, message.data, message.publish_time, message.sequence)
            copied += 1
            end_time = message.log_time if end_time is None else max(end_time, message.log_time)
        result = {"status": RunStatus.RECOVERED.value, "reason": stop_reason, "source": partial_path.name,
                  "message_count": str(copied)}
        if original_status is not None:
            result["original_status"] = original_status
        if library:
            result["source_library"] = library
        if end_time is not None:
            result["end_time_s"] = repr(end_time / NS_PER_S)
        writer.add_metadata(RESULT_METADATA, result)
        writer.finish()
    os.replace(tmp_path, out_path)
    return RecoverReport(
        message_count=copied, chunk_count=chunk_count, schema_count=len(schema_map) - 1,
        channel_count=len(channel_map), metadata_count=len(kept_metadata) + 1, attachment_count=len(attachments),
        end_time_ns=end_time, bytes_read=limit, bytes_total=bytes_total, stop_reason=stop_reason,
        original_status=original_status)


# ---------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------

# Foxglove arrays whose elements are keyed "<field>/<element name>" (list name dropped).
_NAMED_ARRAYS = {
    "foxglove.JointStates": ("joints", "name"),
    "foxglove.FrameTransforms": ("transforms", "child_frame_id"),
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
        Decoded messages, in log-time order.
    fields : list of str
        Numeric field names (nested objects joined with dots; for ``foxglove.JointStates``
        ``"position/<joint>"`` etc., for ``foxglove.FrameTransforms``
        ``"translation.x/<child_frame_id>"`` etc.; other arrays ``"name[i]..."``).
    text_fields : list of str
        Non-numeric (string) field names, see :meth:`text`.
    """

    def __init__(self, topic: str, schema_name: str, log_time: np.ndarray, messages: list[dict]):
        self.topic = topic
        self.schema_name = schema_name
        self.log_time = log_time
        self.t = log_time / NS_PER_S
        self.messages = messages
        named = _NAMED_ARRAYS.get(schema_name)
        count = len(messages)
        columns: dict[str, list] = {}
        for i, message in enumerate(messages):
            for key, value in _flatten_message(message, named).items():
                column = columns.get(key)
                if column is None:
                    column = columns[key] = [None] * count
                column[i] = value
        self._numeric: dict[str, np.ndarray] = {}
        self._text: dict[str, list] = {}
        for key, column in columns.items():
            if all(_is_number(v) for v in column):
                self._numeric[key] = np.array([np.nan if v is None else float(v) for v in column], dtype=np.float64)
            else:
                self._text[key] = column
        self.fields = list(self._numeric)
        self.text_fields = list(self._text)

    def field(self, name: str) -> np.ndarray:
        """Numeric column ``name`` as float64, shape (message_count,); ``null``/missing -> NaN."""
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
        return len(self.messages)


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
        with open(self.path, "rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            try:
                summary = reader.get_summary()
            except McapError:
                raise ValueError(f"{self.path} is not a finished MCAP file (no valid footer or summary); "
                                 "run recover() on it") from None
            if summary is None or summary.statistics is None:
                raise ValueError(f"{self.path} has no summary; it was not finished; run recover() on it")
            self.library = reader.get_header().library
            self.metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
            self.attachments: dict[str, bytes] = {}
            self.attachment_media_types: dict[str, str] = {}
            for attachment in reader.iter_attachments():
                self.attachments[attachment.name] = bytes(attachment.data)
                self.attachment_media_types[attachment.name] = attachment.media_type
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
        messages: list[dict] = []
        with open(self.path, "rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            for _, channel, message in reader.iter_messages(topics=[name], log_time_order=True):
                if channel.message_encoding != "json":
                    raise ValueError(f"topic {name!r} uses {channel.message_encoding!r}; only json is supported")
                log_times.append(message.log_time)
                messages.append(_loads(message.data))
        data = TopicData(name, self.schema_names[name], np.array(log_times, dtype=np.int64), messages)
        self._topic_cache[name] = data
        return data

    def __contains__(self, name: object) -> bool:
        return name in self.message_counts


def read_log(path: str | os.PathLike) -> RunLog:
    """Open a finished log for analysis; see :class:`RunLog`."""
    return RunLog(path)


def log_info(path: str | os.PathLike) -> str:
    """Human-readable summary of a log: run metadata, status, span, topics and counts.

    Parameters
    ----------
    path : str or Path
        A finished log; an unfinished file yields a one-paragraph note.
    """
    try:
        log = RunLog(path)
    except ValueError as error:
        return f"{path}: UNFINISHED: {error}"
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
    if log.attachments:
        lines.append("attachments: " + ", ".join(
            f"{name} ({log.attachment_media_types[name]}, {len(data)} B)" for name, data in log.attachments.items()))
    return "\n".join(lines)


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
    Topic ``/x`` of input ``p`` becomes ``/p/x``. In JSON messages with a ``foxglove.*``
    schema, ``frame_id``, ``parent_frame_id`` and ``child_frame_id`` become ``p/<id>``
    (except ``shared_frames``); other messages are copied byte for byte. Messages are
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
        with open(tmp_path, "wb") as out:
            writer = Writer(out, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD)
            writer.start(profile="", library=library_string())
            writer.add_metadata("hydroplant.merge", {prefix: Path(path).name for prefix, path in inputs.items()})
            schema_ids: dict[tuple[str, str, bytes], int] = {}
            channel_maps: list[dict[int, tuple[int, bool]]] = []
            for prefix, reader in zip(inputs, readers):
                summary = reader.get_summary()
                if summary is None:
                    raise ValueError(f"input {prefix!r} has no summary; recover() it first")
                for record in reader.iter_metadata():
                    writer.add_metadata(f"{prefix}/{record.name}", dict(record.metadata))
                for attachment in reader.iter_attachments():
                    writer.add_attachment(attachment.create_time, attachment.log_time, f"{prefix}/{attachment.name}",
                                          attachment.media_type, attachment.data)
                channel_map: dict[int, tuple[int, bool]] = {}
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
                    rewrite = (schema is not None and schema.name.startswith("foxglove.")
                               and channel.message_encoding == "json")
                    channel_map[channel_id] = (new_id, rewrite)
                channel_maps.append(channel_map)

            def tagged(index: int):
                for _, channel, message in readers[index].iter_messages(log_time_order=True):
                    yield message.log_time, index, channel.id, message

            prefixes = list(inputs)
            for _, index, channel_id, message in heapq.merge(*(tagged(i) for i in range(len(readers))),
                                                              key=lambda entry: (entry[0], entry[1])):
                new_id, rewrite = channel_maps[index][channel_id]
                data = message.data
                if rewrite:
                    data = to_json_bytes(_prefix_frames(_loads(data), prefixes[index], shared))
                writer.add_message(new_id, message.log_time, data, message.publish_time, message.sequence)
            writer.finish()
    finally:
        for stream in streams:
            stream.close()
    os.replace(tmp_path, out_path)
