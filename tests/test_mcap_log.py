"""Tests of sim.io.mcap_log: round trip, CDR and strict JSON, crash safety, recovery and merging."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from sim.io.log_schemas import _step_log_times
from sim.io.mcap_log import (
    FRAME_TRANSFORMS,
    Column,
    LogLevel,
    LogPathError,
    LogWriter,
    TIMESTAMP,
    flat_schema,
    log_info,
    log_message,
    log_schema,
    merge_logs,
    read_log,
    recover,
    step_log_time,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
CYLINDER_FIELDS = {
    "position_m": "Rod extension [m]",
    "velocity_mps": "Rod velocity [m/s]",
    "p_cap_pa": "Cap-side pressure [Pa]",
    "p_rod_pa": "Rod-side pressure [Pa]",
    "q_cap_m3ps": "Cap-side flow [m^3/s]",
    "q_rod_m3ps": "Rod-side flow [m^3/s]",
    "force_n": "Rod force [N]",
    "stroke_frac": "Stroke fraction [1]",
}


def _reject(constant: str) -> None:
    raise ValueError(f"non-finite JSON constant {constant}")


def check_mcap(path: Path) -> dict[str, int]:
    """Independent checks: summary present, CRCs, per-channel and global order; JSON messages strict JSON, CDR
    messages decoded by mcap_ros2 (Foxglove's ROS 2 decoder); every top-level timestamp equal to the log time.

    Returns the message count per topic.
    """
    counts: dict[str, int] = {}
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, "no summary (unfinished file?)"
        assert summary.chunk_indexes, "no chunk index"
        last_global = -1
        decoders = DecoderFactory()
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert message.log_time >= last_global, "messages are not globally ordered by log time"
            last_global = message.log_time
            assert message.publish_time == message.log_time
            sec, nsec = divmod(message.log_time, 1_000_000_000)
            if channel.message_encoding == "json":
                body = json.loads(message.data, parse_constant=_reject)
                assert isinstance(body, dict)
                assert body["timestamp"] == {"sec": sec, "nsec": nsec}
            else:
                assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
                assert message.data[:4] == b"\x00\x01\x00\x00"  # little-endian CDR encapsulation
                body = decoders.decoder_for("cdr", schema)(message.data)
                stamps = [body.timestamp] if hasattr(body, "timestamp") else [t.timestamp for t in body.transforms]
                assert all((t.sec, t.nanosec) == (sec, nsec) for t in stamps)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        assert sum(counts.values()) == summary.statistics.message_count
    check_message_indexes(path)
    return counts


def check_message_indexes(path: Path) -> None:
    """Every chunk's message index entries point at a Message record of their channel and log time, in offset
    order, and together list every message of the chunk once."""
    import struct

    import zstandard
    from mcap.records import Chunk, MessageIndex
    from mcap.stream_reader import StreamReader

    chunks = []  # per chunk: [uncompressed data, messages in it, index entries listed]
    with open(path, "rb") as stream:
        for record in StreamReader(stream, emit_chunks=True).records:
            if isinstance(record, Chunk):
                data = (zstandard.ZstdDecompressor().decompress(record.data, max_output_size=record.uncompressed_size)
                        if record.compression == "zstd" else bytes(record.data))
                messages, position = 0, 0
                while position < len(data):
                    opcode, length = struct.unpack_from("<BQ", data, position)
                    messages += opcode == 0x05
                    position += 9 + length
                chunks.append([data, messages, 0])
            elif isinstance(record, MessageIndex):
                data = chunks[-1][0]
                offsets = [offset for _, offset in record.records]
                assert offsets == sorted(offsets)
                for log_time, offset in record.records:
                    opcode, _, channel_id, _, message_time = struct.unpack_from("<BQHIQ", data, offset)
                    assert (opcode, channel_id, message_time) == (0x05, record.channel_id, log_time)
                chunks[-1][2] += len(record.records)
    assert all(messages == listed for _, messages, listed in chunks)


def cylinder_sample(step: int) -> tuple[float, ...]:
    """Deterministic, full-precision sample of 8 floats for step `step`."""
    t = step * 1e-3
    return (math.sin(t), math.cos(3 * t) * 0.1, 1e7 + step / 3, 2e6 * math.exp(-t), 1e-4 * math.sin(7 * t),
            -1e-4 * t, 12345.678 * t, step / 7)


def write_run(path: Path, steps: int, *, dt: float = 1e-3, **writer_kwargs) -> None:
    """Write the reference run used by several tests."""
    fields = list(CYLINDER_FIELDS)
    with LogWriter(path, dt=dt, run_metadata={"scene": "unit", "mode": "test"}, **writer_kwargs) as log:
        channel = log.cdr_channel("/hydroplant/cylinders/boom", flat_schema("hydroplant_msgs/msg/CylinderState", CYLINDER_FIELDS), fields=fields)
        for step in range(steps):
            channel.append(step, cylinder_sample(step))


def test_round_trip_is_exact(tmp_path):
    """Every field comes back bit-exactly, with metadata, attachments and exact log times."""
    path = tmp_path / "run.mcap"
    steps = 2500
    dt = 1e-3
    fields = list(CYLINDER_FIELDS)
    rng = np.random.default_rng(7)
    boom = rng.standard_normal((steps, len(fields))) * np.logspace(-6, 8, len(fields))
    joints = rng.standard_normal((steps, 3, 2))
    with LogWriter(path, dt=dt, run_metadata={"scene": "dig", "mode": "mujoco"},
                   attachments=[("scenario.toml", "application/toml", b"[scenario]\nname='dig'\n"),
                                ("model.xml", "application/xml", b"<mujoco/>")],
                   batch_size=300, flush_interval=0.7) as log:
        cylinder = log.cdr_channel("/hydroplant/cylinders/boom", flat_schema("hydroplant_msgs/msg/CylinderState", CYLINDER_FIELDS), fields=fields,
                               metadata={"units": "SI"})
        pump = log.cdr_channel("/hydroplant/pump", flat_schema("hydroplant_msgs/msg/PumpState", {"p_pa": "Pressure [Pa]", "force.x": "Fx [N]",
                                                                "force.y": "Fy [N]"}),
                           fields=["p_pa", "force.x", "force.y"])
        joint_states = log.joint_states_channel("/hydroplant/joint_states", ["boom", "arm", "bucket"])
        events = log.channel("/hydroplant/log", "foxglove.Log", log_schema())
        for step in range(steps):
            cylinder.append(step, boom[step])
            if step % 4 == 0:
                pump.append(step, (boom[step, 2], boom[step, 0], -boom[step, 1]))
            joint_states.append(step, joints[step, :, 0], joints[step, :, 1])
            if step % 1000 == 0:
                events.write(step, log_message(LogLevel.INFO, f"step {step}", name="test"))

    assert not (tmp_path / "run.mcap.partial").exists()
    counts = check_mcap(path)
    assert counts == {"/hydroplant/cylinders/boom": steps, "/hydroplant/pump": steps // 4,
                      "/hydroplant/joint_states": steps, "/hydroplant/log": 3}

    log = read_log(path)
    assert log.library.startswith("hydroplant/") and " mcap-python/" in log.library
    assert log.topics == ["/hydroplant/cylinders/boom", "/hydroplant/pump", "/hydroplant/joint_states",
                          "/hydroplant/log"]
    assert log.message_counts == counts
    assert log.schema_names["/hydroplant/joint_states"] == "foxglove_msgs/msg/JointStates"
    run = log.metadata["hydroplant.run"]
    assert run["scene"] == "dig" and run["mode"] == "mujoco" and run["dt_s"] == repr(dt)
    assert log.status == "complete"
    assert log.metadata["hydroplant.result"]["last_step"] == str(steps - 1)
    assert log.attachments == {"scenario.toml": b"[scenario]\nname='dig'\n", "model.xml": b"<mujoco/>"}
    assert log.attachment_media_types["model.xml"] == "application/xml"

    data = log.topic("/hydroplant/cylinders/boom")
    dt_ns = 1_000_000
    assert data.log_time.dtype == np.int64
    np.testing.assert_array_equal(data.log_time, np.arange(steps, dtype=np.int64) * dt_ns)
    np.testing.assert_array_equal(data.t, np.arange(steps) * dt_ns / 1e9)
    for index, name in enumerate(fields):
        np.testing.assert_array_equal(data[name], boom[:, index])  # bit-exact float repr round trip
    np.testing.assert_array_equal(data.field("timestamp.nanosec"), (np.arange(steps) * dt_ns) % 1_000_000_000)

    pump_data = log.topic("/hydroplant/pump")
    np.testing.assert_array_equal(pump_data.log_time, np.arange(0, steps, 4) * dt_ns)
    np.testing.assert_array_equal(pump_data["force.y"], -boom[::4, 1])
    assert set(pump_data.fields) == {"timestamp.sec", "timestamp.nanosec", "p_pa", "force.x", "force.y"}

    joint_data = log.topic("/hydroplant/joint_states")
    for j, name in enumerate(["boom", "arm", "bucket"]):
        np.testing.assert_array_equal(joint_data[f"position/{name}"], joints[:, j, 0])
        np.testing.assert_array_equal(joint_data[f"velocity/{name}"], joints[:, j, 1])
        assert np.isnan(joint_data[f"effort/{name}"]).all() and np.isnan(joint_data[f"acceleration/{name}"]).all()

    event_data = log.topic("/hydroplant/log")
    assert event_data.text("message") == ["step 0", "step 1000", "step 2000"]
    np.testing.assert_array_equal(event_data["level"], [2, 2, 2])


def test_non_finite_values_round_trip(tmp_path):
    """NaN and ±inf are plain float64 values in CDR (bit-exact round trip); in a JSON message they are written as
    null and read back as NaN."""
    path = tmp_path / "nan.mcap"
    payload = np.array([0x7FF8_0000_0000_0123], dtype=np.uint64).view(np.float64)[0]  # a NaN with a payload
    with LogWriter(path, dt=0.01) as log:
        channel = log.cdr_channel("/s", flat_schema("t_msgs/msg/S", {"a": "a [m]", "b": "b [m]"}), fields=["a", "b"])
        events = log.channel("/e", "t.E", {"type": "object"})
        channel.append(0, (1.5, float("nan")))
        channel.append(1, (float("inf"), -float("inf")))
        channel.append(2, np.array([np.float64(2.0), payload]))
        events.write(2, {"x": float("nan"), "y": [1.0, float("inf")], "z": np.float64(0.25)})
    check_mcap(path)  # strict parse of every JSON message, every CDR message decoded independently
    with open(path, "rb") as stream:
        raw = [m.data for _, _, m in make_reader(stream).iter_messages(topics=["/s", "/e"])]
    assert raw[0][-16:] == np.array([1.5, np.nan]).tobytes()
    assert raw[3].endswith(b'"x":null,"y":[1.0,null],"z":0.25}')
    data = read_log(path).topic("/s")
    expected_a, expected_b = np.array([1.5, np.inf, 2.0]), np.array([np.nan, -np.inf, payload])
    np.testing.assert_array_equal(data["a"].view(np.uint64), expected_a.view(np.uint64))
    np.testing.assert_array_equal(data["b"].view(np.uint64), expected_b.view(np.uint64))
    event = read_log(path).topic("/e")
    assert np.isnan(event["x"][0]) and np.isnan(event["y[1]"][0]) and event["z"][0] == 0.25


@pytest.mark.parametrize("dt", [1e-3, 1 / 1200, 2.5e-4, 1 / 3, 1e-9])
def test_log_time_from_step_index(dt):
    """Columnar (numpy) and scalar log times agree bit for bit with the documented formula."""
    steps = np.concatenate([np.arange(20_000), np.arange(10**9, 10**9 + 500)]).astype(np.int64)
    vectorised = _step_log_times(steps, dt)
    scalar = [step_log_time(step, dt) for step in steps.tolist()]
    np.testing.assert_array_equal(vectorised, scalar)
    dt_ns = round(dt * 1e9)
    if abs(dt * 1e9 - dt_ns) <= 1e-9 * dt_ns:  # integral ns step: exact multiples
        np.testing.assert_array_equal(vectorised, steps * dt_ns)
    else:
        assert scalar == [round(step * dt * 1e9) for step in steps.tolist()]


def test_non_integral_dt_round_trip(tmp_path):
    """With dt = 1/1200 s, the stored log times are round(k * dt * 1e9) for every step."""
    path = tmp_path / "odd.mcap"
    dt = 1 / 1200
    steps = 3000
    with LogWriter(path, dt=dt, batch_size=128) as log:
        channel = log.cdr_channel("/s", flat_schema("t_msgs/msg/S", {"a": "a [1]"}), fields=["a"])
        for step in range(steps):
            channel.append(step, (float(step),))
        channel.write(steps, {"a": -1.0})
    data = read_log(path).topic("/s")
    np.testing.assert_array_equal(data.log_time, [round(k * dt * 1e9) for k in range(steps + 1)])


def test_exception_in_with_block_finishes_file(tmp_path):
    """An exception still yields an indexed file at PATH with every sample and status incomplete."""
    path = tmp_path / "crash.mcap"
    appended = 777
    with pytest.raises(RuntimeError, match="solver exploded"):
        with LogWriter(path, dt=1e-3, batch_size=100) as log:
            channel = log.cdr_channel("/s", flat_schema("t_msgs/msg/S", {"a": "a [1]"}), fields=["a"])
            for step in range(appended):
                channel.append(step, (step * 0.5,))
            raise RuntimeError("solver exploded")
    assert path.exists() and not Path(str(path) + ".partial").exists()
    assert check_mcap(path) == {"/s": appended}
    log = read_log(path)
    assert log.metadata["hydroplant.result"]["status"] == "incomplete"
    assert log.metadata["hydroplant.result"]["reason"] == "RuntimeError: solver exploded"
    np.testing.assert_array_equal(log.topic("/s")["a"], np.arange(appended) * 0.5)


def test_keyboard_interrupt_is_recorded(tmp_path):
    path = tmp_path / "int.mcap"
    with pytest.raises(KeyboardInterrupt):
        with LogWriter(path, dt=1e-3) as log:
            log.cdr_channel("/s", flat_schema("t_msgs/msg/S", {"a": "a [1]"}), fields=["a"]).append(0, (1.0,))
            raise KeyboardInterrupt
    assert read_log(path).metadata["hydroplant.result"]["reason"] == "interrupted"


def test_ctrl_c_during_batch_write_loses_nothing(tmp_path, monkeypatch):
    """A SIGINT landing inside the MCAP writer is held until the batch is written."""
    from sim.io.mcap_file import ChunkedWriter

    path = tmp_path / "sigint.mcap"
    original = ChunkedWriter.add_records
    calls = {"n": 0}

    def add_records_with_ctrl_c(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:  # the second batch (steps 100..199)
            signal.raise_signal(signal.SIGINT)  # handler runs at the next bytecode boundary
        return original(self, *args, **kwargs)

    monkeypatch.setattr(ChunkedWriter, "add_records", add_records_with_ctrl_c)
    # Python's own handler, also when the suite inherited SIGINT ignored (started in the background)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    appended = 0
    with pytest.raises(KeyboardInterrupt):
        with LogWriter(path, dt=1e-3, batch_size=100) as log:
            channel = log.cdr_channel("/s", flat_schema("t_msgs/msg/S", {"a": "a [1]"}), fields=["a"])
            for step in range(1000):
                channel.append(step, (float(step),))
                appended = step + 1
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handler restored
    log = read_log(path)
    assert log.metadata["hydroplant.result"]["reason"] == "interrupted"
    # The interrupt arrived after the batch of steps 100..199 was written, before step 200.
    assert appended == 200
    np.testing.assert_array_equal(log.topic("/s")["a"], np.arange(appended, dtype=float))
    signal.signal(signal.SIGINT, previous)


def test_existing_files_are_not_overwritten(tmp_path):
    path = tmp_path / "twice.mcap"
    write_run(path, 10)
    with pytest.raises(LogPathError, match=r"twice.mcap exists; pass --overwrite \(overwrite=True\)"):
        LogWriter(path, dt=1e-3)
    write_run(path, 20, overwrite=True)
    assert read_log(path).message_counts == {"/hydroplant/cylinders/boom": 20}
    with pytest.raises(LogPathError, match="another file than its input"):
        recover(path, path)


def test_recover_onto_target_name(tmp_path):
    """recover("x.mcap.partial", "x.mcap") works although the writer's temp name is the input."""
    partial = write_partial(tmp_path / "x.mcap")
    report = recover(partial, tmp_path / "x.mcap")
    assert report.message_count == 1 and partial.exists()
    assert read_log(tmp_path / "x.mcap").topic("/s")["a"].tolist() == [1.0]


def test_mark_diverged(tmp_path):
    path = tmp_path / "div.mcap"
    with LogWriter(path, dt=1e-3) as log:
        log.cdr_channel("/s", flat_schema("t_msgs/msg/S", {"a": "a [1]"}), fields=["a"]).append(3, (1.0,))
        log.mark("diverged", time_s=0.003, component="boom_cylinder")
    result = read_log(path).metadata["hydroplant.result"]
    assert result["status"] == "diverged"
    assert result["time_s"] == "0.003" and result["component"] == "boom_cylinder"
    assert "diverged" in log_info(path)


def test_periodic_flush_bounds_loss(tmp_path):
    """A copy of the .partial taken mid-run recovers everything before the last periodic flush."""
    path = tmp_path / "live.mcap"
    snapshot = tmp_path / "snapshot.mcap.partial"
    fields = list(CYLINDER_FIELDS)
    with LogWriter(path, dt=1e-3, flush_interval=0.1, batch_size=10_000, chunk_size=1 << 24) as log:
        channel = log.cdr_channel("/c", flat_schema("t_msgs/msg/C", CYLINDER_FIELDS), fields=fields)
        for step in range(551):
            channel.append(step, cylinder_sample(step))
        log._writer.settle()  # the chunk thread has written what the flushes handed it (a few ms after each)
        snapshot.write_bytes(log.partial_path.read_bytes())  # what a SIGKILL would leave
    report = recover(snapshot, tmp_path / "recovered.mcap")
    # Flushes happen when steps 100, 200, ..., 500 arrive: steps 0..499 are on disk.
    assert report.message_count == 500
    assert report.chunk_count == 5
    recovered = read_log(tmp_path / "recovered.mcap")
    assert recovered.status == "recovered"
    assert recovered.metadata["hydroplant.run"]["dt_s"] == "0.001"


WRITER_SCRIPT = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[2])
    from tests.test_mcap_log import CYLINDER_FIELDS, cylinder_sample
    from sim.io.mcap_log import LogWriter, flat_schema
    with LogWriter(sys.argv[1], dt=1e-3, run_metadata={"scene": "unit", "mode": "test"},
                   attachments=[("note.txt", "text/plain", b"kill me")],
                   flush_interval=0.02, batch_size=50, chunk_size=32 * 1024) as log:
        channel = log.cdr_channel("/hydroplant/cylinders/boom", flat_schema("hydroplant_msgs/msg/CylinderState", CYLINDER_FIELDS),
                              fields=list(CYLINDER_FIELDS))
        step = 0
        while True:
            channel.append(step, cylinder_sample(step))
            step += 1
