"""The log writer: :class:`LogWriter`, its channels (:class:`Channel`) and sample rows (:class:`Frame`).

The writer is built for a stepping loop. Samples are appended into numpy buffers
(:meth:`Channel.append`, or one row per sample for many topics with :class:`Frame`, a few
hundred ns) and encoded in batches, outside the loop body: the MCAP Message records of one
sample of every topic of a frame are one constant byte row (record headers, CDR templates
with their strings and padding) with slots, and a batch of samples is that row repeated and
its slots (sequences, log times, timestamps, float64 fields) filled row by row in one
compiled pass (:class:`_RecordRows`, numba). Batches of all channels are merged in log-time
order, sample by sample, and handed whole to the chunks of
:class:`sim.io.mcap_file.ChunkedWriter`, so every file is globally ordered by ``log_time``;
chunks are compressed with zstd at level -2 and written, in order, by one background thread
while the caller goes on stepping.  A batch holding :class:`Frame` rows (a stepping loop's
bulk) is encoded, merged and added to the chunks on that thread as well: the caller hands the
frame's buffer over (the next rows go into another one) and goes on; the file is byte for byte
the one written in the caller's thread (``chunk_thread=False``).  JSON channels take irregular
messages one by one (:meth:`Channel.write`).

Output safety: the file is written to ``PATH.partial``, created exclusively
(``O_CREAT | O_EXCL``) and locked, so two writers never share it; an existing ``.partial`` is
never deleted unless ``overwrite=True``; the finished file is published as ``PATH`` without
replacing an existing file (a hard link, then the ``.partial`` is removed) unless
``overwrite=True``; a ``PATH`` that is not a regular file is always refused.

Example::

    with LogWriter("run.mcap", dt=1e-3) as log:
        pump = log.cdr_channel("/pump", flat_schema("t_msgs/msg/Pump", {"p_pa": "p [Pa]"}), fields=["p_pa"])
        for step in range(1000):
            pump.append(step, (2e7,))
"""

from __future__ import annotations

import bisect
import json
import math
import os
import signal
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numba
import numpy as np

from sim.io.log_schemas import (JOINT_STATES, TIME, TIMESTAMP, Column, MsgType, _CdrTemplate, _cdr_template,
                                _definition_bytes, _fields_template, _LayoutKey, _ros_type_name, _step_log_times,
                                _timestamp, cdr_encode, step_log_time, to_json_bytes)
from sim.io.mcap_file import (DEFAULT_CHUNK_SIZE, MESSAGE_RECORD, NS_PER_S, PARTIAL_SUFFIX, RESULT_METADATA,
                              RUN_METADATA, ChunkedWriter, LogPathError, RecordStream, RunStatus, library_string,
                              publish, refuse_special)

# sim time between forced chunk ends [s]: at the default 100 Hz an excavator sample is ≈ 3 kB (0.9 kB of it the
# cylinder scene), so a 256 KiB chunk fills in ≈ 0.9 s and each 2 s flush ends two full chunks and a small one; each
# flush costs the batch's checks in the caller's thread and its fields, encoding and chunk end on the chunk thread,
# whatever the chunk holds
DEFAULT_FLUSH_INTERVAL = 2.0
DEFAULT_BATCH_SIZE = 1024  # buffered samples per channel before a batch encode
# rows of a Frame's first buffer: it grows (doubling) to the rows a batch takes, so a rare log (a sample a second,
# a few rows per periodic flush) never fills and pages in a whole batch of NaN rows (203 columns × 1024 rows = 1.7 MB
# for the excavator) per buffer
FRAME_FIRST_ROWS = 64

# ---------------------------------------------------------------------------------------
# MCAP Message records of many samples at once
# ---------------------------------------------------------------------------------------

_MESSAGE_RECORD = MESSAGE_RECORD
_MESSAGE_RECORD_OVERHEAD = _MESSAGE_RECORD.size  # 31 B before the message data



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


