"""What a log hands its writer thread, and what it does in the caller's thread instead, changes nothing in the file.

A frame's row buffer grows with the rows a batch takes (``sim.io.log_writer.FRAME_FIRST_ROWS`` at first); a periodic
flush hands the writer thread its batch, the chunk's end and the file flush as one job; the records written at a
log's start are written in the caller's thread, with no thread started.  Each is checked here against the file the
other way writes: the same bytes, and the same samples read back with :func:`sim.io.log_reader.read_log`.
"""

import functools
import threading

import numpy as np
import pytest

from conftest import MODELS, messages_by_topic
import sim.io.log_writer
import sim.run.runner
from sim.io.log_schemas import LogLevel, flat_schema, log_message
from sim.io.mcap_file import ChunkedWriter
from sim.io.mcap_log import LogWriter, read_log
from sim.run.runner import run


def _samples(path):
    """Every topic's samples as :func:`read_log` reads them: log times, each numeric and text field's values."""
    log = read_log(path)
    out = {}
    for topic in log.topics:
        data = log.topic(topic)
        out[topic] = {"log_time": np.asarray(data.log_time)}
        for name in data.fields:
            out[topic][name] = data[name]
        for name in data.text_fields:
            out[topic][name] = data.text(name)
    return log, out


def _assert_same_samples(a, b):
    assert a.keys() == b.keys()
    for topic in a:
        assert a[topic].keys() == b[topic].keys(), topic
        for name, values in a[topic].items():
            if isinstance(values, list):
                assert values == b[topic][name], (topic, name)
            else:
                np.testing.assert_array_equal(values, b[topic][name], err_msg=f"{topic} {name}")