""")


def test_sigkill_then_recover(tmp_path):
    """A SIGKILLed writer leaves a .partial whose recovery equals the uninterrupted run's prefix."""
    path = tmp_path / "killed.mcap"
    partial = tmp_path / "killed.mcap.partial"
    stderr_path = tmp_path / "writer.stderr"
    with open(stderr_path, "wb") as stderr, subprocess.Popen(
            [sys.executable, "-c", WRITER_SCRIPT, str(path), str(REPO_ROOT)],
            stdout=subprocess.DEVNULL, stderr=stderr) as process:
        try:
            deadline = time.monotonic() + 15.0
            while not (partial.exists() and partial.stat().st_size > 200_000):
                assert process.poll() is None, stderr_path.read_text()
                assert time.monotonic() < deadline, "writer produced too little data"
                time.sleep(0.02)
        finally:
            process.send_signal(signal.SIGKILL)
            process.wait(timeout=10)
    assert process.returncode == -signal.SIGKILL
    assert not path.exists()

    recovered_path = tmp_path / "recovered.mcap"
    report = recover(partial, recovered_path)
    assert report.chunk_count >= 2 and report.message_count > 1000
    assert report.attachment_count == 1 and report.original_status is None
    assert check_mcap(recovered_path) == {"/hydroplant/cylinders/boom": report.message_count}
    recovered = read_log(recovered_path)
    assert recovered.status == "recovered"
    assert recovered.metadata["hydroplant.run"]["scene"] == "unit"
    assert recovered.attachments == {"note.txt": b"kill me"}

    count = report.message_count
    reference_path = tmp_path / "reference.mcap"
    write_run(reference_path, count + 10)
    reference = read_log(reference_path).topic("/hydroplant/cylinders/boom")
    data = recovered.topic("/hydroplant/cylinders/boom")
    np.testing.assert_array_equal(data.log_time, reference.log_time[:count])
    for name in CYLINDER_FIELDS:
        np.testing.assert_array_equal(data[name], reference[name][:count])
    assert data.messages == reference.messages[:count]


