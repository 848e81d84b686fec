"""MCAP files on the public record API: a chunked writer for batches of Message records, and a damage-tolerant scanner.

An MCAP file (specification: https://mcap.dev/spec) is the magic ``\\x89MCAP0\\r\\n``, a Header
record, the data section, a DataEnd record, the summary section, a Footer record and the magic
again.  Every record is ``opcode (uint8) | length (uint64, little endian) | body of length
bytes``.  The data section here holds, in order of writing: Schema and Channel records (outside
chunks, so a damaged chunk never takes a channel definition with it), Metadata and Attachment
records, and Chunk records, each followed by one MessageIndex record per channel of the chunk.
A Chunk body is ``message_start_time, message_end_time, uncompressed_size (uint64),
uncompressed_crc (uint32, CRC-32 of the uncompressed records), compression (string),
records (uint64 length + compressed bytes)``; the records inside are Message records.
The summary repeats the schemas and channels and holds the Statistics, ChunkIndex,
AttachmentIndex, MetadataIndex and SummaryOffset records; the Footer carries the summary's
CRC-32.

:class:`ChunkedWriter` writes such a file from ready Message records (:meth:`ChunkedWriter.add_records`,
a whole batch at a time), compressing and writing each finished chunk on one background
thread; a caller can hand that thread whole batches to build first (:meth:`ChunkedWriter.defer`).
:func:`scan` reads a file record by record and survives damage: a record that does not
parse, or a chunk whose CRC or decompression fails, is skipped and reading resumes at the next
record that parses (after a chunk whose length is intact) or at the next Chunk opcode whose
chunk decompresses to its CRC; message indexes are never needed.

The record classes come from ``mcap.records`` (public API); nothing of ``mcap.writer`` is used.

Example::

    with open("x.mcap", "wb") as stream:
        writer = ChunkedWriter(stream, chunk_size=256 * 1024)
        writer.start(library="me")
        schema = writer.register_schema("t", "jsonschema", b"{}")
        channel = writer.register_channel("/t", "json", schema)
        ...  # writer.add_records(stream_of_message_records)
        writer.finish()
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import enum
import io
import mmap
import os
import stat
import struct
import threading
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import mcap
import numpy as np
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap import records as mr

from hydraulics.components import CircuitError

from sim import version

RUN_METADATA = "hydroplant.run"  # metadata record written at construction
RESULT_METADATA = "hydroplant.result"  # metadata record written at close
PARTIAL_SUFFIX = ".partial"  # suffix of the file while it is being written
NS_PER_S = 1_000_000_000  # nanoseconds per second
DEFAULT_CHUNK_SIZE = 256 * 1024  # uncompressed bytes per chunk [B] (see ChunkedWriter.ZSTD_LEVEL)
MCAP_MAGIC = b"\x89MCAP0\r\n"
RECORD_PREFIX = struct.Struct("<BQ")  # opcode (uint8) + record length (uint64)
MESSAGE_RECORD = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log time, publish time
_CHUNK_FIXED = struct.Struct("<QQQII")  # start time, end time, uncompressed size, crc, compression string length
_COMPRESSIONS = {"zstd": "zstd", "lz4": "lz4", "none": ""}  # LogWriter name -> MCAP chunk compression string
_MAX_UNCOMPRESSED = 1 << 28  # a chunk claiming more is damaged [B] (writers cut chunks at a few MB; ours at 256 KiB)
# The largest ratio uncompressed / compressed size each chunk compression can reach: a zstd block of
# 128 KiB can be a 4-byte RLE block; an LZ4 match grows by 255 B per byte. A chunk claiming more than
# its compressed bytes can hold is damaged, found before anything is allocated.
_MAX_RATIO = {"zstd": 1 << 15, "lz4": 256}
_FRAME_SLACK = 64  # B: frame header and end mark, beyond the ratio
_PIECE = 1 << 20  # B decompressed at a time: memory grows with the data a frame really yields


class LogPathError(CircuitError):
    """A log cannot be written where asked: the target exists, is not a regular file, or is in use."""


class LogReadError(CircuitError):
    """A file is not a readable MCAP log: not MCAP, damaged or unfinished; the message names the file."""


class RunStatus(str, enum.Enum):
    """Values of ``status`` in the ``hydroplant.result`` metadata record."""

    COMPLETE = "complete"
    DIVERGED = "diverged"
    INCOMPLETE = "incomplete"
    RECOVERED = "recovered"


def library_string() -> str:
    """Header library string ``"hydroplant/<version> mcap-python/<version>"``."""
    return f"hydroplant/{version()} mcap-python/{mcap.__version__}"


def refuse_special(path: Path) -> None:
    """Refuse a ``path`` that exists and is not a regular file (a folder, device, FIFO or socket)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as error:
        raise LogPathError(f"{path}: cannot write a log there ({error.strerror or error})") from None
    if not stat.S_ISREG(mode):
        raise LogPathError(f"{path}: exists and is not a regular file; a log is written only to a new or "
                           "regular file")


