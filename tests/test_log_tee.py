"""A log tee receives every channel and every message of a log, as written to the file, and does not change the file."""

from __future__ import annotations

import pytest
from mcap.reader import make_reader

from sim.io.log_writer import ChannelInfo, LogTee, LogWriter
from sim.io.mcap_log import LogLevel, flat_schema, log_message, log_schema


class Recorder(LogTee):
    def __init__(self):
        self.channels: dict[int, ChannelInfo] = {}
        self.messages_seen: list[tuple[str, int, bytes]] = []
        self.batches = 0

    def channel(self, info):
        self.channels[info.id] = info

    def messages(self, records):
        self.batches += 1
        self.messages_seen += [(self.channels[c].topic, t, data) for c, t, data in records]


def write(path, tee=None):
    with LogWriter(path, dt=1e-3, batch_size=16) as log:
        pump = log.cdr_channel("/pump", flat_schema("t_msgs/msg/Pump", {"p_pa": "p [Pa]"}), fields=["p_pa"],
                               metadata={"units": "SI"})
        if tee is not None:
            log.add_tee(tee)  # after a channel: it is handed over at once
        frame = log.frame(2)
        frame.channel("/a", flat_schema("t_msgs/msg/A", {"x_m": "x [m]"}), columns=[0], fields=["x_m"])
        frame.channel("/b", flat_schema("t_msgs/msg/B", {"v_mps": "v [m/s]"}), columns=[1], fields=["v_mps"], every=5)
        events = log.channel("/events", "foxglove.Log", log_schema())
        for step in range(60):
            pump.append(step, (1e5 + step,))
            frame.append(step, (0.1 * step, -step))
            if step == 30:
                events.write(step, log_message(LogLevel.INFO, "half way"))
            if step % 7 == 0:
                log.drain()
    return path


def test_tee_gets_the_files_channels_and_messages_and_the_file_is_unchanged(tmp_path):
    tee = Recorder()
    with_tee = write(tmp_path / "tee.mcap", tee)
    without = write(tmp_path / "plain.mcap")
    assert with_tee.read_bytes() == without.read_bytes()
    with open(with_tee, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        in_file = [(channel.topic, message.log_time, message.data) for _, channel, message in reader.iter_messages()]
    assert {i.topic for i in tee.channels.values()} == {"/pump", "/a", "/b", "/events"}
    for info in tee.channels.values():
        channel = summary.channels[info.id]
        schema = summary.schemas[channel.schema_id]
        assert (info.topic, info.message_encoding, dict(info.metadata)) == (channel.topic, channel.message_encoding,
                                                                             channel.metadata)
        assert (info.schema_name, info.schema_encoding, info.schema_data) == (schema.name, schema.encoding, schema.data)
    assert tee.messages_seen == in_file  # every message, same bytes, same log times, in the file's order
    assert len(in_file) == 60 + 60 + 12 + 1 and tee.batches >= 60 // 7


class Counter(Recorder):
    """A tee that also counts the ``channel`` calls of each channel id."""

    def __init__(self):
        super().__init__()
        self.calls: dict[int, int] = {}

    def channel(self, info):
        self.calls[info.id] = self.calls.get(info.id, 0) + 1
        super().channel(info)


@pytest.mark.parametrize("chunk_thread", [True, False])
def test_a_tee_gets_each_channel_once_whichever_thread_writes_the_log(tmp_path, chunk_thread):
    """Channels registered before the tee (handed over when it is added) and after it, with the log's start, its
    batches, periodic flushes and drains written by the chunk thread or by the caller's one: each channel of the file
    reaches each tee exactly once, whether the tee came before the channel or after it."""
    early, late = Counter(), Counter()
    path = tmp_path / f"once-{chunk_thread}.mcap"
    with LogWriter(path, dt=1e-3, batch_size=16, flush_interval=0.01, chunk_thread=chunk_thread) as log:
        pump = log.cdr_channel("/pump", flat_schema("t_msgs/msg/Pump", {"p_pa": "p [Pa]"}), fields=["p_pa"])
        log.add_tee(early)
        frame = log.frame(2)
        frame.channel("/a", flat_schema("t_msgs/msg/A", {"x_m": "x [m]"}), columns=[0], fields=["x_m"])
        for step in range(40):
            pump.append(step, (1e5 + step,))
            frame.append(step, (0.1 * step, -step))
            if step == 20:
                log.add_tee(late)
                frame.channel("/b", flat_schema("t_msgs/msg/B", {"v_mps": "v [m/s]"}), columns=[1], fields=["v_mps"])
                log.channel("/events", "foxglove.Log", log_schema()).write(step, log_message(LogLevel.INFO, "x"))
            if step % 9 == 0:
                log.drain()
        log.flush()
    with open(path, "rb") as f:
        in_file = set(make_reader(f).get_summary().channels)
    assert early.calls == dict.fromkeys(in_file, 1)
    assert late.calls == dict.fromkeys(in_file, 1)