def test_recover_file_cut_anywhere(tmp_path):
    """Cutting a finished file at arbitrary bytes recovers exactly a prefix of its messages."""
    path = tmp_path / "whole.mcap"
    write_run(path, 2000, chunk_size=8 * 1024)
    whole = path.read_bytes()
    reference = read_log(path).topic("/hydroplant/cylinders/boom")
    previous = -1
    for fraction in (0.1, 0.37, 0.5, 0.81, 0.999):
        cut = tmp_path / f"cut_{fraction}.mcap.partial"
        cut.write_bytes(whole[: int(len(whole) * fraction)])
        out = tmp_path / f"cut_{fraction}.mcap"
        report = recover(cut, out)
        assert report.stop_reason.startswith(("truncated record", "no footer"))
        assert report.message_count >= previous  # more bytes never recover fewer messages
        previous = report.message_count
        assert check_mcap(out) == ({"/hydroplant/cylinders/boom": report.message_count}
                                   if report.message_count else {})
        if report.message_count:
            data = read_log(out).topic("/hydroplant/cylinders/boom")
            assert data.messages == reference.messages[: report.message_count]
            np.testing.assert_array_equal(data.log_time, reference.log_time[: report.message_count])
    assert previous > 1500


def test_recover_complete_file(tmp_path):
    path = tmp_path / "done.mcap"
    write_run(path, 300)
    report = recover(path, tmp_path / "again.mcap")
    assert report.stop_reason == "footer" and report.original_status == "complete"
    assert report.message_count == 300
    assert read_log(tmp_path / "again.mcap").metadata["hydroplant.result"]["original_status"] == "complete"