def _frame_file(path, rows, *, chunk_thread=True):
    """A frame of 3 columns fed three ways (append, extend, defer) in batches of 40 rows, with a periodic flush every
    0.05 s and an event channel; returns the file's bytes."""
    schema = flat_schema("t_msgs/msg/Two", {"x": "x [1]", "y": "y [1]"})
    with LogWriter(path, dt=1e-3, batch_size=40, flush_interval=0.05, chunk_size=1500, chunk_thread=chunk_thread,
                   attachments=[("a.txt", "text/plain", b"attached")]) as log:
        frame = log.frame(3)
        frame.channel("/a", schema, fields=["x", "y"], columns=[0, 1])
        frame.channel("/b", flat_schema("t_msgs/msg/One", {"z": "z [1]"}), fields=["z"], columns=[2], every=4)
        events = log.channel("/e", "foxglove.Log", {"type": "object"})
        step = 0
        while step < len(rows):
            kind = (step // 17) % 3
            steps = np.arange(step, min(step + 17, len(rows)))
            if kind == 0:
                for s in steps:
                    frame.append(int(s), rows[s])
            elif kind == 1:
                frame.extend(steps, rows[steps])
            else:
                piece = rows[steps].copy()
                frame.defer(steps, lambda out, lo, hi, piece=piece: out.__setitem__(slice(None), piece[lo:hi]))
            events.write(int(steps[-1]), log_message(LogLevel.INFO, f"to step {steps[-1]}"))
            step = int(steps[-1]) + 1
    return path.read_bytes()


@pytest.mark.parametrize("chunk_thread", [True, False])
def test_a_growing_frame_buffer_writes_the_file_a_whole_batch_buffer_writes(tmp_path, monkeypatch, chunk_thread):
    """Frame rows in a buffer that starts at one row and doubles as rows come give the file, byte for byte, that a
    buffer holding a whole batch from the start gives; every sample reads back."""
    rows = np.random.default_rng(3).normal(size=(400, 3))
    monkeypatch.setattr(sim.io.log_writer, "FRAME_FIRST_ROWS", 1)
    grown = _frame_file(tmp_path / "grown.mcap", rows, chunk_thread=chunk_thread)
    monkeypatch.setattr(sim.io.log_writer, "FRAME_FIRST_ROWS", 4096)
    whole = _frame_file(tmp_path / "whole.mcap", rows, chunk_thread=chunk_thread)
    assert grown == whole
    log = read_log(tmp_path / "grown.mcap")
    np.testing.assert_array_equal(log.topic("/a")["y"], rows[:, 1])
    np.testing.assert_array_equal(log.topic("/b")["z"], rows[::4, 2])
    assert log.attachments["a.txt"] == b"attached"


def test_the_writer_thread_writes_the_file_the_callers_thread_writes(tmp_path):
    """Batches, chunk ends and flushes handed to the writer thread one job per flush: the file the caller's thread
    writes alone, byte for byte."""
    rows = np.random.default_rng(4).normal(size=(400, 3))
    assert _frame_file(tmp_path / "thread.mcap", rows) == _frame_file(tmp_path / "inline.mcap", rows, chunk_thread=False)


def test_a_log_opens_in_the_callers_thread_and_wakes_its_writer_once_per_flush(tmp_path, monkeypatch):
    """Opening a log (header, run metadata, attachments, on disk on return) starts no thread; afterwards each periodic
    flush of frame rows is one hand-over to the writer thread (the records written outside chunks go with it)."""
    handed = []
    submit_one = ChunkedWriter._submit_one

    def spy(self, job, *args):
        if self._outside():
            handed.append(getattr(job, "__name__", repr(job)))
        return submit_one(self, job, *args)

    monkeypatch.setattr(ChunkedWriter, "_submit_one", spy)
    path = tmp_path / "open.mcap"
    before = {t.ident for t in threading.enumerate()}
    log = LogWriter(path, dt=1e-3, flush_interval=0.1, run_metadata={"scene": "unit"},
                    attachments=[("model.xml", "application/xml", b"<mujoco/>" * 100)])
    try:
        assert {t.ident for t in threading.enumerate()} == before and handed == []
        partial = log.partial_path.read_bytes()
        assert b"hydroplant.run" in partial and b"<mujoco/>" * 100 in partial  # on disk before any sample
        frame = log.frame(1)
        frame.channel("/x", flat_schema("t_msgs/msg/X", {"x": "x [1]"}), fields=["x"], columns=[0])
        for step in range(1000):
            frame.append(step, (float(step),))
        assert len(handed) == 9  # the flushes at steps 100, 200, ..., 900: one each
    finally:
        log.close()
    np.testing.assert_array_equal(read_log(path).topic("/x")["x"], np.arange(1000.0))


@pytest.fixture(scope="module")
def dig_rare_logs(tmp_path_factory):
    """The excavator dig's first 4.5 s (two periodic flushes) logged at 1 Hz and at 100 Hz, with the writer thread and
    without it."""
    folder = tmp_path_factory.mktemp("rare")
    results = {}
    for rate in (1.0, 100.0):
        overrides = {"duration": 4.5, "log_rate_hz": rate}
        results[rate, "thread"] = run(MODELS / "excavator" / "dig.scenario.toml", out=folder / f"thread{rate:g}.mcap",
                                      overrides=overrides)
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(sim.run.runner, "LogWriter", functools.partial(LogWriter, chunk_thread=False))
            results[rate, "inline"] = run(MODELS / "excavator" / "dig.scenario.toml",
                                          out=folder / f"inline{rate:g}.mcap", overrides=overrides)
    return results


@pytest.mark.parametrize("rate", [1.0, 100.0])
def test_a_rare_log_holds_the_same_samples_whichever_thread_writes_it(dig_rare_logs, rate):
    """A run logged at 1 Hz or 100 Hz, its batches handed to the writer thread at each periodic flush, holds every
    message the run written in its own thread holds, byte for byte, and reads back to the same samples: one per log
    interval from t = 0, and the last step's, complete."""
    thread, inline = dig_rare_logs[rate, "thread"], dig_rare_logs[rate, "inline"]
    assert thread.status == inline.status == "complete"
    assert messages_by_topic(thread.log_path) == messages_by_topic(inline.log_path)
    log, samples = _samples(thread.log_path)
    _assert_same_samples(samples, _samples(inline.log_path)[1])
    assert log.status == "complete"
    interval, end = round(1e9 / rate), round(4.5e9)  # [ns]; the run's last step is logged too
    expected = np.unique(np.append(np.arange(0, end + 1, interval), end))
    np.testing.assert_array_equal(samples["/hydroplant/energy"]["log_time"], expected)
