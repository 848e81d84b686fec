"""Verification and recovery of MCAP logs: every chunk that checks is kept, what is damaged is skipped and named.

:func:`verify_log` reads a log record by record (:class:`sim.io.mcap_file.Scan`), decompresses
every chunk and checks its CRC-32; :func:`recover` writes a new, finished and indexed log from
what checks: schemas, channels, metadata and attachments wherever they are (a finished file
repeats schemas and channels in its summary), and the messages of every chunk whose CRC holds.
Reading resumes after damage at the next record when the damaged one's length is intact (a
chunk with a flipped bit in its data loses that chunk only), else at the next Chunk opcode
whose chunk decompresses to its CRC.  Message indexes are not read (a damaged index loses
nothing); a damaged chunk's own indexes, when intact, say how many messages it held (found
after it, or through the summary's chunk indexes of a finished file).

Limitations: a Message record inside a chunk whose CRC holds is trusted; records outside
chunks (schemas, channels, metadata) carry no CRC and are kept when they parse to their
length.

Example::

    report = recover("run.mcap.partial", "run.mcap")
    print(report.summary_text())
    exit_code = 0 if report.complete else 1
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from mcap import records as mr
from mcap.writer import CompressionType, Writer

from sim.io.mcap_file import (DEFAULT_CHUNK_SIZE, NS_PER_S, RESULT_METADATA, Damage, LogPathError, LogReadError,
                              MappedFile, RunStatus, Scan, library_string, publish, refuse_special)

__all__ = ["LogCheck", "RecoverReport", "recover", "verify_log"]


def _scan(path: Path, data) -> Scan:
    try:
        return Scan(data)
    except ValueError as error:
        raise LogReadError(f"{path}: {error}") from None


def _stop_reason(scan: Scan) -> str:
    if scan.footer:
        return "footer"
    if scan.damage and scan.damage[-1].end == scan.size and scan.damage[-1].what.startswith("incomplete"):
        return f"truncated record: {scan.damage[-1].start} of {scan.size} bytes are complete records"
    return f"no footer: data ends at a record boundary after {scan.end} bytes"


def _damage_lines(damage: tuple[Damage, ...]) -> list[str]:
    lines = []
    for item in damage:
        lost = "" if item.messages is None and not item.what.startswith("chunk") else (
            " (messages lost: unknown)" if item.messages is None else f" ({item.messages} messages)")
        lines.append(f"  bytes {item.start}..{item.end} ({item.end - item.start} B): {item.what}{lost}")
    return lines


@dataclass(frozen=True)
class LogCheck:
    """Outcome of :func:`verify_log`.

    Attributes
    ----------
    chunk_count : int
        Chunks whose records decompressed to their CRC.
    damage : tuple of Damage
        Byte ranges that do not check (damaged chunks with the messages they held, when their
        message indexes say so; unreadable bytes; an incomplete record at the end).
    footer : bool
        Whether the file ends with a Footer and the closing magic.
    size : int
        File size [B].
    """

    chunk_count: int
    damage: tuple[Damage, ...]
    footer: bool
    size: int

    @property
    def damaged_chunks(self) -> int:
        """Chunks that fail their CRC or do not decompress, plus unreadable ranges in which chunks may have been."""
        return sum(1 for d in self.damage if d.what.startswith(("chunk", "unreadable", "incomplete chunk")))

    @property
    def messages_affected(self) -> int | None:
        """Messages of the damaged chunks (None when some chunk's count is unknown)."""
        counts = [d.messages for d in self.damage if d.what.startswith(("chunk", "unreadable", "incomplete chunk"))]
        return None if any(c is None for c in counts) else sum(counts)

    def summary_text(self) -> str:
        """Lines for ``log info``: ``verified: ...`` and one line per damaged range."""
        if not self.damage:
            return f"verified: {self.chunk_count} chunks, every CRC matches"
        affected = self.messages_affected
        lines = [f"DAMAGED: {self.damaged_chunks} damaged chunk(s) or range(s), {self.chunk_count} chunks check; "
                 f"messages affected: {'unknown' if affected is None else affected}; "
                 "'hydroplant log recover' keeps every chunk that checks"]
        return "\n".join(lines + _damage_lines(self.damage))


def verify_log(path: str | os.PathLike) -> LogCheck:
    """Decompress every chunk of the log at ``path`` and check its CRC; :class:`LogCheck` of what does not.

    Raises :class:`sim.io.mcap_file.LogReadError` for a file that is not MCAP.
    """
    path = Path(path)
    with MappedFile(path) as data:
        scan = _scan(path, data)
    return LogCheck(chunk_count=len(scan.chunks), damage=tuple(scan.damage), footer=scan.footer, size=scan.size)


@dataclass(frozen=True)
class RecoverReport:
    """Outcome of :func:`recover`.

    Attributes
    ----------
    message_count : int
        Messages copied to the new file.
    chunk_count : int
        Chunks read whose records decompressed to their CRC.
    schema_count, channel_count, metadata_count, attachment_count : int
        Records of each kind written (the metadata count includes the new ``hydroplant.result``).
    end_time_ns : int or None
        Largest log time recovered [ns].
    bytes_read : int
        Byte offset after the last record read.
    bytes_total : int
        Size of the damaged file [B].
    stop_reason : str
        How the input ends (``"footer"`` for a finished file, else the cut).
    original_status : str or None
        ``status`` of a ``hydroplant.result`` record found in the input, if any.
    skipped : tuple of Damage
        Byte ranges skipped, with the messages of the damaged chunks when known.
    orphan_messages : int
        Messages of checked chunks skipped because their channel's record was lost.
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
    skipped: tuple[Damage, ...] = ()
    orphan_messages: int = 0

    @property
    def complete(self) -> bool:
        """Whether nothing was skipped (no damaged range, no message without its channel)."""
        return not self.skipped and not self.orphan_messages

    @property
    def skipped_messages(self) -> int | None:
        """Messages skipped: those of damaged chunks (None when a count is unknown) and orphans."""
        check = LogCheck(self.chunk_count, self.skipped, self.stop_reason == "footer", self.bytes_total)
        affected = check.messages_affected
        return None if affected is None else affected + self.orphan_messages

    def summary_text(self) -> str:
        """What was kept and what was skipped, for ``hydroplant log recover``."""
        end = "" if self.end_time_ns is None else f", up to t = {self.end_time_ns / NS_PER_S:.6g} s"
        lines = [f"kept: {self.message_count} messages from {self.chunk_count} chunks{end}; {self.schema_count} schemas, "
                 f"{self.channel_count} channels, {self.metadata_count} metadata records, "
                 f"{self.attachment_count} attachments",
                 f"input: {self.bytes_total} B, ends with {self.stop_reason}"
                 + (f"; original status {self.original_status}" if self.original_status else "")]
        if self.complete:
            lines.append("skipped: nothing")
            return "\n".join(lines)
        skipped = self.skipped_messages
        check = LogCheck(self.chunk_count, self.skipped, False, self.bytes_total)
        lines.append(f"skipped: {check.damaged_chunks} damaged chunk(s) or range(s), "
                     f"{'an unknown number of' if skipped is None else skipped} messages, "
                     f"{sum(d.end - d.start for d in self.skipped)} B")
        lines += _damage_lines(self.skipped)
        if self.orphan_messages:
            lines.append(f"  {self.orphan_messages} messages whose channel record was lost")
        return "\n".join(lines)


def recover(partial_path: str | os.PathLike, out_path: str | os.PathLike, *,
            overwrite: bool = False) -> RecoverReport:
    """Write a valid, indexed MCAP from every record of a cut or damaged log that checks.

    Parameters
    ----------
    partial_path : str or Path
        Damaged file, typically ``run.mcap.partial`` left by a killed process, or a finished
        log with damaged chunks.
    out_path : str or Path
        Output file, written via ``out_path.recovering`` (created exclusively) and published
        without replacing anything. It may be the name the killed writer was aiming for, e.g.
        ``recover("run.mcap.partial", "run.mcap")``; it may not be the input.
    overwrite : bool, optional
        Replace an existing regular file ``out_path``; otherwise :class:`LogPathError`.

    Returns
    -------
    RecoverReport
        What was kept and what was skipped (``report.complete`` is False when anything was).

    Notes
    -----
    Any ``hydroplant.result`` record of the input is replaced by one with
    ``status="recovered"``, the stop reason and the skipped ranges.
    """
    partial_path, out_path = Path(partial_path), Path(out_path)
    if out_path.resolve() == partial_path.resolve():
        raise LogPathError(f"{out_path}: the recovered log must be written to another file than its input")
    refuse_special(out_path)
    if os.path.lexists(out_path) and not overwrite:
        raise LogPathError(f"{out_path} exists; pass --overwrite (overwrite=True) to replace it")
    tmp_path = out_path.with_name(out_path.name + ".recovering")  # not ".partial": that may be the input
    with MappedFile(partial_path) as data:
        scan = _scan(partial_path, data)
        schemas: dict[int, mr.Schema] = {}
        channels: dict[int, mr.Channel] = {}
        metadata: list[mr.Metadata] = []
        attachments: list[mr.Attachment] = []
        library = ""
        for _, record in scan.records:
            if isinstance(record, mr.Schema):
                schemas.setdefault(record.id, record)
            elif isinstance(record, mr.Channel):
                channels.setdefault(record.id, record)
            elif isinstance(record, mr.Metadata):
                metadata.append(record)
            elif isinstance(record, mr.Attachment):
                attachments.append(record)
            elif isinstance(record, mr.Header):
                library = record.library
        for chunk in scan.chunks:  # schemas and channels written inside chunks (other writers)
            for record in chunk.records(data):
                if isinstance(record, mr.Schema):
                    schemas.setdefault(record.id, record)
                elif isinstance(record, mr.Channel):
                    channels.setdefault(record.id, record)
        original_status = next((r.metadata.get("status") for r in metadata if r.name == RESULT_METADATA), None)
        kept_metadata = [r for r in metadata if r.name != RESULT_METADATA]
        try:
            fd = os.open(tmp_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            raise LogPathError(f"{tmp_path} exists (another recovery is running, or one was interrupted); "
                               "remove it first") from None
        except OSError as error:
            raise LogPathError(f"{tmp_path}: cannot create the recovered log ({error.strerror or error})") from None
        copied = orphans = 0
        end_time = None
        try:
            with os.fdopen(fd, "wb") as out:
                writer = Writer(out, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD)
                writer.start(profile="", library=library_string())
                for record in kept_metadata:
                    writer.add_metadata(record.name, record.metadata)
                for record in attachments:
                    writer.add_attachment(record.create_time, record.log_time, record.name, record.media_type,
                                          record.data)
                schema_map = {0: 0}
                for schema_id, schema in schemas.items():
                    schema_map[schema_id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                channel_map = {channel_id: writer.register_channel(channel.topic, channel.message_encoding,
                                                                    schema_map[channel.schema_id], dict(channel.metadata))
                               for channel_id, channel in channels.items() if channel.schema_id in schema_map}
                sources = sorted([(offset, [record]) for offset, record in scan.records if isinstance(record, mr.Message)]
                                 + [(chunk.start, chunk) for chunk in scan.chunks], key=lambda item: item[0])
                for _, source in sources:
                    for message in (source if isinstance(source, list) else source.records(data)):
                        if not isinstance(message, mr.Message):
                            continue
                        new_id = channel_map.get(message.channel_id)
                        if new_id is None:
                            orphans += 1
                            continue
                        writer.add_message(new_id, message.log_time, message.data, message.publish_time,
                                           message.sequence)
                        copied += 1
                        end_time = message.log_time if end_time is None else max(end_time, message.log_time)
                report = RecoverReport(
                    message_count=copied, chunk_count=len(scan.chunks), schema_count=len(schema_map) - 1,
                    channel_count=len(channel_map), metadata_count=len(kept_metadata) + 1,
                    attachment_count=len(attachments), end_time_ns=end_time, bytes_read=scan.end,
                    bytes_total=scan.size, stop_reason=_stop_reason(scan), original_status=original_status,
                    skipped=tuple(scan.damage), orphan_messages=orphans)
                result = {"status": RunStatus.RECOVERED.value, "reason": report.stop_reason,
                          "source": partial_path.name, "message_count": str(copied)}
                if not report.complete:
                    skipped = report.skipped_messages
                    result["skipped_messages"] = "unknown" if skipped is None else str(skipped)
                    result["skipped_ranges"] = ", ".join(f"{d.start}..{d.end}" for d in scan.damage)
                if original_status is not None:
                    result["original_status"] = original_status
                if library:
                    result["source_library"] = library
                if end_time is not None:
                    result["end_time_s"] = repr(end_time / NS_PER_S)
                writer.add_metadata(RESULT_METADATA, result)
                writer.finish()
        except BaseException:
            tmp_path.unlink(missing_ok=True)  # (ours, created above; the input is untouched)
            raise
    publish(tmp_path, out_path, overwrite)  # (an output that appeared meanwhile is kept, and so is ours)
    return report
