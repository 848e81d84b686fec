"""``play`` end to end with a live Foxglove client: while the paced loop runs, a WebSocket client on loopback receives
the advertised schemas, decodes the live cylinder messages, and the command it publishes on ``/hydroplant/commands``
moves the machine; the log records the commands the frames used.

The client is the Foxglove WebSocket protocol spoken directly (:class:`test_live_foxglove.Client`).
"""

from __future__ import annotations

import threading

import mcap.records as mr
import numpy as np
import pytest
from mcap_ros2.decoder import DecoderFactory
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from conftest import MODELS
from sim.io.mcap_log import read_log
from sim.live.foxglove_live import FoxgloveLive
from sim.run.commands import COMMANDS_TOPIC
from sim.run.play import PlayOptions, play
from sim.run.recorder import CYLINDER_STATE
from test_live_foxglove import SUBPROTOCOL, TIMEOUT, Client, wait_for

CYLINDER = "/hydroplant/cylinders/boom_cyl"


def test_a_foxglove_client_watches_play_and_its_command_moves_the_boom(tmp_path):
    from sim.run.runner import run

    run(MODELS / "boom" / "lift.scenario.toml", out=tmp_path / "warm.mcap", overrides={"duration": 0.01})  # kernels loaded
    live = FoxgloveLive(port=0)
    outcome = {}

    def operate():
        try:
            outcome["result"] = play(MODELS / "boom" / "lift.scenario.toml", source=live.commands, sinks=[live],
                                     options=PlayOptions(rate_hz=60.0, pace=1.0), out=tmp_path / "play.mcap",
                                     overrides={"duration": 6.0})  # long enough to subscribe on a busy machine
        except BaseException as exc:  # noqa: BLE001 - reported by the test thread below
            outcome["error"] = exc

    runner = threading.Thread(target=operate, daemon=True)
    try:
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=[SUBPROTOCOL], open_timeout=TIMEOUT) as ws:
            client = Client(ws)
            runner.start()
            client.wait_topics([CYLINDER])
            advertised = client.channels[CYLINDER]
            assert (advertised["encoding"], advertised["schemaEncoding"]) == ("cdr", "ros2msg")
            assert advertised["schema"] == CYLINDER_STATE.definition()
            client.subscribe([CYLINDER])
            wait_for(lambda: (client.pump(0.02) or True) and len(client.received) >= 30, "30 live cylinder samples")
            client.advertise_commands()
            client.publish({"boom_valve": 1.0})
            try:
                while runner.is_alive():
                    client.pump(0.05)
            except ConnectionClosed:  # play closes its sinks, and so the server, when the run ends
                pass
        runner.join(TIMEOUT)
    finally:
        live.close()
    assert "error" not in outcome, outcome.get("error")
    # every topic was advertised once, and none withdrawn while the run went on
    assert all(len(ids) == 1 for ids in client.advertised.values()) and not client.unadvertised
    result = outcome["result"]
    assert result.run.status == "complete" and result.frames.frames == 360

    # the live samples decode to the cylinder's stroke: still, then extending once the client's command arrived
    schema = mr.Schema(id=1, name=CYLINDER_STATE.name, encoding="ros2msg", data=advertised["schema"].encode())
    decode = DecoderFactory().decoder_for("cdr", schema)
    live_t = np.array([t for topic, t, _ in client.received if topic == CYLINDER]) * 1e-9
    live_x = np.array([decode(data).position_m for topic, _, data in client.received if topic == CYLINDER])
    assert np.all(np.diff(live_t) > 0) and live_x[-1] - live_x[0] > 0.03

    # the log records the commands of every frame: 0 until the client's command, 1 after it, and the stroke follows
    log = read_log(result.run.log_path)
    commands = log.topic(COMMANDS_TOPIC)
    valve = np.asarray(commands["boom_valve"])
    opened = np.flatnonzero(valve == 1.0)
    assert len(opened) and np.all(valve[: opened[0]] == 0.0) and np.all(valve[opened[0]:] == 1.0)
    t_open = commands.t[opened[0]]
    cylinder = log.topic(CYLINDER)
    x = np.asarray(cylinder["position_m"])
    before = x[cylinder.t < t_open]
    assert np.ptp(before) < 1e-3  # the boom held while the valve was closed
    assert x[-1] - before[-1] > 0.03
    # every live sample is the logged one at the same time
    logged = dict(zip(np.round(cylinder.t * 1e9).astype(np.int64), x))
    for t, value in zip(np.round(live_t * 1e9).astype(np.int64), live_x):
        assert logged[t] == value


def test_play_with_the_viewer_and_the_keyboard_drives_the_boom_by_the_iso_pattern(tmp_path, monkeypatch):
    """``play --view --input keyboard``: the viewer (a stand-in window here) shows every frame, and the keys pressed in
    it drive the valves through the ISO pattern: right stick forward (boom down) is the boom valve negative."""
    import argparse

    from sim.live.devices import KeyboardSource
    from sim.run import play as play_module
    from test_live_viewer import Handle

    handles = []

    def launch(m, d, *, key_callback, show_left_ui, show_right_ui):
        handles.append((Handle(m), key_callback))
        return handles[-1][0]

    real = play_module._endpoints
    monkeypatch.setattr(play_module, "_endpoints", lambda args, scene=None: real(args, scene, launch=launch))
    pressed = []

    def press_during_play(self, t):  # a key pressed in the window between the first frames and the rest
        if t > 0.2 and not pressed:
            pressed.append(t)
            for _ in range(5):  # five presses: the axis at 0.5, past the pattern's dead band
                handles[0][1](KEY_BOOM_DOWN)
        return self.axes_now(t)

    KEY_BOOM_DOWN = next(code for code, (axis, sign) in KeyboardSource().keys.items() if axis == "right_y" and sign > 0)
    monkeypatch.setattr(KeyboardSource, "axes_now", KeyboardSource.poll, raising=False)
    monkeypatch.setattr(KeyboardSource, "poll", press_during_play)
    args = argparse.Namespace(scenario=MODELS / "boom" / "lift.scenario.toml", example=None, replay=None, resume=None,
                              at=None, rate=60.0, pace=0.0, overrun="catch-up", snapshot_hz=1.0, input="keyboard",
                              pattern="iso", view=True, foxglove=None, mode=None, coupling=None, dt=None, duration=0.5,
                              substeps=None, pbd_substeps=None, no_monitor=False, out=tmp_path / "kb.mcap",
                              overwrite=False)
    assert play_module.main(args) == 0
    handle = handles[0][0]
    assert handle.syncs == 30 and handle.texts  # every frame shown, with the overlay
    valve = np.asarray(read_log(tmp_path / "kb.mcap").topic(COMMANDS_TOPIC)["boom_valve"])
    assert valve[0] == 0.0 and valve[-1] < 0.0  # forward on the right stick lowers the boom (ISO)
