"""The live Foxglove stream: a WebSocket client on loopback receives the log's advertised schemas and decodes the live
messages of a stepping boom while it runs, and the commands it publishes move the boom.

The loop here is a short frame loop of its own (steps, samples, ``log.drain()``, ``live.show()``), what a paced
``play`` loop does per frame; the client speaks the Foxglove WebSocket protocol directly (JSON control messages,
binary message-data frames: opcode 0x01, subscription id, log time, payload).
"""

from __future__ import annotations

import dataclasses
import json
import re
import struct
import threading
import time

import mcap.records as mr
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from websockets.sync.client import connect

from conftest import MODELS
from sim.io.log_writer import ChannelInfo
from sim.io.mcap_log import LogWriter
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.live.foxglove_live import COMMAND_TOPIC, FoxgloveCommands, FoxgloveLive, flatten_command
from sim.live.frame_topic import FRAME_TOPIC
from sim.live.protocol import CommandSource, FrameSink, FrameStats
from sim.plants.mujoco import MujocoPlant
from sim.run.recorder import CYLINDER_STATE, RunRecorder

SUBPROTOCOL = "foxglove.sdk.v1"  # the WebSocket subprotocol foxglove-sdk's server accepts
TIMEOUT = 10.0  # s: longest wait for any server reply (loopback: milliseconds in practice)
CYLINDER = "/hydroplant/cylinders/boom_cyl"
WATCHED = (CYLINDER, "/tf", "/hydroplant/scene", "/hydroplant/valves/boom_valve", FRAME_TOPIC)


def wait_for(condition, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.005)


class Client:
    """A Foxglove WebSocket client: advertised channels, subscriptions, received message data.

    foxglove-sdk's server sends a channel's advertisement to a connected client before it records the channel as
    advertised to that client; a subscription that arrives in between is rejected with an error status
    ``Unknown channel ID: <id>`` although the channel stays advertised.  The client then subscribes again (what a
    client may always do for an advertised channel it is not subscribed to), as often as the server rejects it.
    """

    UNKNOWN = re.compile(r"Unknown channel ID: (\d+)")

    def __init__(self, ws):
        self.ws = ws
        self.channels: dict[str, dict] = {}  # topic -> advertised channel
        self.advertised: dict[str, list[int]] = {}  # topic -> every channel id advertised for it, in order
        self.unadvertised: set[int] = set()
        self.by_subscription: dict[int, str] = {}
        self.subscription_of: dict[int, int] = {}  # channel id -> subscription id
        self.rejected: list[int] = []  # channel ids of subscriptions the server rejected as unknown
        self.received: list[tuple[str, int, bytes]] = []  # (topic, log time, payload)
        self.times: list[int] = []

    def handle(self, message) -> None:
        if isinstance(message, bytes):
            if message[0] == 0x01:
                subscription, log_time = struct.unpack_from("<IQ", message, 1)
                self.received.append((self.by_subscription[subscription], log_time, message[13:]))
            elif message[0] == 0x02:
                self.times.append(struct.unpack_from("<Q", message, 1)[0])
            return
        body = json.loads(message)
        if body["op"] == "advertise":
            for channel in body["channels"]:
                self.channels[channel["topic"]] = channel
                self.advertised.setdefault(channel["topic"], []).append(channel["id"])
        elif body["op"] == "unadvertise":
            self.unadvertised.update(body["channelIds"])
        elif body["op"] == "status" and (unknown := self.UNKNOWN.fullmatch(body["message"])):
            channel_id = int(unknown.group(1))
            if channel_id in self.subscription_of and channel_id not in self.unadvertised:
                self.rejected.append(channel_id)
                self._send_subscriptions([(self.subscription_of[channel_id], channel_id)])

    def pump(self, idle: float = 0.05, limit: float = 0.5) -> None:
        """Handle every message that arrives until none has for ``idle`` seconds, or for ``limit`` seconds at most (a
        stream faster than 1/``idle`` would otherwise keep the caller from ever checking what it waits for)."""
        end = time.monotonic() + limit
        while time.monotonic() < end:
            try:
                self.handle(self.ws.recv(timeout=idle))
            except TimeoutError:
                return

    def wait_topics(self, topics) -> None:
        deadline = time.monotonic() + TIMEOUT
        while not set(topics) <= set(self.channels):
            assert time.monotonic() < deadline, f"not advertised: {set(topics) - set(self.channels)}"
            try:
                self.handle(self.ws.recv(timeout=0.1))
            except TimeoutError:
                pass

    def subscribe(self, topics) -> None:
        pairs = []
        for topic in topics:
            subscription = len(self.by_subscription) + 1
            self.by_subscription[subscription] = topic
            self.subscription_of[self.channels[topic]["id"]] = subscription
            pairs.append((subscription, self.channels[topic]["id"]))
        self._send_subscriptions(pairs)

    def _send_subscriptions(self, pairs) -> None:
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": s, "channelId": c} for s, c in pairs]}))

    def advertise_commands(self, channel_id: int = 1) -> None:
        self.ws.send(json.dumps({"op": "advertise", "channels": [
            {"id": channel_id, "topic": COMMAND_TOPIC, "encoding": "json", "schemaName": "hydroplant.Commands"}]}))

    def publish(self, message: dict, channel_id: int = 1) -> None:
        self.ws.send(b"\x01" + struct.pack("<I", channel_id) + json.dumps(message).encode())