def publish(partial: Path, path: Path, overwrite: bool) -> None:
    """Give the finished ``partial`` its final name ``path``: never over an existing file unless ``overwrite``."""
    refuse_special(path)
    if overwrite:
        os.replace(partial, path)
        return
    try:
        os.link(partial, path)  # fails if path exists: no window in which another file is replaced
    except FileExistsError:
        raise LogPathError(f"{path} appeared while the run was written; the finished log is kept as {partial}; "
                           "rename it or pass --overwrite") from None
    except OSError:  # a file system without hard links
        if os.path.lexists(path):
            raise LogPathError(f"{path} appeared while the run was written; the finished log is kept as {partial}; "
                               "rename it or pass --overwrite") from None
        os.rename(partial, path)
        return
    partial.unlink()


def _record_bytes(record: mr.McapRecord) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


def _compressor(compression: str) -> Callable[[bytes], bytes]:
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdCompressor(level=ChunkedWriter.ZSTD_LEVEL).compress
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.compress
    return bytes


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """The ``size`` bytes a chunk's ``data`` decompress to; ValueError when they cannot be, without allocating more
    than the compressed bytes can yield (a frame's own claimed content size is never trusted)."""
    if compression == "":
        return bytes(data)
    ratio = _MAX_RATIO.get(compression)
    if ratio is None:
        raise ValueError(f"unknown chunk compression {compression!r}")
    if size > ratio * len(data) + _FRAME_SLACK:
        raise ValueError(f"claims {size} B uncompressed from {len(data)} B of {compression}, more than "
                         f"{compression} can hold")
    pieces, total = [], 0
    for piece in _pieces(compression, data):
        total += len(piece)
        if total > size:
            raise ValueError(f"decompresses to more than its stated {size} B")
        pieces.append(piece)
    return b"".join(pieces)


def _pieces(compression: str, data: bytes) -> Iterator[bytes]:
    """The decompressed bytes of one frame, :data:`_PIECE` at a time."""
    if compression == "zstd":
        import zstandard

        with zstandard.ZstdDecompressor().stream_reader(bytes(data)) as reader:
            while piece := reader.read(_PIECE):
                yield piece
        return
    import lz4.frame

    decompressor = lz4.frame.LZ4FrameDecompressor()
    piece = decompressor.decompress(bytes(data), max_length=_PIECE)
    while True:
        yield piece
        if decompressor.eof:
            return
        if decompressor.needs_input:
            raise ValueError("the LZ4 frame ends early")
        piece = decompressor.decompress(b"", max_length=_PIECE)


@dataclass(frozen=True)
class RecordStream:
    """Message records of several channels in log-time order, unit (sample) after unit.

    Unit u ends at byte ``unit_ends[u]`` of ``data`` (uint8, the units one after the other), at
    ``unit_times[u]`` [ns].  ``messages`` holds per block the units of its rows (ascending),
    its channel ids and, for row r and member j, the stream offset of that message:
    ``(units (n,), channel_ids (m,), offsets (n, m))``.
    """

    data: np.ndarray
    unit_ends: np.ndarray
    unit_times: np.ndarray
    messages: list[tuple[np.ndarray, np.ndarray, np.ndarray]]