@dataclass(frozen=True)
class _EncodeJob:
    """Rows of a :class:`Frame` buffer that become one :class:`_RecordBlock` when encoded (on the chunk thread).

    The rows ``rows`` (a slice or indexes) of the first ``count`` rows of ``buffer`` at ``log_times``
    [ns], member i's sequence numbers from ``first_sequences[i]``; ``order`` and ``serial`` as in
    :class:`_RecordBlock`.  ``fills`` (on the first job of a buffer): rows still to be written,
    ``(first row, fill, lo, hi)`` for ``fill(buffer[first:first + hi - lo], lo, hi)`` (see
    :meth:`Frame.defer`), run before anything is encoded.  ``spares`` (on the last job of a
    buffer): where the buffer goes once encoded, for the frame to fill again.
    """

    records: _RecordRows
    buffer: np.ndarray
    count: int
    rows: Any
    log_times: np.ndarray
    first_sequences: list[int]
    order: int
    serial: int
    fills: tuple = ()
    spares: list[np.ndarray] | None = None

    def block(self) -> _RecordBlock:
        for first, fill, lo, hi in self.fills:
            fill(self.buffer[first:first + hi - lo], lo, hi)
        rows = self.records.encode(self.buffer[:self.count][self.rows], self.log_times, self.first_sequences)
        if self.spares is not None:
            self.spares.append(self.buffer)  # (list.append is atomic: the frame pops it in the caller's thread)
        return _RecordBlock(self.log_times, rows, self.records.channel_ids, self.records.offsets, self.order,
                            self.serial)


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
class ChannelInfo:
    """What a log channel is, as written in its MCAP Schema and Channel records (handed to a :class:`LogTee`).

    Attributes
    ----------
    id : int
        MCAP channel id (from 1), the ``channel_id`` of its messages.
    topic : str
        Topic name.
    schema_name, schema_encoding : str
        Schema name and encoding (``"ros2msg"`` or ``"jsonschema"``).
    schema_data : bytes
        Schema text (``ros2msg`` definition or JSON Schema).
    message_encoding : str
        ``"cdr"`` or ``"json"``.
    metadata : dict of str
        Channel metadata.
    """

    id: int
    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    metadata: Mapping[str, str]


class LogTee:
    """Receiver of a copy of everything a :class:`LogWriter` writes (see :meth:`LogWriter.add_tee`): a live stream
    of the log's topics.  Subclass it and override both methods.

    Calls come from the thread that writes the log (the drain of a batch), so they should be quick: copy the
    bytes out, do not block.
    """

    def channel(self, info: ChannelInfo) -> None:
        """A channel of the log: every channel registered before the tee was added, then each new one."""

    def messages(self, records: Sequence[tuple[int, int, bytes]]) -> None:
        """Messages in log-time order, as written to the file: ``(channel id, log time [ns], message data)``."""