def test_flatten_command_names_nested_numbers():
    assert flatten_command({"boom_valve": 0.4, "linear": {"x": 1, "y": True}, "axes": [0.5, -1], "name": "x",
                            "bad": float("nan")}) == {"boom_valve": 0.4, "linear.x": 1.0, "axes.0": 0.5, "axes.1": -1.0}


def test_foxglove_live_streams_the_log_and_client_commands_move_the_boom(tmp_path):
    live = FoxgloveLive(port=0)
    try:
        assert isinstance(live, FrameSink) and isinstance(live.commands, CommandSource)
        base = load_scenario(MODELS / "boom" / "lift.scenario.toml")
        inputs = dict(base.inputs, boom_valve=lambda t: live.commands.poll(t).get("boom_valve", 0.0))
        scenario = base.with_overrides(inputs=inputs)
        plant = MujocoPlant(load_scene(scenario))
        log = LogWriter(tmp_path / "live.mcap", dt=scenario.dt)
        recorder = RunRecorder(log, plant, tf_every=scenario.tf_every)
        live.attach(log)
        every, frame_steps = scenario.log_every, 20  # 10 ms samples, 20 ms frames
        recorder.capture(0)

        def frames(count: int, first: int) -> None:
            for index in range(first, first + count):
                start = time.perf_counter()
                for _ in range(frame_steps):
                    plant.step()
                    if plant.step_index % every == 0:
                        recorder.capture(plant.step_index)
                recorder.push()
                log.drain()
                physics = time.perf_counter() - start
                live.show(plant.time, plant.data.qpos, {}, FrameStats(index, plant.time, physics, 0.02, 0.0, False))

        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=[SUBPROTOCOL], open_timeout=TIMEOUT) as ws:
            client = Client(ws)
            client.wait_topics(WATCHED[:-1])
            # every advertised schema is the log's own: the ros2msg text of the cylinder type, the JSON scene schema
            advertised = client.channels[CYLINDER]
            assert (advertised["encoding"], advertised["schemaEncoding"]) == ("cdr", "ros2msg")
            assert advertised["schemaName"] == CYLINDER_STATE.name and advertised["schema"] == CYLINDER_STATE.definition()
            assert (client.channels["/hydroplant/scene"]["encoding"], client.channels["/tf"]["encoding"]) == ("json", "cdr")
            frames(1, 0)  # the frame topic is advertised with the first frame
            client.wait_topics(WATCHED)
            client.subscribe(WATCHED)
            wait_for(lambda: live.commands.subscriptions >= len(WATCHED), "the subscriptions")
            frames(10, 1)  # 0.2 s with the valve closed: the boom holds
            client.pump()
            t_command = plant.time
            client.advertise_commands()
            client.publish({"boom_valve": 1.0})
            wait_for(lambda: live.commands.poll(0.0).get("boom_valve") == 1.0, "the published command")
            frames(30, 11)  # 0.6 s with the valve open: the boom cylinder extends
            client.pump()
            ws.send(json.dumps({"op": "unadvertise", "channelIds": [1]}))
            wait_for(lambda: live.commands.poll(0.0).get("boom_valve") == 0.0, "neutral after the client leaves")
        log.close()
    finally:
        live.close()

    # the live messages decode with the same decoder as the log tests, to the stroke of the cylinder
    schema = mr.Schema(id=1, name=CYLINDER_STATE.name, encoding="ros2msg", data=advertised["schema"].encode())
    decode = DecoderFactory().decoder_for("cdr", schema)
    cylinder = [(t, decode(data)) for topic, t, data in client.received if topic == CYLINDER]
    times = np.array([t for t, _ in cylinder]) * 1e-9
    stroke = np.array([m.position_m for _, m in cylinder])
    assert np.all(np.diff(times) > 0) and times[-1] == pytest.approx(plant.time)
    before, after = stroke[times <= t_command], stroke[times > t_command + 0.1]
    assert len(before) >= 10 and np.ptp(before) < 1e-3  # valve closed: holding within a millimetre
    assert after[-1] - before[-1] > 0.03  # opened by the client: extending (≈ 0.15 m/s at full flow)
    assert np.all(np.diff(after) > 0)

    # the stream is the log: every live message of a log topic is in the file with the same log time and bytes
    with open(tmp_path / "live.mcap", "rb") as f:
        in_file = {(channel.topic, message.log_time): message.data
                   for _, channel, message in make_reader(f).iter_messages(topics=list(WATCHED[:-1]))}
    streamed = [(topic, t, data) for topic, t, data in client.received if topic != FRAME_TOPIC]
    assert {topic for topic, _, _ in streamed} == set(WATCHED[:-1])
    for topic, t, data in streamed:
        assert in_file[(topic, t)] == data, (topic, t)
    # a late subscriber still got the static scene (written at t = 0, before it subscribed)
    scene = [json.loads(data) for topic, _, data in streamed if topic == "/hydroplant/scene"]
    assert scene and {e["id"] for e in scene[0]["entities"]} >= {"world", "boom"}
    # the frame topic and the server clock follow the simulated time
    frames_seen = [t for topic, t, _ in client.received if topic == FRAME_TOPIC]
    assert frames_seen and max(client.times) == pytest.approx(plant.time * 1e9, abs=1)