def test_identical_runs_give_identical_files(tmp_path):
    write_run(tmp_path / "a.mcap", 1200)
    write_run(tmp_path / "b.mcap", 1200)
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def _write_tf_run(path: Path, dt: float, steps: int, offset: float) -> None:
    layout = {"transforms": [{"timestamp": TIMESTAMP, "parent_frame_id": "world", "child_frame_id": "boom",
                              "translation": {"x": Column(0), "y": Column(1), "z": Column(2)},
                              "rotation": {"x": Column(3), "y": Column(4), "z": Column(5), "w": Column(6)}}]}
    with LogWriter(path, dt=dt, run_metadata={"mode": str(offset)}) as log:
        tf = log.cdr_channel("/tf", FRAME_TRANSFORMS, layout=layout)
        signal_channel = log.cdr_channel("/hydroplant/pump", flat_schema("t_msgs/msg/P", {"p_pa": "p [Pa]"}),
                                     fields=["p_pa"])
        for step in range(steps):
            tf.append(step, (offset + step, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0))
            signal_channel.append(step, (offset * step,))


def test_merge_logs(tmp_path):
    """Merged file: prefixed topics and frames, all messages, global log-time order, renamed metadata."""
    a, b, out = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "merged.mcap"
    _write_tf_run(a, 1e-3, 400, 1.0)
    _write_tf_run(b, 2.5e-3, 200, 2.0)
    merge_logs({"mujoco": a, "pbd": b}, out)
    counts = check_mcap(out)  # includes the global order check
    assert counts == {"/mujoco/tf": 400, "/mujoco/hydroplant/pump": 400, "/pbd/tf": 200,
                      "/pbd/hydroplant/pump": 200}
    merged = read_log(out)
    assert merged.metadata["mujoco/hydroplant.run"]["mode"] == "1.0"
    assert merged.metadata["pbd/hydroplant.result"]["status"] == "complete"
    tf = merged.topic("/pbd/tf")
    assert "translation.x/pbd/boom" in tf.fields
    assert set(tf.text("parent_frame_id/pbd/boom")) == {"world"}  # shared root frame is not prefixed
    np.testing.assert_array_equal(tf["translation.x/pbd/boom"], 2.0 + np.arange(200))
    assert tf.messages[0]["transforms"][0]["parent_frame_id"] == "world"
    np.testing.assert_array_equal(tf.log_time, np.arange(200) * 2_500_000)
    original = read_log(a).topic("/hydroplant/pump")
    np.testing.assert_array_equal(merged.topic("/mujoco/hydroplant/pump")["p_pa"], original["p_pa"])