class ChunkedWriter:
    """Write an MCAP file from batches of ready Message records, in zstd (or lz4, or plain) chunks, all indexes.

    Parameters
    ----------
    stream : binary file
        Output, positioned at its start.
    chunk_size : int
        A chunk ends after the sample that takes its uncompressed records past this [B].
    compression : {"zstd", "lz4", "none"}
        Chunk compression; zstd at :attr:`ZSTD_LEVEL`.
    chunk_thread : bool
        Compress, checksum and write finished chunks on one background thread (zstd, crc32
        and file writes release the GIL), in the order they were finished; every other write
        goes through the same queue, so the file is byte for byte the one written inline.

    Notes
    -----
    A write failing on the chunk thread is kept and raised by the next call that hands it
    work or waits for it; nothing is written after it (the offsets would be unknown).

    Jobs handed over with :meth:`defer` run on the chunk thread in order; the chunk in
    progress is theirs while any is queued, so :meth:`add_records` and :meth:`end_chunk`
    called from another thread first wait for the queue (:meth:`settle`), and
    :meth:`flush` queues its chunk end behind them.  Inside a job every method acts at once.
    What a caller would hand over only to wait for it (the records written outside chunks
    when it settles the queue; :meth:`flush` with ``wait`` when nothing is queued) runs in its
    own thread, the thread left asleep: a hand-over wakes the thread, which then takes
    Python's GIL for its Python parts, and a caller still running Python waits for it to be
    handed back (up to the interpreter's switch interval, 5 ms).  Each hand-over is one
    wake-up: the records written outside chunks go with the job that follows them.
    """

    # zstd's fast level -2 on the message records of the dig logged every step, in one run (CPU time): 965 MB/s at a
    # ratio of 2.83 in 256 KiB chunks, against 853 MB/s at 2.75 in 512 KiB chunks (the chunk and zstd's tables stay in
    # a core's cache) and 1000 MB/s at 2.80 in 128 KiB; level -1 830 MB/s at 3.02, level 1 683 MB/s at 2.90
    ZSTD_LEVEL = -2
    MAX_PENDING_CHUNKS = 4  # jobs handed to the chunk thread and not yet done (≤ 4 × chunk_size of memory)

    def __init__(self, stream: BinaryIO, *, chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd",
                 chunk_thread: bool = True):
        if compression not in _COMPRESSIONS:
            raise ValueError(f"`compression` must be one of {sorted(_COMPRESSIONS)}, got {compression!r}")
        self._stream = stream
        self._chunk_size = int(chunk_size)
        self._compression = _COMPRESSIONS[compression]
        self._compress: Callable[[bytes], bytes] | None = None  # made on the thread that first needs it
        self._chunk_thread = chunk_thread
        self._pool: concurrent.futures.ThreadPoolExecutor | None = None
        self._pending: collections.deque[concurrent.futures.Future] = collections.deque()
        self._failure: BaseException | None = None
        self._inside = threading.local()  # .job is True on the chunk thread while it runs a job
        self._outbox: list[tuple[Any, Callable[[int, int], None] | None, int | None]] = []  # see _write
        # the chunk in progress
        self._pieces: list[np.ndarray] = []
        self._chunk_bytes = 0
        self._chunk_messages = 0
        self._chunk_times = (0, 0)
        self._chunk_indexes: dict[int, list[np.ndarray]] = {}
        # the summary
        self._schemas: list[mr.Schema] = []
        self._channels: list[mr.Channel] = []
        # the records of these summary groups, serialised when they are written (chunk indexes on the chunk thread)
        self._summary_bytes: dict[int, list[bytes]] = {Opcode.SCHEMA: [], Opcode.CHANNEL: [], Opcode.CHUNK_INDEX: []}
        self._chunk_index_records: list[mr.ChunkIndex] = []
        self._attachment_indexes: list[mr.AttachmentIndex] = []
        self._metadata_indexes: list[mr.MetadataIndex] = []
        self._channel_counts: collections.Counter[int] = collections.Counter()
        self._message_times = (0, 0)
        self.message_count = 0

    # -- the chunk thread ------------------------------------------------------------

    def _outside(self) -> bool:
        """Whether the caller is not the chunk thread while there is one (jobs it queued may still be running)."""
        return self._chunk_thread and not getattr(self._inside, "job", False)

    def _submit(self, job: Callable[..., None], *args: Any) -> None:
        """Run ``job(*args)`` on the chunk thread (inline without one, or when called from a job), after every job
        submitted before it and the records written outside chunks so far (:meth:`_write`; those are the caller's:
        a job on the chunk thread leaves them to it)."""
        if self._outbox and not getattr(self._inside, "job", False):
            box, self._outbox = self._outbox, []
            self._submit_one(self._write_box_then, box, job, args)  # (one hand-over: each wakes the thread)
            return
        self._submit_one(job, *args)

    def _write_box_then(self, box: list, job: Callable[..., None], args: tuple) -> None:
        self._write_box(box)
        job(*args)

    def _now(self, job: Callable[..., None], *args: Any) -> None:
        """Run ``job(*args)`` in the caller's thread once every job handed over before is done, as the chunk thread
        would run it next (the records written outside chunks first; the methods it calls act at once): for a caller
        that waits for the job anyway, without waking the thread and waiting for it to hand the GIL back.  A failure is
        kept as a failed job's is, and raised."""
        while self._pending:
            self._pending.popleft().result()
        self._raise_failure()
        inside = getattr(self._inside, "job", False)
        self._inside.job = True
        try:
            if self._outbox:
                box, self._outbox = self._outbox, []
                self._write_box(box)
            job(*args)
        except BaseException as error:
            self._failure = error
            raise
        finally:
            self._inside.job = inside

    def _submit_one(self, job: Callable[..., None], *args: Any) -> None:
        if not self._outside():
            job(*args)
            return
        self._raise_failure()
        if self._pool is None:
            self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="mcap-chunks")
        while len(self._pending) >= self.MAX_PENDING_CHUNKS:
            self._pending.popleft().result()
        self._pending.append(self._pool.submit(self._guarded, job, args))

    def _guarded(self, job: Callable[..., None], args: tuple) -> None:
        if self._failure is not None:  # after a failed write the stream's offsets are unknown: write nothing more
            return
        self._inside.job = True
        try:
            job(*args)
        except BaseException as error:  # noqa: BLE001 - raised in the caller's thread by _raise_failure
            self._failure = error
        finally:
            self._inside.job = False

    def defer(self, job: Callable[..., None], *args: Any) -> None:
        """Run ``job(*args)`` on the chunk thread after everything handed to it before (at once without a thread),
        e.g. encode a batch and :meth:`add_records` it while the caller goes on.  At most
        :attr:`MAX_PENDING_CHUNKS` jobs wait: the caller blocks until the oldest is done (a bounded queue).  A job's
        exception is raised by the next call that hands over work or waits (:meth:`settle`), and nothing is
        written after it."""
        self._submit(job, *args)

    def _raise_failure(self) -> None:
        if self._failure is not None:
            raise self._failure

    def settle(self) -> None:
        """Wait until the chunk thread has written everything handed to it; raise the error of a failed write."""
        while self._pending:
            self._pending.popleft().result()
        self._raise_failure()
        if self._outbox and self._outside():
            self._now(lambda: None)  # the records written outside chunks, after everything handed over before
        elif self._outbox:
            self._submit(lambda: None)

    def stop_thread(self) -> None:
        """Settle and end the chunk thread (idempotent; later writes are inline)."""
        self._chunk_thread = False
        try:
            self.settle()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None

    # -- records outside chunks --------------------------------------------------------

    def _write(self, record: Any, index: Callable[[int, int], None] | None = None, summary: int | None = None) -> None:
        """Write ``record`` (bytes, or a ``mcap.records`` record) at the end of the stream: kept until the next job is
        handed to the chunk thread, then serialised and written there with the others kept (one job instead of one per
        record, the serialisation off the caller's thread); ``index(offset, length)`` records where, ``summary``: the
        opcode of the summary group that repeats it."""
        self._outbox.append((record, index, summary))

    def _write_box(self, box: list[tuple[Any, Callable[[int, int], None] | None, int | None]]) -> None:
        for record, index, summary in box:
            data = record if isinstance(record, bytes) else _record_bytes(record)
            if summary is not None:
                self._summary_bytes[summary].append(data)
            if index is not None:
                index(self._stream.tell(), len(data))
            self._stream.write(data)

    def start(self, *, profile: str = "", library: str = "") -> None:
        """Write the magic and the Header record."""
        self._write(MCAP_MAGIC + _record_bytes(mr.Header(profile, library or library_string())))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a Schema record; return its id (from 1)."""
        schema = mr.Schema(id=len(self._schemas) + 1, data=bytes(data), encoding=encoding, name=name)
        self._schemas.append(schema)
        self._write(schema, summary=Opcode.SCHEMA)  # (its bytes are written again in the summary)
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str] | None = None) -> int:
        """Write a Channel record; return its id (from 1)."""
        channel = mr.Channel(id=len(self._channels) + 1, topic=topic, message_encoding=message_encoding,
                             metadata=dict(metadata or {}), schema_id=schema_id)
        self._channels.append(channel)
        self._write(channel, summary=Opcode.CHANNEL)
        return channel.id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a Metadata record (indexed)."""
        self._write(mr.Metadata(name=name, metadata=dict(data)),
                    lambda offset, length: self._metadata_indexes.append(mr.MetadataIndex(offset, length, name)))

    def add_attachment(self, create_time: int, log_time: int, name: str, media_type: str, data: bytes) -> None:
        """Write an Attachment record (with its CRC; indexed)."""
        self._write(mr.Attachment(create_time, log_time, name, media_type, bytes(data)),
                    lambda offset, length: self._attachment_indexes.append(
                        mr.AttachmentIndex(offset, length, log_time, create_time, len(data), name, media_type)))

    # -- messages and chunks -----------------------------------------------------------

    def add_records(self, stream: RecordStream) -> None:
        """Add the Message records of ``stream`` (in log-time order) to the chunks, ending a chunk after the unit
        (sample) that takes it past ``chunk_size``."""
        n = len(stream.unit_ends)
        if n == 0:
            return
        if self._outside():
            self.settle()  # deferred jobs own the chunk in progress until they are done
        times = stream.unit_times
        first, last = int(times.min()), int(times.max())
        start, end = self._message_times
        self._message_times = (first if self.message_count == 0 else min(start, first), max(end, last))
        for units, channel_ids, _ in stream.messages:
            for channel_id in channel_ids.tolist():
                self._channel_counts[channel_id] += len(units)
            self.message_count += len(units) * len(channel_ids)
        done = 0
        while done < n:
            base = int(stream.unit_ends[done - 1]) if done else 0
            filled = self._chunk_bytes + (stream.unit_ends[done:] - base)  # bytes of the chunk after each unit
            stop = min(n, done + int(np.searchsorted(filled, self._chunk_size, side="right")) + 1)
            piece_times = times[done:stop]
            first, last = int(piece_times.min()), int(piece_times.max())
            start, end = self._chunk_times
            self._chunk_times = (first if self._chunk_messages == 0 else min(start, first), max(end, last))
            shift = self._chunk_bytes - base
            for units, channel_ids, offsets in stream.messages:  # a block's rows are in order: one slice per block
                lo, hi = np.searchsorted(units, (done, stop))
                if lo == hi:
                    continue
                pairs = np.empty((len(channel_ids), hi - lo, 2), dtype=np.uint64)
                pairs[:, :, 0] = times[units[lo:hi]]
                pairs[:, :, 1] = (offsets[lo:hi] + shift).T
                for j, channel_id in enumerate(channel_ids.tolist()):
                    self._chunk_indexes.setdefault(channel_id, []).append(pairs[j])
                self._chunk_messages += (hi - lo) * len(channel_ids)
            stop_byte = int(stream.unit_ends[stop - 1])
            self._pieces.append(stream.data[base:stop_byte])
            self._chunk_bytes += stop_byte - base
            if self._chunk_bytes > self._chunk_size:
                self._end_chunk()
            done = stop

    def end_chunk(self) -> None:
        """Hand the chunk in progress (if it holds messages) to the chunk thread."""
        if self._outside():
            self.settle()
        self._end_chunk()

    def _end_chunk(self) -> None:
        if self._chunk_messages == 0:
            return
        job = (self._pieces, self._chunk_times, sorted(self._chunk_indexes.items()))
        self._pieces, self._chunk_bytes, self._chunk_messages, self._chunk_indexes = [], 0, 0, {}
        self._submit(self._write_chunk, *job)

    def _write_chunk(self, pieces: list[np.ndarray], times: tuple[int, int],
                     indexes: list[tuple[int, list[np.ndarray]]]) -> None:
        """Compress one chunk, write it and its message indexes at the end of the stream, and index it."""
        # (a chunk within one batch is one piece, a view of the batch's records: compressed and checked in place)
        data = pieces[0] if len(pieces) == 1 else b"".join(pieces)
        if self._compress is None:
            self._compress = _compressor(self._compression)
        compressed = self._compress(data)
        compression = self._compression.encode()
        body = _CHUNK_FIXED.pack(times[0], times[1], len(data), zlib.crc32(data), len(compression)) + compression
        head = RECORD_PREFIX.pack(Opcode.CHUNK, len(body) + 8 + len(compressed)) + body + struct.pack("<Q", len(compressed))
        chunk_start = self._stream.tell()
        chunk_length = len(head) + len(compressed)
        offsets, records, position = {}, [head, compressed], chunk_start + chunk_length
        for channel_id, blocks in indexes:
            pairs = (np.concatenate(blocks) if len(blocks) > 1 else blocks[0]).astype("<u8").tobytes()
            record = struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 6 + len(pairs), channel_id, len(pairs)) + pairs
            offsets[channel_id] = position
            records.append(record)
            position += len(record)
        self._stream.write(b"".join(records))
        index = mr.ChunkIndex(
            message_start_time=times[0], message_end_time=times[1], chunk_start_offset=chunk_start,
            chunk_length=chunk_length, message_index_offsets=offsets,
            message_index_length=position - chunk_start - chunk_length, compression=self._compression,
            compressed_size=len(compressed), uncompressed_size=len(data))
        self._chunk_index_records.append(index)
        self._summary_bytes[Opcode.CHUNK_INDEX].append(_record_bytes(index))  # (not left to finish(), on the caller's thread)

    def flush(self, wait: bool = True) -> None:
        """End the chunk in progress and flush the stream to the OS; ``wait=False`` leaves both to the chunk thread.
        With ``wait`` and nothing handed over since the last wait (e.g. the records written at a log's start), the
        caller's thread does them (:meth:`_now`)."""
        if wait and self._outside() and not self._pending:
            self._now(self._end_chunk_and_flush)
            return
        self._submit(self._end_chunk_and_flush)
        if wait:
            self.settle()

    def _end_chunk_and_flush(self) -> None:
        self._end_chunk()
        self._stream.flush()

    def flush_stream(self) -> None:
        """Flush the stream to the OS after the chunks handed over so far (on the chunk thread)."""
        self._submit(self._stream.flush)

    def finish(self) -> None:
        """End the last chunk; write DataEnd, the summary, the Footer and the closing magic; end the thread."""
        self.end_chunk()
        self.stop_thread()
        stream = self._stream
        stream.write(_record_bytes(mr.DataEnd(0)))
        summary_start = stream.tell()
        start, end = self._message_times
        statistics = mr.Statistics(
            attachment_count=len(self._attachment_indexes), channel_count=len(self._channels),
            channel_message_counts=dict(sorted(self._channel_counts.items())),
            chunk_count=len(self._chunk_index_records), message_count=self.message_count, message_end_time=end,
            message_start_time=start, metadata_count=len(self._metadata_indexes), schema_count=len(self._schemas))
        groups = [(Opcode.SCHEMA, self._schemas), (Opcode.CHANNEL, self._channels), (Opcode.STATISTICS, [statistics]),
                  (Opcode.CHUNK_INDEX, self._chunk_index_records), (Opcode.ATTACHMENT_INDEX, self._attachment_indexes),
                  (Opcode.METADATA_INDEX, self._metadata_indexes)]
        summary, offsets = b"", []
        for opcode, group in groups:
            known = self._summary_bytes.get(opcode)
            data = b"".join(known if known is not None else (_record_bytes(record) for record in group))
            offsets.append(mr.SummaryOffset(group_opcode=opcode, group_start=summary_start + len(summary),
                                            group_length=len(data)))
            summary += data
        offset_start = summary_start + len(summary)
        summary += b"".join(_record_bytes(record) for record in offsets)
        footer_start = RECORD_PREFIX.pack(Opcode.FOOTER, 20) + struct.pack("<QQ", summary_start, offset_start)
        crc = zlib.crc32(footer_start, zlib.crc32(summary))
        stream.write(summary + footer_start + struct.pack("<I", crc) + MCAP_MAGIC)


