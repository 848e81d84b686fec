"""``hydroplant play``: the paced loop, its commands and mappings, record, replay and resume.

* The excavator dig, 20 s paced at 60 Hz by a scripted operator (the scenario's schedules played as commands at the
  frame rate), in MuJoCo mode and in PBD mode: 1200 frames, the frame statistics in the output and in the log,
  the simulated clock within one frame of the wall clock at the end, no missed deadline when the machine is idle
  (load average below a quarter of the cores); ``hydroplant run --replay`` of the log gives every logged value bit
  for bit, and ``hydroplant run --resume LOG --at 7.3`` every value from its snapshot (7.0 s) on.
* The operator commands are held over each frame (every physics step of a frame logs the frame's command), the
  program source holds its values between its own calls, and frame sinks see every frame without changing the run.
* Overruns: ``catch-up`` keeps the deadlines (no slip), ``slow`` moves them (the slip is reported).
* The ISO and SAE presets: which stick axis moves which valve with which sign; dead band and expo shape.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from conftest import MODELS
from sim.cli import main as cli
from sim.io.mcap_log import RESULT_METADATA, RUN_METADATA, read_log
from sim.io.scenario import ScenarioError, load_scenario
from sim.live.mapping import AXES, PRESETS, Mapping, MappingError, parse_mapping, shape
from sim.run.commands import COMMANDS_TOPIC, CommandTable
from sim.run.play import FrameSummary, HoldSource, PlayOptions, ProgramSource, play, replay, resume
from sim.run.snapshot import SNAPSHOT_TOPIC

DIG = MODELS / "excavator" / "dig.scenario.toml"
LIFT = MODELS / "boom" / "lift.scenario.toml"
PERIOD = 1.0 / 60.0


def assert_same_messages(original, other, *, since: float = 0.0):
    """Every numeric topic of ``other`` (but the frame timing) equals ``original``'s from ``since`` [s] on: the same
    log times and every field equal (``==``, NaN where NaN); returns the number of values compared."""
    a, b = read_log(original), read_log(other)
    compared = 0
    for topic in b.topics:
        tb = b.topic(topic)
        if not hasattr(tb, "fields") or topic in ("/hydroplant/frame", "/hydroplant/events"):
            continue  # (the wall-clock timing, and the events a missed deadline writes, differ from run to run)
        ta = a.topic(topic)
        ka, kb = ta.log_time >= round(since * 1e9), tb.log_time >= round(since * 1e9)
        assert np.array_equal(ta.log_time[ka], tb.log_time[kb]), topic
        for name in tb.fields:
            x, y = np.asarray(ta[name])[ka], np.asarray(tb[name])[kb]
            assert np.array_equal(x, y, equal_nan=True), (topic, name, np.nanmax(np.abs(x - y)))
            compared += x.size
    return compared


def idle() -> bool:
    """Whether the machine is idle enough for deadlines to be met (1-minute load below a quarter of the cores)."""
    return os.getloadavg()[0] < 0.25 * (os.cpu_count() or 1)


# ---------------------------------------------------------------------------------------------- the must-shows
@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_paced_dig_replays_and_resumes_bit_for_bit(tmp_path, capsys, mode):
    log = tmp_path / "play.mcap"
    status = cli(["play", str(DIG), "--mode", mode, "--out", str(log)])
    out = capsys.readouterr().out
    assert status == 0, out
    # the frame statistics in the output ...
    assert "frames        1200 at 60 Hz (16.67 ms), pace 1, overrun policy catch-up" in out
    assert "physics [ms]  median" in out and "p99" in out and "missed" in out
    # ... and in the log: a frame topic, a command row per frame, the summary in the result record
    run = read_log(log)
    result = run.metadata[RESULT_METADATA]
    assert result["status"] == "complete" and int(result["frames"]) == 1200
    frames = run.topic("/hydroplant/frame")
    assert len(frames) == 1200 and len(run.topic(COMMANDS_TOPIC)) == 1200
    assert int(result["missed_deadlines"]) == int(frames["missed"].sum())
    assert float(result["physics_ms_median"]) == pytest.approx(np.median(frames["physics_ms"]))
    assert run.metadata[RUN_METADATA]["play_overrun"] == "catch-up"
    # the loop kept the wall clock: never ahead of it; when every frame met its deadline (always on an idle
    # machine), the simulated clock within one frame of it at the end
    simulated, wall = float(result["simulated_s"]), float(result["wall_s"])
    assert simulated == pytest.approx(20.0, abs=1e-9)
    assert wall >= simulated - 1e-3
    if idle():  # deadlines are only promised on an idle machine
        assert int(result["missed_deadlines"]) == 0, frames["physics_ms"].max()
    if int(result["missed_deadlines"]) == 0:
        assert wall - simulated <= PERIOD, (wall, simulated)
    # the samples follow the scripted operator: the boom valve's command is the schedule's value at each frame start
    steps = run.topic(COMMANDS_TOPIC)["step"]
    boom = load_scenario(DIG).inputs["boom_valve"]
    assert np.array_equal(run.topic(COMMANDS_TOPIC)["boom_valve"], [boom(s * 1e-3) for s in steps])
    # run --replay: the recorded commands reproduce every logged value bit for bit
    again = tmp_path / "replay.mcap"
    assert cli(["run", "--replay", str(log), "--out", str(again)]) == 0
    assert assert_same_messages(log, again) > 100_000
    # run --resume at 7.3 s: from the 7.0 s snapshot every value is the original's
    resumed = tmp_path / "resumed.mcap"
    assert cli(["run", "--resume", str(log), "--at", "7.3", "--out", str(resumed)]) == 0
    first = read_log(resumed).topic("/hydroplant/joint_states").log_time[0]
    assert first == 7_000_000_000
    assert assert_same_messages(log, resumed, since=7.0) > 50_000
    assert read_log(resumed).metadata[RUN_METADATA]["resumed_at_s"] == repr(7.0)


# ---------------------------------------------------------------------------------------------- commands and frames
def test_commands_are_held_over_each_frame_and_sinks_change_nothing(tmp_path):
    """A program at 10 Hz of simulated time drives the boom valve through frames of 60 Hz; the log's valve command
    at every sample is the program's last value at or before the sample's frame start, and a run shown to a sink
    every frame logs the same values as one without."""
    calls = []

    def program(t):
        calls.append(t)
        return {"boom_valve": math.sin(7.0 * t)}

    class Sink:
        def __init__(self):
            self.frames = []

        def show(self, t, qpos, values, stats):
            self.frames.append((t, qpos.copy(), values["boom_valve/command"], stats.index))

        def close(self):
            self.closed = True

    sink = Sink()
    options = PlayOptions(pace=0.0, snapshot_hz=0.0)
    a = play(LIFT, source=ProgramSource(program, rate_hz=10.0), sinks=[sink], options=options,
             out=tmp_path / "a.mcap", overrides={"duration": 1.0})
    b = play(LIFT, source=ProgramSource(lambda t: {"boom_valve": math.sin(7.0 * t)}, rate_hz=10.0), options=options,
             out=tmp_path / "b.mcap", overrides={"duration": 1.0})
    assert a.run.status == b.run.status == "complete"
    assert np.allclose(calls, np.arange(10) * 0.1)  # 10 Hz of simulated time (frames 0, 6, 12, ... start on them)
    assert assert_same_messages(a.run.log_path, b.run.log_path) > 1000
    assert len(sink.frames) == 60 and sink.closed and [f[3] for f in sink.frames] == list(range(60))
    assert sink.frames[-1][0] == pytest.approx(1.0)
    log = read_log(a.run.log_path)
    commands = log.topic(COMMANDS_TOPIC)
    valve = log.topic("/hydroplant/valves/boom_valve")
    frame_of_sample = np.searchsorted(commands.log_time, valve.log_time, side="right") - 1
    # the command logged after each step is that step's, and a sample at a frame's first step was taken after the
    # previous frame's last step
    step_of_sample = np.round(valve.log_time / 1e6).astype(int)
    held = np.where(np.isin(step_of_sample, commands["step"]) & (frame_of_sample > 0), frame_of_sample - 1,
                    frame_of_sample)
    assert np.array_equal(valve["command"][1:], commands["boom_valve"][held][1:])
    assert len(np.unique(commands["boom_valve"])) == 10  # one value per program call (0.0 .. 0.9 s)


def test_command_table_holds_rows_from_their_first_step():
    table = CommandTable(["a", "b"], 1e-3)
    table.append(0, [1.0, 2.0])
    table.append(17, [3.0, 4.0])
    table.append(33, [5.0, 6.0])
    held = table.inputs()["a"]
    times = np.arange(40) * 1e-3  # as the plants form the step times
    expected = np.where(np.arange(40) < 17, 1.0, np.where(np.arange(40) < 33, 3.0, 5.0))
    assert np.array_equal(held.sample(times), expected)
    assert [held(t) for t in times] == list(expected)
    later = table.after(20)
    assert list(later.steps) == [20, 33] and list(later.values[:, 1]) == [4.0, 6.0]
    with pytest.raises(ValueError, match="not after"):
        table.append(33, [0.0, 0.0])


def test_overrun_policies(tmp_path):
    """At 1000× real time every frame misses its deadline: catch-up keeps the deadlines (no slip, the backlog grows
    as lateness), slow moves them by each overrun (the slip is the sum, frames start on their moved deadlines)."""
    results = {}
    for policy in ("catch-up", "slow"):
        options = PlayOptions(pace=1000.0, overrun=policy, snapshot_hz=0.0)
        results[policy] = play(LIFT, source=HoldSource(), options=options, out=tmp_path / f"{policy}.mcap",
                               overrides={"duration": 0.5}).frames
        assert read_log(tmp_path / f"{policy}.mcap").metadata[RESULT_METADATA]["overrun"] == policy
    catch, slow = results["catch-up"], results["slow"]
    assert catch.misses == catch.frames == slow.frames == slow.misses == 30
    events = [e["message"] for e in read_log(tmp_path / "slow.mcap").topic("/hydroplant/events").messages
              if "missed its deadline" in e["message"]]
    assert len(events) == 1 and events[0].startswith("frame 0 ") and "overrun policy slow" in events[0]
    assert catch.slip_s == 0.0 and slow.slip_s > 0.0
    assert catch.lateness_ms[-1] > catch.lateness_ms[1] > 0  # the backlog grows
    assert np.median(slow.lateness_ms) < np.median(catch.lateness_ms)
    assert slow.wall_s == pytest.approx(slow.simulated_s / 1000.0 + slow.slip_s, rel=0.05)


def test_play_resume_with_a_live_source_starts_at_the_snapshot(tmp_path):
    first = play(LIFT, options=PlayOptions(pace=0.0, snapshot_hz=2.0), out=tmp_path / "a.mcap",
                 overrides={"duration": 1.5})
    snapshots = read_log(first.run.log_path).topic(SNAPSHOT_TOPIC)
    assert list(snapshots.log_time) == [0, 500_000_000, 1_000_000_000, 1_500_000_000]
    taken = resume(first.run.log_path, 1.2, source=ProgramSource(lambda t: {"boom_valve": -0.5}),
                   options=PlayOptions(pace=0.0), out=tmp_path / "b.mcap")
    log = read_log(taken.run.log_path)
    commands = log.topic(COMMANDS_TOPIC)
    assert commands["step"][0] == 1000 and set(commands["boom_valve"]) == {-0.5}
    assert log.topic("/hydroplant/joint_states").log_time[0] == 1_000_000_000
    # the first sample is the original's state at 1.0 s
    a = read_log(first.run.log_path).topic("/hydroplant/cylinders/boom_cyl")
    b = log.topic("/hydroplant/cylinders/boom_cyl")
    i = int(np.flatnonzero(a.log_time == 1_000_000_000)[0])
    for name in b.fields:
        assert a[name][i] == b[name][0], name
    assert b["position_m"][-1] < b["position_m"][0]  # the operator lowered the boom from there
    # the taken-over run's own log replays bit for bit (from its first snapshot, with its recorded commands)
    again = replay(taken.run.log_path, out=tmp_path / "c.mcap")
    assert assert_same_messages(taken.run.log_path, again.log_path) > 1000


def test_cli_refuses_bad_combinations(tmp_path, capsys):
    assert cli(["run", "--at", "1.0", "--example", "boom/lift"]) == 2
    assert "--at T needs --resume LOG" in capsys.readouterr().err
    assert cli(["play", str(LIFT), "--replay", str(tmp_path / "x.mcap")]) == 2
    assert cli(["play", str(LIFT), "--rate", "5000"]) == 2
    assert "rate_hz" in capsys.readouterr().err
    plain = tmp_path / "plain.mcap"
    assert cli(["run", str(LIFT), "--duration", "0.1", "--out", str(plain), "--no-progress"]) == 0
    capsys.readouterr()
    assert cli(["run", "--resume", str(plain), "--at", "0.05"]) == 2
    assert "no snapshots" in capsys.readouterr().err
    assert cli(["run", "--replay", str(plain)]) == 2
    assert "no recorded commands" in capsys.readouterr().err


def test_frame_summary_figures():
    summary = FrameSummary(60.0, 1.0, "catch-up", np.arange(1.0, 101.0), np.zeros(100), np.full(100, 16.7),
                           np.arange(100) >= 98, 100 / 60, 100 / 60)
    assert summary.physics == (50.5, pytest.approx(99.01), 100.0)
    assert summary.misses == 2
    assert "missed        2 deadlines" in summary.text()


# ---------------------------------------------------------------------------------------------- mapping and presets
# (axis pushed +1) -> (valve, command) per preset; the excavator's spool sign: +1 = boom up, stick in, bucket curl,
# swing left
EXPECTED = {
    "iso": {"left_x": ("swing_valve", -1.0),    # left stick right: swing right
            "left_y": ("stick_valve", -1.0),    # left stick forward: stick out
            "right_x": ("bucket_valve", -1.0),  # right stick right: bucket dump
            "right_y": ("boom_valve", -1.0)},   # right stick forward: boom down
    "sae": {"left_x": ("swing_valve", -1.0),
            "left_y": ("boom_valve", -1.0),     # SAE: boom on the left hand
            "right_x": ("bucket_valve", -1.0),
            "right_y": ("stick_valve", -1.0)},  # and the stick on the right
}


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_presets_move_the_intended_valve_with_the_intended_sign(preset):
    mapping = Mapping.preset(preset, dead_band=0.1, expo=0.3)
    for axis, (valve, sign) in EXPECTED[preset].items():
        assert mapping.apply({axis: 1.0}) == {valve: sign}, axis
        assert mapping.apply({axis: -1.0}) == {valve: -sign}, axis
        assert mapping.apply({axis: 0.05}) == {valve: 0.0}, axis  # inside the dead band
    assert mapping.targets() == {"boom_valve", "stick_valve", "bucket_valve", "swing_valve"}
    assert mapping.apply({"l2": 1.0, "boom_valve": 0.3}, passthrough={"boom_valve"}) == {"boom_valve": 0.3}


def test_iso_and_sae_swap_boom_and_stick_only():
    iso, sae = Mapping.preset("iso"), Mapping.preset("sae")
    assert iso.axes["left_y"].valve == sae.axes["right_y"].valve == "stick_valve"
    assert iso.axes["right_y"].valve == sae.axes["left_y"].valve == "boom_valve"
    assert iso.axes["left_x"] == sae.axes["left_x"] and iso.axes["right_x"] == sae.axes["right_x"]


@pytest.mark.parametrize("dead_band, expo", [(0.0, 0.0), (0.1, 0.3), (0.25, 1.0), (0.9, 0.5)])
def test_dead_band_and_expo_shape(dead_band, expo):
    half = np.linspace(0.0, 1.0, 2001)
    u = np.concatenate([-half[::-1], half])
    y = np.array([shape(v, dead_band, expo) for v in u])
    assert np.all(y[np.abs(u) <= dead_band] == 0.0)
    assert np.all(np.diff(y) >= 0.0)  # monotone
    assert shape(1.0, dead_band, expo) == 1.0 and shape(-1.0, dead_band, expo) == -1.0
    assert np.array_equal(y, -y[::-1])  # odd
    assert shape(2.0, dead_band, expo) == 1.0 and shape(0.5, dead_band, expo, invert=True) == -shape(0.5, dead_band, expo)
    if expo > 0 and dead_band < 0.5:  # expo: finer near the centre than linear
        s = (0.5 - dead_band) / (1.0 - dead_band)
        assert shape(0.5, dead_band, expo) < s


def test_mapping_section_of_a_scenario(tmp_path):
    def scenario(text):
        path = tmp_path / "m.scenario.toml"
        path.write_text(f'[scene]\nmjcf = "{MODELS / "excavator" / "excavator.xml"}"\n'
                        f'circuit = "{MODELS / "excavator" / "excavator.circuit.toml"}"\n{text}', encoding="utf-8")
        return load_scenario(path)

    m = scenario('[mapping]\npreset = "sae"\ndead_band = 0.2\n[mapping.axes]\nr2 = { valve = "boom_valve", expo = 0.0 }\n').mapping
    assert m.preset_name == "sae" and m.axes["left_y"].dead_band == 0.2 and m.axes["r2"].expo == 0.0
    assert m.axes["r2"].dead_band == 0.2 and not m.axes["r2"].invert
    for bad, message in [('preset = "jis"', "field 'preset'"), ("dead_band = 0.95", "field 'dead_band'"),
                         ("[mapping.axes]\nthumb = { valve = \"boom_valve\" }", "axis 'thumb'"),
                         ("[mapping.axes]\nl2 = { valve = \"boom_valve\", invert = 1 }", "field 'invert'")]:
        text = bad if bad.startswith("[mapping.axes]") else f"[mapping]\n{bad}"
        with pytest.raises(ScenarioError, match=message):
            scenario(text)
    assert set(AXES) >= {axis for p in PRESETS.values() for axis, _ in p.values()}
    with pytest.raises(MappingError):
        parse_mapping({"axes": {"l2": {"dead_band": 0.1}}}, "x")


def test_a_mapping_to_a_missing_valve_is_refused(tmp_path, capsys):
    path = tmp_path / "lift.scenario.toml"
    path.write_text(LIFT.read_text(encoding="utf-8").replace('mjcf = "', f'mjcf = "{LIFT.parent}/').replace(
        'circuit = "', f'circuit = "{LIFT.parent}/') + '\n[mapping]\npreset = "iso"\n', encoding="utf-8")
    assert cli(["play", str(path), "--pace", "0", "--duration", "0.1", "--out", str(tmp_path / "x.mcap")]) == 2
    assert "which is no valve or pump of the circuit" in capsys.readouterr().err


def test_snapshot_messages_round_trip_exactly():
    from sim.run.snapshot import decode, encode

    state = {"format": 1, "kind": "mujoco", "step_index": 7000, "net_time": 0.1 + 0.2,
             "node_pressure": np.array([1e5, np.nan, -0.0, 5e-324, np.inf]), "mj_state": np.arange(6.0).reshape(2, 3) / 3}
    back = decode(json_round_trip(encode(state)))
    assert back.keys() == state.keys()
    assert back["net_time"] == 0.1 + 0.2 and back["step_index"] == 7000
    assert np.array_equal(back["node_pressure"], state["node_pressure"], equal_nan=True)
    assert np.signbit(back["node_pressure"][2]) and back["node_pressure"][3] == 5e-324
    assert np.array_equal(back["mj_state"], state["mj_state"])


def json_round_trip(message):
    import json

    return json.loads(json.dumps(message))


def test_replay_of_a_scenario_changed_in_code(tmp_path):
    """A Scenario object changed in code (log rate, start pose) replays as it ran: the log carries the changes."""
    import dataclasses

    scenario = dataclasses.replace(load_scenario(LIFT).with_overrides(duration=0.5, log_rate_hz=50.0),
                                   qpos={"boom_hinge": 0.25})
    first = play(scenario, options=PlayOptions(pace=0.0), out=tmp_path / "a.mcap")
    again = replay(first.run.log_path, out=tmp_path / "b.mcap")
    assert len(read_log(again.log_path).topic("/hydroplant/joint_states")) == 26  # 50 Hz over 0.5 s
    assert assert_same_messages(first.run.log_path, again.log_path) > 500