def test_log_info_summary(tmp_path):
    path = tmp_path / "info.mcap"
    write_run(path, 250)
    text = log_info(path)
    assert "status: complete" in text
    assert "scene: unit" in text and "mode: test" in text
    assert "/hydroplant/cylinders/boom" in text and " 250 " in text
    assert "0.249 s" in text
    assert "UNFINISHED" in log_info(write_partial(tmp_path / "open.mcap"))


def write_partial(path: Path) -> Path:
    """Leave an unfinished file behind (the writer is never closed)."""
    log = LogWriter(path, dt=1e-3)
    log.cdr_channel("/s", flat_schema("t_msgs/msg/S", {"a": "a [1]"}), fields=["a"]).append(0, (1.0,))
    log.flush()
    log._file.close()
    return log.partial_path


def test_validation_messages(tmp_path):
    with pytest.raises(ValueError, match=r"`dt` must be positive and finite, got -0.001 s"):
        LogWriter(tmp_path / "x.mcap", dt=-1e-3)
    with pytest.raises(TypeError, match="`run_metadata` keys and values must be str"):
        LogWriter(tmp_path / "x.mcap", dt=1e-3, run_metadata={"seed": 3})
    with LogWriter(tmp_path / "y.mcap", dt=1e-3) as log:
        schema = flat_schema("t_msgs/msg/S", {"a": "a [1]"})
        channel = log.cdr_channel("/s", schema, fields=["a"])
        with pytest.raises(ValueError, match="topic '/s' is already registered"):
            log.cdr_channel("/s", schema, fields=["a"])
        with pytest.raises(ValueError, match=r"t_msgs/msg/S has no field\(s\) \['b'\]"):
            log.cdr_channel("/t", schema, fields=["b"])
        with pytest.raises(TypeError, match="columnar channels are ROS 2 CDR"):
            log.channel("/u", "t.S", {"type": "object"}, fields=["a"])
        log.channel("/u", "t.S", schema, fields=["a"])  # the JSON-era call: schema name "t.S" names t_msgs/msg/S
        with pytest.raises(ValueError, match="does not name message type"):
            log.channel("/v", "t.T", schema, fields=["a"])
        with pytest.raises(ValueError, match="`status` must be one of"):
            log.mark("exploded")
        channel.append(5, (1.0,))
        with pytest.raises(ValueError, match="/s: step_index 4 is before the previous one 5"):
            channel.append(4, (1.0,))
        events = log.channel("/e", "t.E", {"type": "object"})
        with pytest.raises(TypeError, match="/e: a JSON channel takes irregular messages; use write()"):
            events.append(0, (1.0,))
        with pytest.raises(ValueError):
            channel.append(6, (1.0, 2.0))  # wrong sample width
        channel.append(6, (2.0,))
    with pytest.raises(RuntimeError, match="y.mcap is closed"):
        channel.append(7, (3.0,))
    np.testing.assert_array_equal(read_log(tmp_path / "y.mcap").topic("/s")["a"], [1.0, 2.0])