def stream_messages(stream: RecordStream) -> list[tuple[int, int, bytes]]:
    """The messages of a record stream as ``(channel id, log time [ns], message data)``, in stream order.

    Reads the MCAP Message records (``opcode, record length, channel, sequence, log time,
    publish time`` then the data) at the offsets the stream lists.
    """
    found = []
    for _, _, offsets in stream.messages:
        found.append(offsets.reshape(-1))
    if not found:
        return []
    starts = np.sort(np.concatenate(found))
    data = stream.data
    raw = data.tobytes() if not data.flags.c_contiguous else memoryview(data).cast("B")
    out = []
    for start in starts.tolist():
        _, length, channel_id, _, log_time, _ = _MESSAGE_RECORD.unpack_from(raw, start)
        begin = start + _MESSAGE_RECORD_OVERHEAD
        out.append((channel_id, log_time, bytes(raw[begin:start + 9 + length])))
    return out


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
        n = self._next_row(step_index)
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
        n = self._next_row(step_index)
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

    def _next_row(self, step_index: int) -> int:
        """Index of the buffer row for a sample at ``step_index`` (after any flush it needs); ValueError if
        ``step_index`` is before the channel's previous sample."""
        n = self._count
        if n == self._capacity or step_index >= self._writer._next_flush_step:
            n = self._prepare(step_index)
        if step_index < self._last_step:
            raise ValueError(f"{self.topic}: step_index {step_index} is before the previous one {self._last_step}")
        return n

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
            writer._drain(end_chunk=False, wait=False)
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
        row = self.claim(step_index).reshape(3, len(self.joint_names))  # (position, velocity, effort) rows
        row[0] = position
        row[1] = np.nan if velocity is None else velocity
        row[2] = np.nan if effort is None else effort
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
        self._capacity = capacity  # rows per batch; the buffer holding them grows as rows come (_room)
        self._values = np.full((min(capacity, FRAME_FIRST_ROWS), self.column_count), np.nan)
        self._steps = np.empty(capacity, dtype=np.int64)
        self._count = 0
        self._last_step = -1
        self._members: list[tuple[Channel, np.ndarray | slice, int]] = []  # (channel, columns, every)
        self._records: dict[tuple[int, ...], _RecordRows] = {}  # per set of members fed together, their records
        self._jobs: list[_EncodeJob] = []  # rows taken from the buffer, to encode
        self._spares: list[np.ndarray] = []  # buffers whose rows are encoded, to fill again
        self._fills: list[tuple[int, Callable[[np.ndarray, int, int], None], int, int]] = []  # rows of defer()

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
                writer._drain(end_chunk=False, wait=False)
        if step_index < self._last_step:
            raise ValueError(f"frame: step_index {step_index} is before the previous one {self._last_step}")
        n = self._count
        if n == len(self._values):
            self._room(n + 1)
        self._steps[n] = step_index
        return self._values[n]

    def _room(self, rows: int) -> None:
        """Grow the buffer to hold ``rows`` rows (at least doubling it, at most the batch's ``capacity``): the rows it
        had are kept, the new ones are NaN."""
        values = self._values
        if rows <= len(values):
            return
        grown = np.full((min(self._capacity, max(rows, 2 * len(values))), self.column_count), np.nan)
        grown[:len(values)] = values
        self._values = grown

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
        values = np.asarray(values, dtype=np.float64)
        k = np.size(step_index)
        if values.shape != (k, self.column_count):
            raise ValueError(f"frame: `values` must have shape ({k}, {self.column_count}), got {values.shape}")

        def store(n: int, i: int, j: int) -> None:
            self._values[n:n + j - i] = values[i:j]
        self._take_rows(step_index, store)

    def defer(self, step_index: Sequence[int] | np.ndarray, fill: Callable[[np.ndarray, int, int], None]) -> None:
        """Buffer rows for steps ``step_index`` whose values are written later, by ``fill(out, lo, hi)``: rows
        ``lo:hi`` of these rows into ``out`` (shape (hi - lo, column_count), SI; every column a channel reads).

        As :meth:`extend` (the same file, byte for byte, as ``extend`` of what ``fill`` writes),
        but ``fill`` runs when the batch is encoded: on the writer's chunk thread while the
        caller goes on, or in the caller's thread when it drains there (a tee, no chunk
        thread).  ``fill`` must read only what nothing changes until it has run (e.g. a
        buffer the caller hands over), and may be called for several ranges, each once.
        """
        def store(n: int, i: int, j: int) -> None:
            self._fills.append((n, fill, i, j))
        self._take_rows(step_index, store)

    def _take_rows(self, step_index: Sequence[int] | np.ndarray, store: Callable[[int, int, int], None]) -> None:
        """Buffer rows for steps ``step_index`` (non-decreasing): ``store(n, i, j)`` puts rows ``i:j`` of them at buffer
        row ``n``, after the periodic flushes and batch drains due before them; SIGINT held back until all are in."""
        steps = np.asarray(step_index, dtype=np.int64).ravel()
        k = len(steps)
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
                        writer._drain(end_chunk=False, wait=False)
                j = min(k, i + self._capacity - self._count)
                if math.isfinite(writer._next_flush_step):  # stop before the next periodic flush
                    # (bisect keeps the GIL: numpy's search drops it, and the chunk thread, woken by the flush just
                    # handed over, would take it for its Python and keep this thread waiting up to the switch interval)
                    j = bisect.bisect_left(steps, writer._next_flush_step, i, j)
                j = max(j, i + 1)
                n = self._count
                self._room(n + j - i)
                store(n, i, j)
                self._steps[n:n + j - i] = steps[i:j]
                self._count = n + j - i
                self._last_step = int(steps[j - 1])
                i = j

    def _encode(self) -> None:
        """Take the buffered rows as encode jobs (:class:`_EncodeJob`, encoded by the writer's drain): one block of the
        members fed by every buffered row (those with ``every`` 1 or dividing every row's step, as /tf at the log
        rate) and one per other ``every``, of its members' messages at the rows at multiples of it; each channel is
        in one block, in log-time order.  Sequence numbers and serials are given here, in the caller's thread, so
        the file does not depend on where the jobs are encoded.  The jobs take the buffer itself (and the rows still
        to be filled, :meth:`defer`): the next rows go into a spare one."""
        n = self._count
        if n == 0 or not self._members:
            self._count, self._fills = 0, []
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
        buffer, fills = self._values, tuple(self._fills)
        for g, (group, rows) in enumerate(groups):
            members = [self._members[m][:2] for m in group]
            records = self._records.get(group)
            if records is None:
                records = self._records[group] = _RecordRows([(c._channel_id, c._template, columns) for c, columns in members])
            times = log_times[rows]
            first_sequences = [c._sequence + 1 for c, _ in members]
            last = int(steps[rows][-1])
            for channel, _ in members:
                channel._sequence += len(times)
                channel._last_step = last
            self._jobs.append(_EncodeJob(records, buffer, n, rows, times, first_sequences,
                                         min(c._order for c, _ in members), self._writer._next_serial(),
                                         fills if g == 0 else (), self._spares if g == len(groups) - 1 else None))
        if groups:  # the buffer goes with the jobs; the next rows go into a spare one, or a new one as large as they were
            self._values = (self._spares.pop() if self._spares else
                            np.full((min(self._capacity, max(FRAME_FIRST_ROWS, 1 << (n - 1).bit_length())),
                                     self.column_count), np.nan))
        self._count, self._fills = 0, []

    def _take_jobs(self) -> list[_EncodeJob]:
        """Encode jobs of the rows taken so far, buffered rows included."""
        self._encode()
        jobs, self._jobs = self._jobs, []
        return jobs


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
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # held until the file is closed
        except OSError:  # a file system without locks: O_EXCL alone keeps a second writer out
            pass
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
        Encode the batches of frame rows and compress and write finished zstd chunks on a
        background thread (the compiled encoding, zstd, crc32, the file writes and MuJoCo's
        ``mj_step`` all release the GIL, so they overlap the stepping on a second core). The
        file is byte for byte the same either way; ``False`` does all the work in the caller's
        thread.

    Notes
    -----
    What a SIGKILL can lose is bounded by the larger of ``flush_interval`` of simulation
    time and ``chunk_size`` bytes of messages plus ``batch_size`` samples per channel,
    plus, with the chunk thread, the batches and chunks handed to it and not yet written (at
    most ``ChunkedWriter.MAX_PENDING_CHUNKS``; a periodic flush or a full batch does not wait
    for them, an explicit :meth:`flush`, :meth:`drain` or :meth:`close` does); everything before is in complete chunks on disk and
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
        self._infos: list[ChannelInfo] = []
        self._tees: list[LogTee] = []
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

    def add_tee(self, tee: LogTee) -> None:
        """Hand ``tee`` every channel of the log (those registered so far at once) and, at each drain, the messages
        written to the file, as they are written (same bytes, same log times).

        For a live view of the log's topics (:class:`sim.live.foxglove_live.FoxgloveLive`).  Messages reach the tee
        when the writer drains its buffers: at a batch, a periodic flush, :meth:`drain`, :meth:`flush` and
        :meth:`close`; a live view calls :meth:`drain` once per frame.  A tee does not change the file.
        """
        self._check_open()
        self._tees.append(tee)
        for info in self._infos:
            tee.channel(info)

    def drain(self) -> None:
        """Encode every buffered sample and add it to the chunk in progress without ending the chunk (what a batch
        drain does); the messages reach the tees (:meth:`add_tee`) now.  Call it after a frame's samples are all
        buffered: a message written later for an earlier step would follow them in the file."""
        self._check_open()
        self._drain(end_chunk=False)

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
        info = ChannelInfo(channel_id, topic, schema_name, schema_encoding, bytes(schema_bytes), message_encoding,
                           _str_dict("metadata", metadata))
        self._infos.append(info)
        for tee in self._tees:
            tee.channel(info)
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
        """Hand every buffered sample to the chunks: a batch with frame rows is encoded, merged and added on the chunk
        thread (in the caller's one with a tee, so that the tees have the messages on return, or without the
        thread); ``end_chunk`` ends the chunk after it; ``wait`` returns only once all is in the file."""
        jobs = [job for frame in self._frames for job in frame._take_jobs()]
        blocks = [block for channel in self._channels for block in channel._take_encoded()]
        if jobs or blocks:
            self._last_step = max(self._last_step, max(c._last_step for c in self._channels))
            if jobs and not self._tees:
                if not wait:  # the batch, the chunk's end and the flush in one hand-over to the chunk thread
                    self._writer.defer(self._write_batch_and_flush, jobs, blocks, end_chunk)
                    return
                self._writer.defer(self._write_batch, jobs, blocks, ())
            else:
                self._write_batch(jobs, blocks, tuple(self._tees))
        if end_chunk:
            self._writer.flush(wait=wait)
        else:
            self._writer.flush_stream()
            if wait:
                self._writer.settle()

    def _write_batch(self, jobs: list[_EncodeJob], blocks: list[_RecordBlock], tees: Sequence[LogTee]) -> None:
        """Encode ``jobs``, merge them with ``blocks`` in log-time order, add the records to the chunks and hand the
        messages to ``tees``."""
        stream = _merge_blocks([job.block() for job in jobs] + blocks)
        self._writer.add_records(stream)
        if tees:
            records = stream_messages(stream)
            for tee in tees:
                tee.messages(records)

    def _write_batch_and_flush(self, jobs: list[_EncodeJob], blocks: list[_RecordBlock], end_chunk: bool) -> None:
        """:meth:`_write_batch` (no tees), then end the chunk (``end_chunk``) and flush the stream: a job of the chunk
        thread, as ``_drain_now(end_chunk, wait=False)`` hands them over."""
        self._write_batch(jobs, blocks, ())
        if end_chunk:
            self._writer.end_chunk()
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
