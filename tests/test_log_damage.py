"""Damaged and cut logs, and the output safety of the log writer.

A 20 s excavator dig log (31 chunks) with one flipped bit: ``log recover`` keeps every other
chunk (exact message counts, the same messages byte for byte), a damaged message index loses
nothing, ``log info`` flags the damage; cut files recover the chunks before the cut.  The writer
never shares, deletes or replaces a file it was not told to: two writers on one path, an
existing ``.partial``, an existing log, a folder, a FIFO.
"""

from __future__ import annotations

import collections
import io
import os
import struct

import pytest
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk

from sim.cli import main
from sim.io.examples import example_path
from sim.io.mcap_log import LogPathError, LogWriter, flat_schema, inspect_log, read_log, recover

SCHEMA = flat_schema("t_msgs/msg/S", {"a": "a [1]"})


@pytest.fixture(scope="module")
def dig(tmp_path_factory):
    """The undamaged 20 s dig log: its bytes, chunk layout and messages (read by mcap's own reader)."""
    from sim.run.runner import run

    path = tmp_path_factory.mktemp("dig") / "dig.mcap"
    assert run(example_path("excavator/dig"), out=path).status == "complete"
    data = path.read_bytes()
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        messages = [(channel.topic, m.log_time, m.sequence, bytes(m.data))
                    for _, channel, m in reader.iter_messages(log_time_order=False)]
    chunks = []  # (start, length, message index offsets, messages in the chunk)
    for index in summary.chunk_indexes:
        body = data[index.chunk_start_offset + 9:index.chunk_start_offset + index.chunk_length]
        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
        records = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        count, position = 0, 0
        while position < len(records):
            opcode, length = struct.unpack_from("<BQ", records, position)
            count += opcode == 0x05
            position += 9 + length
        chunks.append((index.chunk_start_offset, index.chunk_length, index.message_index_offsets, count))
    assert len(chunks) == 31 and len(messages) == 32_017 == sum(c[3] for c in chunks)  # 256 KiB chunks
    return path, data, chunks, messages


def _flipped(data: bytes, offset: int, bit: int = 3) -> bytes:
    damaged = bytearray(data)
    damaged[offset] ^= 1 << bit
    return bytes(damaged)


def _messages(path) -> list[tuple]:
    with open(path, "rb") as stream:
        return [(channel.topic, m.log_time, m.sequence, bytes(m.data))
                for _, channel, m in make_reader(stream, validate_crcs=True).iter_messages(log_time_order=False)]


def _in_chunk(dig, k: int) -> collections.Counter:
    """The messages of chunk k (by log time range and order of the undamaged file)."""
    _, _, chunks, messages = dig
    first = sum(c[3] for c in chunks[:k])
    return collections.Counter(messages[first:first + chunks[k][3]])