def test_append_cost_is_printed(tmp_path, capsys):
    """Measure the amortised cost of an 8-field append (printed; no timing assertion)."""
    steps = 20_000
    samples = [cylinder_sample(step) for step in range(steps)]
    fields = list(CYLINDER_FIELDS)
    with LogWriter(tmp_path / "bench.mcap", dt=1e-3) as log:
        channel = log.cdr_channel("/c", flat_schema("t_msgs/msg/C", CYLINDER_FIELDS), fields=fields)
        start = time.perf_counter()
        for step in range(steps):
            channel.append(step, samples[step])
        log.flush()  # include encoding, compression and writing
        elapsed = time.perf_counter() - start
    with capsys.disabled():
        print(f"\n[mcap_log] 8-field append, amortised incl. encode+write: {elapsed / steps * 1e6:.1f} us/sample")


def test_frame_channels_log_what_separate_channels_log(tmp_path):
    """A Frame (one row per sample feeding several channels, from scattered or contiguous columns) writes the same
    messages as one channel per topic, across batch and periodic-flush boundaries; its channels refuse their own
    appends."""
    fields_a, fields_b = {"x": "x [m]", "y": "y [m]"}, {"p": "p [Pa]"}
    steps = 2500  # > batch_size and several flush intervals
    rng = np.random.default_rng(3)
    rows = rng.standard_normal((steps, 4)) * 1e5

    def write(path, framed):
        with LogWriter(path, dt=1e-3, batch_size=700, flush_interval=0.9) as log:
            if framed:
                frame = log.frame(4)
                a = frame.channel("/a", flat_schema("t_msgs/msg/A", fields_a), fields=list(fields_a), columns=[2, 0])
                b = frame.channel("/b", flat_schema("t_msgs/msg/B", fields_b), fields=list(fields_b), columns=[3])
                c = frame.channel("/c", flat_schema("t_msgs/msg/A", fields_a), fields=list(fields_a), columns=[0, 1])
                events = log.channel("/e", "foxglove.Log", log_schema())
                with pytest.raises(TypeError):
                    a.append(0, (1.0, 2.0))
                with pytest.raises(TypeError):
                    b.write(0, {"p": 1.0})
            else:
                a = log.cdr_channel("/a", flat_schema("t_msgs/msg/A", fields_a), fields=list(fields_a))
                b = log.cdr_channel("/b", flat_schema("t_msgs/msg/B", fields_b), fields=list(fields_b))
                c = log.cdr_channel("/c", flat_schema("t_msgs/msg/A", fields_a), fields=list(fields_a))
                events = log.channel("/e", "foxglove.Log", log_schema())
            for step in range(steps):
                if framed:
                    frame.append(step, rows[step])
                else:
                    a.append(step, rows[step, [2, 0]])
                    b.append(step, rows[step, [3]])
                    c.append(step, rows[step, [0, 1]])
                if step % 1000 == 0:
                    events.write(step, log_message(LogLevel.INFO, f"step {step}"))
        return path

    framed, separate = write(tmp_path / "frame.mcap", True), write(tmp_path / "separate.mcap", False)
    # (check_mcap also checks strict JSON, CDR, CRCs and the global log-time order of the file)
    assert check_mcap(framed) == check_mcap(separate) == {"/a": steps, "/b": steps, "/c": steps, "/e": 3}
    la, lb = read_log(framed), read_log(separate)
    for topic in ("/a", "/b", "/c", "/e"):
        assert la.topic(topic).messages == lb.topic(topic).messages
    np.testing.assert_array_equal(la.topic("/a")["x"], rows[:, 2])
    np.testing.assert_array_equal(la.topic("/b")["p"], rows[:, 3])
    np.testing.assert_array_equal(la.topic("/c")["y"], rows[:, 1])  # contiguous columns: read as a view