def test_commands_ignore_other_topics_and_bad_messages():
    commands = FoxgloveCommands()

    class Who:
        def __init__(self, id, topic="", encoding="json"):
            self.id, self.topic, self.encoding = id, topic, encoding

    commands.on_client_advertise(Who(1), Who(5, "/other"))
    commands.on_message_data(Who(1), 5, b'{"boom_valve": 1}')
    commands.on_client_advertise(Who(1), Who(6, COMMAND_TOPIC))
    for bad in (b"not json", b"[1, 2]", b'"text"'):
        commands.on_message_data(Who(1), 6, bad)
    assert commands.poll(0.0) == {} and commands.received == 0
    commands.on_message_data(Who(1), 6, b'{"stick_valve": -0.5, "pump": 150}')
    commands.on_message_data(Who(2), 6, b'{"stick_valve": 1}')  # another client's channel 6, never advertised
    assert commands.poll(0.0) == {"stick_valve": -0.5, "pump": 150.0}
    commands.on_client_unadvertise(Who(1), 6)
    assert commands.poll(0.0) == {"stick_valve": 0.0, "pump": 0.0}


def test_a_client_subscribing_at_each_advertisement_gets_every_channel_advertised_once(tmp_path):
    """Channels added to the log from another thread while a client is connected: the client subscribes to each the
    moment its advertisement arrives (the window in which foxglove-sdk may still reject it as unknown), and every
    channel is advertised once, never withdrawn, and delivers the bytes the file holds."""
    topics = [f"/hydroplant/t{i}" for i in range(120)]
    live = FoxgloveLive(port=0)
    try:
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=[SUBPROTOCOL], open_timeout=TIMEOUT) as ws:
            client = Client(ws)
            log = LogWriter(tmp_path / "many.mcap", dt=1e-3)
            live.attach(log)
            channels = []

            def register():
                for topic in topics:
                    channels.append(log.channel(topic, "hydroplant.Value", {"type": "object"}))
                    time.sleep(0.001)  # one advertisement at a time, each answered by the client's subscription

            worker = threading.Thread(target=register)
            worker.start()
            pending = list(topics)
            deadline = time.monotonic() + TIMEOUT
            while pending:
                assert time.monotonic() < deadline, f"not advertised: {pending}"
                try:
                    client.handle(ws.recv(timeout=0.1))
                except TimeoutError:
                    continue
                ready = [topic for topic in pending if topic in client.channels]
                if ready:
                    client.subscribe(ready)
                    pending = [topic for topic in pending if topic not in ready]
            worker.join()
            wait_for(lambda: (client.pump(0.02) or True) and live.commands.subscriptions >= len(topics),
                     "every subscription accepted")
            for i, channel in enumerate(channels):
                channel.write(0, {"value": i})
            log.drain()
            wait_for(lambda: (client.pump(0.02) or True) and len(client.received) >= len(topics), "every message")
        log.close()
    finally:
        live.close()
    assert all(client.advertised[topic] == [client.channels[topic]["id"]] for topic in topics)  # each once
    assert not client.unadvertised
    with open(tmp_path / "many.mcap", "rb") as f:
        in_file = [(channel.topic, message.log_time, message.data)
                   for _, channel, message in make_reader(f).iter_messages(topics=topics)]
    assert {topic for topic, _, _ in in_file} == set(topics)
    assert sorted(client.received) == sorted(in_file)


def test_a_log_channel_handed_over_again_is_advertised_once():
    info = ChannelInfo(7, "/hydroplant/x", "hydroplant.Value", "jsonschema", b'{"type":"object"}', "json", {})
    live = FoxgloveLive(port=0)
    try:
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=[SUBPROTOCOL], open_timeout=TIMEOUT) as ws:
            client = Client(ws)
            live.channel(info)
            live.channel(info)
            with pytest.raises(ValueError, match="already streamed"):  # another log's channel under the same id
                live.channel(dataclasses.replace(info, topic="/hydroplant/y"))
            client.wait_topics([info.topic])
            client.pump()
    finally:
        live.close()
    assert client.advertised == {info.topic: [client.channels[info.topic]["id"]]} and not client.unadvertised