@pytest.mark.parametrize("which", [0, 15, 30])
def test_one_flipped_bit_in_a_chunk_loses_that_chunk_only(dig, tmp_path, which):
    """A bit flipped in the compressed data of the first, a middle or the last chunk: the chunk fails its CRC (or
    does not decompress); every other chunk is kept, message for message; the report names the chunk's byte
    range and its message count, counted in the undamaged log (1 361, 1 424 and 16 of 32 017 messages for chunks
    1, 16 and 31 of the dig as logged today)."""
    path, data, chunks, messages = dig
    start, length, _, count = chunks[which]
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(_flipped(data, start + length // 2))
    out = tmp_path / "recovered.mcap"
    report = recover(damaged, out)
    assert report.message_count == len(messages) - count
    assert report.chunk_count == 30 and not report.complete
    assert [(d.start, d.end, d.messages) for d in report.skipped] == [(start, start + length, count)]
    assert report.skipped_messages == count
    assert report.stop_reason == "footer" and report.original_status == "complete"
    kept = collections.Counter(_messages(out))
    assert kept == collections.Counter(messages) - _in_chunk(dig, which)
    assert read_log(out).metadata["hydroplant.result"]["skipped_messages"] == str(count)
    assert main(["log", "recover", str(damaged), str(tmp_path / "cli.mcap")]) == 1


def test_flipped_bit_in_a_chunk_length_resynchronises_on_the_next_chunk(dig, tmp_path):
    """A flipped bit in a chunk's record length: reading resumes at the next chunk whose CRC checks."""
    path, data, chunks, messages = dig
    start, _, _, count = chunks[3]
    damaged = tmp_path / "length.mcap"
    damaged.write_bytes(_flipped(data, start + 2, 0))  # length += 256
    report = recover(damaged, tmp_path / "out.mcap")
    assert report.message_count == len(messages) - count and report.chunk_count == 30
    assert [(d.start, d.end, d.messages) for d in report.skipped] == [(start, chunks[4][0], count)]  # (summary)
    assert collections.Counter(_messages(tmp_path / "out.mcap")) == collections.Counter(messages) - _in_chunk(dig, 3)


def test_flipped_bit_in_a_chunk_opcode_loses_that_chunk_only(dig, tmp_path):
    """A chunk whose opcode byte is hit is recognised by the message indexes that follow it: that chunk is skipped
    and its messages counted, the others kept."""
    path, data, chunks, messages = dig
    start, length, _, count = chunks[7]
    damaged = tmp_path / "opcode.mcap"
    damaged.write_bytes(_flipped(data, start, 4))  # 0x06 -> 0x16
    report = recover(damaged, tmp_path / "out.mcap")
    assert report.message_count == len(messages) - count and report.chunk_count == 30
    assert [(d.start, d.end, d.what, d.messages) for d in report.skipped] == [
        (start, start + length, "chunk: opcode damaged (0x16)", count)]


def test_flipped_bits_in_message_indexes_lose_nothing(dig, tmp_path):
    """Recovery does not read message indexes: a flip in an index entry loses nothing and skips nothing; a flip in
    an index's length skips bytes up to the next chunk but no message."""
    path, data, chunks, messages = dig
    _, _, offsets, _ = chunks[2]
    entry = min(offsets.values()) + 9 + 6 + 3  # inside the first entry's log time
    damaged = tmp_path / "entry.mcap"
    damaged.write_bytes(_flipped(data, entry))
    report = recover(damaged, tmp_path / "entry-out.mcap")
    assert report.message_count == len(messages) and report.complete
    assert collections.Counter(_messages(tmp_path / "entry-out.mcap")) == collections.Counter(messages)

    damaged = tmp_path / "index-length.mcap"
    damaged.write_bytes(_flipped(data, max(offsets.values()) + 1, 1))
    report = recover(damaged, tmp_path / "length-out.mcap")
    assert report.message_count == len(messages) and report.chunk_count == 31
    assert len(report.skipped) == 1 and report.skipped[0].end == chunks[3][0] and report.skipped_messages == 0


def test_log_info_verifies_chunk_crcs(dig, tmp_path, capsys):
    """``log info`` decompresses every chunk: exit 0 and "verified" for the intact log; exit 1 naming the damaged
    chunk and its messages for a flipped bit (``--no-verify`` does not look: exit 0); every attachment listed."""
    path, data, chunks, _ = dig
    text, code = inspect_log(path)
    assert code == 0 and "verified: 31 chunks, every CRC matches" in text
    attachments = read_log(path).attachment_list
    assert attachments and f"attachments: {len(attachments)}" in text
    assert all(f"  {name}  {media}  {size} B" in text for name, media, size in attachments)
    damaged = tmp_path / "damaged.mcap"
    start, length, _, count = chunks[5]
    damaged.write_bytes(_flipped(data, start + length // 2))
    capsys.readouterr()
    assert main(["log", "info", str(damaged)]) == 1
    out = capsys.readouterr().out
    assert "status: complete" in out and "DAMAGED: 1 damaged chunk(s)" in out
    assert f"messages affected: {count}" in out and f"bytes {start}..{start + length}" in out
    assert main(["log", "info", "--no-verify", str(damaged)]) == 0


@pytest.mark.parametrize("content", [b"", b"hello, not a log\n", b"\x89MCAP0\r\n" + b"\xff" * 40])
def test_not_a_log_is_one_line_exit_2(tmp_path, capsys, content):
    """``log info``, ``log recover`` and ``compare`` on a file that is not MCAP: one line naming it, exit 2 (an MCAP
    magic followed by garbage is an unfinished log with damage for ``log info``: exit 1)."""
    path = tmp_path / "foreign.mcap"
    path.write_bytes(content)
    capsys.readouterr()
    expected = 1 if content.startswith(b"\x89MCAP") else 2
    assert main(["log", "info", str(path)]) == expected
    if expected == 2:
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(path) in err and "not an MCAP file" in err
    assert main(["compare", str(path), str(path), "--out", str(tmp_path / "cmp")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "Traceback" not in err


def test_compare_on_a_damaged_log_is_one_line_exit_2(dig, tmp_path, capsys):
    path, data, chunks, _ = dig
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(_flipped(data, chunks[1][0] + chunks[1][1] // 2))
    capsys.readouterr()
    assert main(["compare", str(path), str(damaged), "--out", str(tmp_path / "cmp")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "damaged log" in err and str(damaged) in err


def test_cut_logs_recover_the_chunks_before_the_cut(dig, tmp_path, capsys):
    """A log cut inside chunk k recovers the messages of chunks 0..k-1 exactly (exit 1: an incomplete record was
    skipped, and ``log info`` reports the damage: exit 1); cut where a chunk starts, nothing is skipped (exit 0,
    ``log info`` says UNFINISHED: exit 0); an existing output is never replaced."""
    path, data, chunks, messages = dig
    for k in (1, 6, 10):
        start, length, _, _ = chunks[k]
        before = sum(c[3] for c in chunks[:k])
        for cut, code in ((start + length // 3, 1), (start, 0)):
            partial = tmp_path / f"cut{k}-{cut}.mcap.partial"
            partial.write_bytes(data[:cut])
            out = tmp_path / f"cut{k}-{cut}.mcap"
            assert main(["log", "recover", str(partial), str(out)]) == code
            assert _messages(out) == messages[:before]
            text, info_code = inspect_log(partial)
            assert info_code == code and "UNFINISHED" in text
    kept = out.read_bytes()
    capsys.readouterr()
    assert main(["log", "recover", str(partial), str(out)]) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err and out.read_bytes() == kept
    assert main(["log", "recover", str(partial), str(out), "--overwrite"]) == 0


def _write(path, *, overwrite=False, value=1.0):
    with LogWriter(path, dt=1e-3, overwrite=overwrite) as log:
        log.cdr_channel("/s", SCHEMA, fields=["a"]).append(0, (value,))


def test_two_writers_on_one_path(tmp_path):
    """The second writer on a path is refused, naming the first's .partial, with or without overwrite; the first
    finishes its log."""
    path = tmp_path / "run.mcap"
    first = LogWriter(path, dt=1e-3)
    first.cdr_channel("/s", SCHEMA, fields=["a"]).append(0, (7.0,))
    for overwrite in (False, True):
        with pytest.raises(LogPathError, match=r"run\.mcap\.partial is being written by another run"):
            LogWriter(path, dt=1e-3, overwrite=overwrite)
    first.close()
    assert read_log(path).topic("/s")["a"].tolist() == [7.0]
    assert not (tmp_path / "run.mcap.partial").exists()


def test_existing_partial_is_refused_and_kept(tmp_path):
    """A .partial left by a killed run is never deleted: refused with a pointer to ``log recover``; replaced only
    with overwrite."""
    path = tmp_path / "run.mcap"
    partial = tmp_path / "run.mcap.partial"
    partial.write_bytes(b"\x89MCAP0\r\nleft by a killed run")
    before = partial.read_bytes()
    with pytest.raises(LogPathError) as error:
        LogWriter(path, dt=1e-3)
    assert str(error.value) == (f"{partial} exists (left by an interrupted run): recover it with 'hydroplant log "
                                f"recover {partial}', or pass --overwrite (overwrite=True) to replace it")
    assert partial.read_bytes() == before and not path.exists()
    _write(path, overwrite=True)
    assert read_log(path).topic("/s")["a"].tolist() == [1.0] and not partial.exists()


def test_existing_log_is_kept_unless_overwrite(tmp_path):
    """An existing log is refused at the start and kept byte for byte; one that appears during the run is not
    replaced either (the finished log stays as the .partial); overwrite=True replaces it."""
    path = tmp_path / "run.mcap"
    _write(path, value=1.0)
    before = path.read_bytes()
    with pytest.raises(LogPathError, match=r"run\.mcap exists; pass --overwrite"):
        _write(path, value=2.0)
    assert path.read_bytes() == before
    _write(path, overwrite=True, value=3.0)
    assert read_log(path).topic("/s")["a"].tolist() == [3.0]

    late = tmp_path / "late.mcap"
    log = LogWriter(late, dt=1e-3)
    log.cdr_channel("/s", SCHEMA, fields=["a"]).append(0, (4.0,))
    late.write_bytes(b"written meanwhile")
    with pytest.raises(LogPathError, match=r"late\.mcap appeared while the run was written; the finished log is kept"):
        log.close()
    assert late.read_bytes() == b"written meanwhile"
    assert read_log(tmp_path / "late.mcap.partial").topic("/s")["a"].tolist() == [4.0]


def test_targets_that_are_not_regular_files_are_refused(tmp_path):
    """A folder, a FIFO or a device as the log is refused even with overwrite, and left as it was."""
    folder = tmp_path / "folder.mcap"
    folder.mkdir()
    fifo = tmp_path / "fifo.mcap"
    os.mkfifo(fifo)
    for target in (folder, fifo, "/dev/null"):
        for overwrite in (False, True):
            with pytest.raises(LogPathError, match="exists and is not a regular file"):
                LogWriter(target, dt=1e-3, overwrite=overwrite)
    assert folder.is_dir() and not any(folder.iterdir()) and not (tmp_path / "folder.mcap.partial").exists()
    assert os.path.exists(fifo) and not os.path.isfile(fifo)


def test_random_damage_gives_one_line_errors_only(dig, tmp_path):
    """Random damage (bit flips, cuts, overwritten ranges; 9 seeded cases): ``log info``, ``recover`` and reading
    every topic either work or raise a one-line CircuitError; a recovered log always reads, and holds at least the
    messages of every chunk the damage did not touch."""
    import random

    from hydraulics.components import CircuitError

    path, data, chunks, messages = dig
    rng = random.Random(2024)
    for case in range(9):
        damaged = bytearray(data)
        if case % 3 == 0:
            damaged = damaged[:rng.randrange(len(data))]
            touched = (len(damaged), len(data))
        elif case % 3 == 1:
            offset = rng.randrange(len(data))
            damaged[offset] ^= 1 << rng.randrange(8)
            touched = (offset, offset + 1)
        else:
            offset = rng.randrange(len(data) - 64)
            damaged[offset:offset + 64] = rng.randbytes(64)
            touched = (offset, offset + 64)
        source, out = tmp_path / f"case{case}.mcap", tmp_path / f"case{case}.recovered.mcap"
        source.write_bytes(bytes(damaged))
        for action in (lambda: inspect_log(source), lambda: [read_log(source).topic(t) for t in read_log(source).topics]):
            try:
                action()
            except CircuitError as error:
                assert "\n" not in str(error) and str(source) in str(error)
        report = recover(source, out)
        intact = sum(count for start, length, _, count in chunks if start + length <= touched[0] or start >= touched[1])
        assert report.message_count >= intact
        assert sum(read_log(out).message_counts.values()) == report.message_count