# ---------------------------------------------------------------------------------------
# Scanning a possibly damaged file
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Damage:
    """A byte range of a file that was skipped.

    Attributes
    ----------
    start, end : int
        Byte offsets, ``[start, end)``.
    what : str
        What was there and why it was skipped, e.g. ``"chunk: CRC mismatch"``.
    messages : int or None
        Messages lost with it (from the chunk's message indexes; None when they are unreadable too).
    """

    start: int
    end: int
    what: str
    messages: int | None = None


@dataclass(frozen=True)
class GoodChunk:
    """A chunk whose records decompressed to their CRC, at bytes ``[start, end)`` of the file."""

    start: int
    end: int

    def records(self, data: bytes | mmap.mmap) -> Iterator[Any]:
        """The chunk's records, read again from ``data`` (the scanned file's bytes)."""
        return inner_records(chunk_records(data[self.start + RECORD_PREFIX.size:self.end]))


_READERS = {Opcode.HEADER: mr.Header, Opcode.SCHEMA: mr.Schema, Opcode.CHANNEL: mr.Channel,
            Opcode.METADATA: mr.Metadata, Opcode.ATTACHMENT: mr.Attachment, Opcode.MESSAGE_INDEX: mr.MessageIndex,
            Opcode.CHUNK_INDEX: mr.ChunkIndex, Opcode.ATTACHMENT_INDEX: mr.AttachmentIndex,
            Opcode.METADATA_INDEX: mr.MetadataIndex, Opcode.STATISTICS: mr.Statistics,
            Opcode.SUMMARY_OFFSET: mr.SummaryOffset, Opcode.DATA_END: mr.DataEnd, Opcode.FOOTER: mr.Footer}


