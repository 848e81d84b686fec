"""Reading logs back: :func:`read_log` (topics as numpy columns), :func:`inspect_log` / :func:`log_info` /
:func:`log_summary`, :func:`merge_logs`.

:func:`read_log` reads CDR and JSON topics back as numpy columns with the field names of the
messages (``"p_cap_pa"``, ``"pressure_pa.supply"``, ``"position/<joint>"``,
``"translation.x/<frame>"``, ``"timestamp.nanosec"``); a CDR topic whose messages share one
layout is read as strided views of the message bytes (bit-exact floats).  A file that is not
MCAP, unfinished or damaged raises :class:`sim.io.mcap_file.LogReadError` (a ``CircuitError``)
naming it.

Example::

    log = read_log("run.mcap")
    boom = log.topic("/hydroplant/cylinders/boom")
    print(boom.t[-1], boom["p_cap_pa"].max())
"""

from __future__ import annotations

import heapq
import os
import re
import struct
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.records import Schema as McapSchema
from mcap.writer import CompressionType, Writer

from sim.io.log_recover import verify_log
from sim.io.log_schemas import (FRAME_TRANSFORMS, JOINT_STATES, MsgType, _CDR_BASE, _cdr_get, _Leaf, _loads, cdr_decode,
                                cdr_encode, ros2msg_type, to_json_bytes)
from sim.io.mcap_file import (DEFAULT_CHUNK_SIZE, MCAP_MAGIC, NS_PER_S, PARTIAL_SUFFIX, RESULT_METADATA, RUN_METADATA,
                              LogPathError, LogReadError, library_string, publish, refuse_special)

FRAME_ID_KEYS = ("frame_id", "parent_frame_id", "child_frame_id")  # rewritten by merge_logs
_PREFIX_PATTERN = re.compile(r"[A-Za-z0-9_.\-]+")

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
        except OSError:
            raise
        except Exception as error:  # noqa: BLE001 - a damaged summary: mcap's errors, parse errors
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
                            raise LogReadError(f"{self.path}: topic {name!r} uses {channel.message_encoding!r}; json "
                                               "and cdr (ros2msg) are supported, one per topic")
                        encoding, msg_type = "cdr", ros2msg_type(schema.name, schema.data.decode())
                    log_times.append(message.log_time)
                    datas.append(message.data)
        except LogReadError:
            raise
        except Exception as error:  # noqa: BLE001 - a damaged chunk: mcap's CRC error, zstd's or a parse error
            raise LogReadError(f"{self.path}: topic {name!r} cannot be read, the log is damaged "
                               f"({type(error).__name__}: {error}); 'hydroplant log recover {self.path}' keeps "
                               "every chunk that checks") from None
        times = np.array(log_times, dtype=np.int64)
        try:
            if msg_type is not None:
                data = TopicData.from_cdr(name, msg_type, times, datas)
            else:
                data = TopicData.from_messages(name, self.schema_names[name], times, [_loads(d) for d in datas])
        except (ValueError, TypeError, AttributeError, LookupError) as error:  # another program's payloads
            raise LogReadError(f"{self.path}: topic {name!r} holds messages that do not decode as {encoding} objects "
                               f"({type(error).__name__}: {error})") from None
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
    """Summary of a log and its state: ``(text, code)`` with code 1 when the verification found damage (a chunk that
    fails its CRC or does not decompress, unreadable bytes, an incomplete record at the end), else 0 (an unfinished
    log without damage is summarised as such: 0).

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
        if check is None and "not an MCAP file" in str(error):
            raise
        code = 1 if check is not None and check.damage else 0
        if check is not None and not check.footer:
            return "\n".join([f"{path}: UNFINISHED: no footer; run 'hydroplant log recover {path}'", *damage]), code
        return "\n".join([f"{path}: UNFINISHED: {error}", *damage]), code
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


def log_summary(path: str | os.PathLike, *, verify: bool = True) -> dict:
    """The facts of :func:`inspect_log` as a dict (the ``log info --json`` document, SI units).

    ``status`` is ``"ok"`` (no damage found), ``"damaged"`` (a chunk fails its CRC or does not decompress;
    exit status 1) or ``"unfinished"`` (no summary or footer, no damage found); ``run_status`` is the
    run's own ``hydroplant.result`` status (``complete``, ``diverged``, ``incomplete``, ``unknown``).
    Raises :class:`LogReadError` for a file that is not MCAP.
    """
    check = verify_log(path) if verify else None
    damage = [] if check is None else [{"start": d.start, "end": d.end, "what": d.what, "messages": d.messages}
                                       for d in check.damage]
    base = {"file": str(path), "verified": check is not None, "damage": damage,
            "chunks_verified": None if check is None else check.chunk_count}
    try:
        log = RunLog(path)
    except LogReadError as error:
        if check is None and "not an MCAP file" in str(error):
            raise
        return {**base, "status": "damaged" if damage else "unfinished", "run_status": "unknown", "message": str(error),
                "library": None, "run": {}, "result": {}, "start_time_s": None, "end_time_s": None,
                "message_count": None, "topics": [], "attachments": []}
    result = log.metadata.get(RESULT_METADATA, {})
    return {
        **base, "status": "damaged" if damage else "ok", "run_status": result.get("status", "unknown"), "message": "",
        "library": log.library, "run": log.metadata.get(RUN_METADATA, {}), "result": result,
        "start_time_s": log.start_time_ns / NS_PER_S, "end_time_s": log.end_time_ns / NS_PER_S,
        "message_count": log.message_count,
        "topics": [{"name": t, "schema": log.schema_names[t], "messages": log.message_counts[t]} for t in log.topics],
        "attachments": [{"name": n, "media_type": m, "size_b": size} for n, m, size in log.attachment_list],
    }


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
        Output file (written via ``out_path.partial``, created exclusively, and published
        without replacing another file unless ``overwrite``).
    shared_frames : iterable of str, optional
        Frame ids left unprefixed so that both trees hang off a common root.
    overwrite : bool, optional
        Replace an existing regular file ``out_path``; otherwise :class:`LogPathError`.

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
    refuse_special(out_path)
    if os.path.lexists(out_path) and not overwrite:
        raise LogPathError(f"{out_path} exists; pass overwrite=True to replace it")
    tmp_path = out_path.with_name(out_path.name + PARTIAL_SUFFIX)
    if os.path.lexists(tmp_path):
        raise LogPathError(f"{tmp_path} exists (left by an interrupted merge or being written); remove it first")
    streams = [open(path, "rb") for path in inputs.values()]
    created = False
    try:
        readers = [make_reader(stream, validate_crcs=True) for stream in streams]
        with open(tmp_path, "xb") as out:
            created = True
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
    except BaseException:
        if created:  # (ours: created exclusively above)
            tmp_path.unlink(missing_ok=True)
        raise
    finally:
        for stream in streams:
            stream.close()
    publish(tmp_path, out_path, overwrite)