def test_frame_extend_writes_what_row_appends_write(tmp_path):
    """Frame.extend (many rows at once, as the run recorder hands over a batch) gives the same file, byte for byte,
    as one append per row, with batches that straddle batch-size and periodic-flush boundaries and repeated steps;
    a close hook runs before the last drain, and rows out of order are refused."""
    steps = np.repeat(np.arange(1800), 2)[::3]  # non-decreasing, some steps twice
    rng = np.random.default_rng(5)
    rows = rng.standard_normal((len(steps), 3)) * 1e3
    rows[7, 1] = np.nan

    def write(path, cuts):
        with LogWriter(path, dt=1e-3, batch_size=250, flush_interval=0.4) as log:
            frame = log.frame(3)
            frame.channel("/a", flat_schema("t_msgs/msg/A", {"x": "x", "y": "y"}), fields=["x", "y"], columns=[1, 0])
            frame.channel("/b", flat_schema("t_msgs/msg/B", {"z": "z"}), fields=["z"], columns=[2])
            if cuts is None:
                for step, row in zip(steps, rows):
                    frame.append(int(step), row)
            else:
                tail = len(steps) - 5
                for lo, hi in zip([0, *cuts], [*cuts, tail]):
                    frame.extend(steps[lo:hi], rows[lo:hi])
                log.on_close(lambda: frame.extend(steps[tail:], rows[tail:]))
        return path.read_bytes()

    reference = write(tmp_path / "rows.mcap", None)
    assert write(tmp_path / "batches.mcap", [1, 2, 130, 131, 600, 601, 1100]) == reference
    assert write(tmp_path / "one-batch.mcap", []) == reference
    with LogWriter(tmp_path / "bad.mcap", dt=1e-3) as log:
        frame = log.frame(1)
        frame.channel("/a", flat_schema("t_msgs/msg/A", {"x": "x"}), fields=["x"], columns=[0])
        with pytest.raises(ValueError, match="non-decreasing"):
            frame.extend([3, 2], np.zeros((2, 1)))
        frame.extend([5], np.zeros((1, 1)))
        with pytest.raises(ValueError, match="non-decreasing"):
            frame.extend([4], np.zeros((1, 1)))
        with pytest.raises(ValueError, match="shape"):
            frame.extend([6], np.zeros((1, 2)))


def test_frame_channels_at_their_own_every_log_what_separate_channels_log(tmp_path):
    """Frame channels fed every k-th step (``every``, as /tf at a display rate) write the messages, sequence numbers
    and message indexes that separate channels appending at those steps write, across batch, chunk and periodic-flush
    boundaries and with steps that skip; ``every`` must be an integer >= 1."""
    steps = np.concatenate([np.arange(0, 900), np.arange(905, 1400, 2)])  # a gap, then every other step
    rng = np.random.default_rng(17)
    rows = rng.standard_normal((len(steps), 3)) * 1e4
    fields = {"x": "x [m]"}
    every = {"/a": 1, "/b": 3, "/c": 7}

    def write(path, framed):
        with LogWriter(path, dt=1e-3, chunk_size=4000, batch_size=130, flush_interval=0.35) as log:
            if framed:
                frame = log.frame(3)
                for column, (topic, k) in enumerate(every.items()):
                    frame.channel(topic, flat_schema("t_msgs/msg/A", fields), fields=["x"], columns=[column], every=k)
                frame.extend(steps[:500], rows[:500])
                for step, row in zip(steps[500:700], rows[500:700]):
                    frame.append(int(step), row)
                frame.extend(steps[700:], rows[700:])
            else:
                channels = {topic: log.cdr_channel(topic, flat_schema("t_msgs/msg/A", fields), fields=["x"])
                            for topic in every}
                for step, row in zip(steps, rows):
                    for column, (topic, k) in enumerate(every.items()):
                        if step % k == 0:
                            channels[topic].append(int(step), row[[column]])
        return path

    framed, separate = write(tmp_path / "frame.mcap", True), write(tmp_path / "separate.mcap", False)
    expected = {topic: int(np.sum(steps % k == 0)) for topic, k in every.items()}
    assert check_mcap(framed) == check_mcap(separate) == expected
    check_message_indexes(framed)
    la, lb = read_log(framed), read_log(separate)
    for column, (topic, k) in enumerate(every.items()):
        assert la.topic(topic).messages == lb.topic(topic).messages
        np.testing.assert_array_equal(la.topic(topic).log_time, steps[steps % k == 0] * 1_000_000)
        np.testing.assert_array_equal(la.topic(topic)["x"], rows[steps % k == 0, column])
    for path in (framed, separate):
        with open(path, "rb") as stream:
            sequences: dict[str, list[int]] = {}
            for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
                sequences.setdefault(channel.topic, []).append(message.sequence)
        assert sequences == {topic: list(range(1, n + 1)) for topic, n in expected.items()}

    def on_a_grid(path, every_b):  # rows every 10 steps: a channel at every=10 is fed by every row
        with LogWriter(path, dt=1e-3, chunk_size=4000, batch_size=130, flush_interval=0.35) as log:
            frame = log.frame(3)
            frame.channel("/a", flat_schema("t_msgs/msg/A", fields), fields=["x"], columns=[0])
            frame.channel("/b", flat_schema("t_msgs/msg/A", fields), fields=["x"], columns=[1], every=every_b)
            frame.extend(np.arange(0, 5000, 10), rows[:500])
        return path.read_bytes()

    assert on_a_grid(tmp_path / "grid10.mcap", 10) == on_a_grid(tmp_path / "grid1.mcap", 1)
    with LogWriter(tmp_path / "bad.mcap", dt=1e-3) as log:
        frame = log.frame(1)
        for bad in (0, -2, 1.5, True):
            with pytest.raises(ValueError, match="`every` must be an integer >= 1"):
                frame.channel(f"/bad{bad}", flat_schema("t_msgs/msg/A", fields), fields=["x"], columns=[0], every=bad)