def parse_record(opcode: int, body: bytes) -> Any:
    """The record of ``opcode`` whose body is exactly ``body``; ValueError when it does not parse to its length."""
    if opcode == Opcode.MESSAGE:
        if len(body) < 22:
            raise ValueError("message record too short")
        channel_id, sequence, log_time, publish_time = struct.unpack_from("<HIQQ", body)
        return mr.Message(channel_id, log_time, body[22:], publish_time, sequence)
    reader = _READERS.get(opcode)
    if reader is None:
        raise ValueError(f"unknown opcode 0x{opcode:02x}")
    stream = ReadDataStream(io.BytesIO(body))
    try:
        record = reader.read(stream)
    except (McapError, struct.error, UnicodeDecodeError) as error:
        raise ValueError(f"{Opcode(opcode).name} record does not parse ({type(error).__name__})") from None
    if stream.count != len(body):
        raise ValueError(f"{Opcode(opcode).name} record has {len(body) - stream.count} stray bytes")
    if opcode == Opcode.ATTACHMENT and struct.unpack_from("<I", body, len(body) - 4)[0] not in (0, zlib.crc32(body[:-4])):
        raise ValueError("attachment CRC mismatch")
    return record


def chunk_records(body: bytes) -> bytes:
    """The uncompressed records of a Chunk record's body; ValueError when it does not parse, decompress or match its
    CRC."""
    if len(body) < _CHUNK_FIXED.size:
        raise ValueError("record too short")
    _, _, size, crc, name_length = _CHUNK_FIXED.unpack_from(body)
    data_at = _CHUNK_FIXED.size + name_length + 8
    if data_at > len(body) or size > _MAX_UNCOMPRESSED:
        raise ValueError("header does not parse")
    compression = bytes(body[_CHUNK_FIXED.size:data_at - 8]).decode("ascii", "replace")
    (data_length,) = struct.unpack_from("<Q", body, data_at - 8)
    if data_at + data_length != len(body):
        raise ValueError("data length does not match the record length")
    try:
        data = _decompress(compression, body[data_at:], size)
    except ValueError:
        raise
    except Exception as error:  # noqa: BLE001 - zstd/lz4 raise their own error types on damaged data
        raise ValueError(f"does not decompress ({type(error).__name__}: {error})") from None
    if len(data) != size:
        raise ValueError(f"decompresses to {len(data)} bytes, not {size}")
    if crc and zlib.crc32(data) != crc:
        raise ValueError("CRC mismatch")
    return data


def inner_records(data: bytes) -> Iterator[Any]:
    """The records inside a chunk's uncompressed ``data`` (whose CRC matched)."""
    position = 0
    while position < len(data):
        opcode, length = RECORD_PREFIX.unpack_from(data, position)
        start = position + RECORD_PREFIX.size
        position = start + length
        if position > len(data):
            raise ValueError("record crosses the end of its chunk")
        yield parse_record(opcode, data[start:position])


class Scan:
    """A record-by-record reading of a possibly damaged MCAP file.

    Attributes
    ----------
    size : int
        File size [B].
    records : list of (offset, record)
        Records outside chunks that parsed, in file order (Schema, Channel, Metadata,
        Attachment, Message, and the summary's records).
    chunks : list of GoodChunk
        Chunks whose records decompressed to their CRC.
    damage : list of Damage
        Byte ranges skipped, in file order.
    footer : bool
        Whether the Footer and closing magic were read.
    end : int
        Byte offset after the last record read (the file size when nothing is missing).
    """

    def __init__(self, data: bytes | mmap.mmap):
        self.size = len(data)
        self.records: list[tuple[int, Any]] = []
        self.chunks: list[GoodChunk] = []
        self.damage: list[Damage] = []
        self.footer = False
        self.end = len(MCAP_MAGIC)
        self._data = data
        if len(data) < len(MCAP_MAGIC) or bytes(data[:len(MCAP_MAGIC)]) != MCAP_MAGIC:
            raise ValueError("not an MCAP file (no MCAP magic at its start)")
        self._read()

    def _record_at(self, position: int) -> tuple[int, int, Any] | None:
        """(opcode, end, parsed record or GoodChunk) of a record that parses at ``position``, else None."""
        data = self._data
        if position + RECORD_PREFIX.size > self.size:
            return None
        opcode, length = RECORD_PREFIX.unpack_from(data, position)
        end = position + RECORD_PREFIX.size + length
        if end > self.size:
            return None
        body = data[position + RECORD_PREFIX.size:end]
        try:
            if opcode == Opcode.CHUNK:
                chunk_records(body)
                return opcode, end, GoodChunk(position, end)
            return opcode, end, parse_record(opcode, body)
        except ValueError:
            return None

    def _next_chunk(self, position: int) -> int:
        """Offset of the next chunk after ``position`` that decompresses to its CRC, or the file size."""
        data = self._data
        opcode = bytes([Opcode.CHUNK])
        while True:
            position = data.find(opcode, position + 1)
            if position < 0:
                return self.size
            if position + RECORD_PREFIX.size + _CHUNK_FIXED.size > self.size:
                continue
            _, length = RECORD_PREFIX.unpack_from(data, position)
            if position + RECORD_PREFIX.size + length > self.size:
                continue
            name_length = _CHUNK_FIXED.unpack_from(data, position + RECORD_PREFIX.size)[4]
            if name_length > 8 or length < _CHUNK_FIXED.size + name_length + 8:
                continue
            found = self._record_at(position)
            if found is not None:
                return position

    def _lost_messages(self, position: int) -> tuple[int | None, int]:
        """Messages listed by the MessageIndex records at ``position`` (after a damaged chunk) and where they end."""
        count, found = 0, False
        while True:
            found_record = self._record_at(position)
            if found_record is None or found_record[0] != Opcode.MESSAGE_INDEX:
                return (count if found else None), position
            count += len(found_record[2].records)
            found = True
            position = found_record[1]

    def _read(self) -> None:
        position = len(MCAP_MAGIC)
        while position < self.size:
            found = self._record_at(position)
            if found is None:
                position = self._skip(position)
                continue
            opcode, end, record = found
            if isinstance(record, GoodChunk):
                self.chunks.append(record)
            elif opcode != Opcode.MESSAGE_INDEX:  # message indexes are not needed
                self.records.append((position, record))
            position = self.end = end
            if opcode == Opcode.FOOTER:
                if bytes(self._data[end:end + len(MCAP_MAGIC)]) == MCAP_MAGIC:
                    self.footer = True
                    self.end = end + len(MCAP_MAGIC)
                else:
                    self.damage.append(Damage(end, self.size, "no closing magic after the footer"))
                break
        self._count_from_summary()

    def _count_from_summary(self) -> None:
        """Messages of damaged ranges whose count is unknown, from the summary's chunk indexes (a finished file):
        the message indexes of every chunk starting in the range, or 0 when no chunk starts there."""
        indexes = [record for _, record in self.records if isinstance(record, mr.ChunkIndex)]
        if not indexes:
            return
        for i, damage in enumerate(self.damage):
            if damage.messages is not None:
                continue
            count = 0
            for index in indexes:
                if damage.start <= index.chunk_start_offset < damage.end:
                    for offset in index.message_index_offsets.values():
                        found = self._record_at(offset)
                        if found is None or found[0] != Opcode.MESSAGE_INDEX:
                            count = None
                            break
                        count += len(found[2].records)
                if count is None:
                    break
            self.damage[i] = dataclasses.replace(damage, messages=count)

    def _skip(self, position: int) -> int:
        """Record the damage at ``position``; return where reading resumes."""
        data = self._data
        if position + RECORD_PREFIX.size > self.size:
            self.damage.append(Damage(position, self.size, "incomplete record at the end of the file"))
            return self.size
        opcode, length = RECORD_PREFIX.unpack_from(data, position)
        end = position + RECORD_PREFIX.size + length
        known = opcode in {int(o) for o in Opcode}
        name = Opcode(opcode).name.lower().replace("_", " ") if known else "unknown record"
        if end == self.size or (end < self.size and self._record_at(end) is not None):  # its length is intact
            why = "does not parse"
            if opcode == Opcode.CHUNK:
                try:
                    chunk_records(data[position + RECORD_PREFIX.size:end])
                except ValueError as error:
                    why = str(error)
            lost = None if opcode == Opcode.MESSAGE_INDEX else self._lost_messages(end)[0]
            if lost is not None and opcode != Opcode.CHUNK:  # message indexes follow it: a chunk whose opcode is hit
                name, why = "chunk", f"opcode damaged (0x{opcode:02x})"
            self.damage.append(Damage(position, end, f"{name}: {why}",
                                      lost if lost is not None or opcode == Opcode.CHUNK else 0))
            return end
        resume = self._next_chunk(position)
        if resume == self.size and end > self.size and known:
            self.damage.append(Damage(position, self.size, f"incomplete {name} record at the end of the file"))
        else:
            self.damage.append(Damage(position, resume, f"unreadable bytes ({name} opcode 0x{opcode:02x})"))
        return resume


class MappedFile:
    """A file's bytes, memory-mapped read-only (``with MappedFile(path) as data: ...``); an empty file is ``b""``."""

    def __init__(self, path: str | os.PathLike):
        self._stream = open(path, "rb")
        size = os.fstat(self._stream.fileno()).st_size
        self._map = mmap.mmap(self._stream.fileno(), 0, access=mmap.ACCESS_READ) if size else None

    def __enter__(self) -> bytes | mmap.mmap:
        return self._map if self._map is not None else b""

    def __exit__(self, *exc_info: Any) -> None:
        if self._map is not None:
            self._map.close()
        self._stream.close()