def _write_mixed_run(path: Path, steps: int, **writer_kwargs) -> None:
    """A run with every kind of record: attachments, a frame, an own-buffer channel, JSON events, marks, explicit
    and periodic flushes, and chunks small enough that most batches span several."""
    rows = np.random.default_rng(5).standard_normal((steps, 3))
    with LogWriter(path, dt=1e-3, chunk_size=3000, batch_size=97, flush_interval=0.25,
                   attachments=[("a.txt", "text/plain", b"attached")], **writer_kwargs) as log:
        _write_mixed_channels(log, rows, g_every=4, flush_at=steps // 2)
        log.mark("diverged", time_s=steps * 1e-3, component="unit")


def _write_mixed_channels(log: LogWriter, rows: np.ndarray, g_every: int = 1, flush_at: int | None = None) -> None:
    """One sample per row of ``rows`` (steps, 3): a frame's ``/f`` (columns 0, 1) and ``/g`` (column 2, every
    ``g_every`` steps), an own-buffer channel ``/own`` (the step, every 3rd), a JSON event on ``/e`` every 50th;
    an explicit flush after step ``flush_at``."""
    own = log.cdr_channel("/own", flat_schema("t_msgs/msg/Own", {"u": "u [1]"}), fields=["u"])
    frame = log.frame(3)
    frame.channel("/f", flat_schema("t_msgs/msg/F", {"x": "x [1]", "y": "y [1]"}), fields=["x", "y"], columns=[0, 1])
    frame.channel("/g", flat_schema("t_msgs/msg/G", {"z": "z [1]"}), fields=["z"], columns=[2], every=g_every)
    events = log.channel("/e", "foxglove.Log", log_schema())
    for step in range(len(rows)):
        frame.append(step, rows[step])
        if step % 3 == 0:
            own.append(step, (float(step),))
        if step % 50 == 0:
            events.write(step, log_message(LogLevel.INFO, f"step {step}"))
        if step == flush_at:
            log.flush()


def test_chunk_thread_writes_the_inline_file(tmp_path, monkeypatch):
    """Chunks compressed and written on the chunk thread make the same file, byte for byte, as the caller's thread."""
    import threading

    from sim.io.mcap_file import ChunkedWriter

    writers = []
    write_chunk = ChunkedWriter._write_chunk

    def spy(self, *args):
        writers.append(threading.current_thread().name)
        write_chunk(self, *args)

    monkeypatch.setattr(ChunkedWriter, "_write_chunk", spy)
    _write_mixed_run(tmp_path / "inline.mcap", 900, chunk_thread=False)
    inline = len(writers)
    _write_mixed_run(tmp_path / "thread.mcap", 900)
    assert set(writers[:inline]) == {threading.current_thread().name}
    assert inline > 20 and all(name.startswith("mcap-chunks") for name in writers[inline:])
    assert len(writers) == 2 * inline
    assert (tmp_path / "thread.mcap").read_bytes() == (tmp_path / "inline.mcap").read_bytes()
    assert check_mcap(tmp_path / "thread.mcap") == {"/own": 300, "/f": 900, "/g": 225, "/e": 18}
    assert not any(t.name.startswith("mcap-chunks") for t in threading.enumerate())  # close() ended the thread


def test_chunk_thread_failure_is_raised_and_the_partial_kept(tmp_path, monkeypatch):
    """A chunk write failing on the chunk thread stops the run with that error; the chunks before it come back."""
    from sim.io.mcap_file import ChunkedWriter

    calls = []
    write_chunk = ChunkedWriter._write_chunk

    def failing(self, *args):
        calls.append(len(calls))
        if len(calls) == 4:
            raise OSError(28, "No space left on device")
        write_chunk(self, *args)

    monkeypatch.setattr(ChunkedWriter, "_write_chunk", failing)
    path = tmp_path / "full.mcap"
    with pytest.raises(OSError, match="No space left"):
        write_run(path, 5000, chunk_size=4000)
    assert len(calls) == 4  # nothing more was written after the failed chunk
    assert not path.exists()
    report = recover(tmp_path / "full.mcap.partial", tmp_path / "recovered.mcap")
    assert report.chunk_count == 3
    data = read_log(tmp_path / "recovered.mcap").topic("/hydroplant/cylinders/boom")
    expected = np.array([cylinder_sample(step) for step in range(report.message_count)])
    np.testing.assert_array_equal(data["p_cap_pa"], expected[:, 2])


def test_small_chunks_split_merged_batches_anywhere(tmp_path):
    """Batches of several channels (their own buffers, a frame, irregular messages at the same steps) merged in
    log-time order and cut into chunks of a few records: every value and index entry in place, global order kept."""
    path = tmp_path / "small.mcap"
    steps = 700
    rng = np.random.default_rng(11)
    rows = rng.standard_normal((steps, 3))
    with LogWriter(path, dt=1e-3, chunk_size=1500, batch_size=97, flush_interval=0.25) as log:
        _write_mixed_channels(log, rows)
    assert check_mcap(path) == {"/own": (steps + 2) // 3, "/f": steps, "/g": steps, "/e": steps // 50}
    log = read_log(path)
    np.testing.assert_array_equal(log.topic("/f")["y"], rows[:, 1])
    np.testing.assert_array_equal(log.topic("/g")["z"], rows[:, 2])
    np.testing.assert_array_equal(log.topic("/own")["u"], np.arange(0, steps, 3, dtype=float))
    assert log.topic("/e").text("message") == [f"step {s}" for s in range(0, steps, 50)]
