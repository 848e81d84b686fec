"""Run logs: every declared topic and field present, metadata and attachments, strict JSON and ROS 2 CDR, exact
sim-time stamps."""

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from conftest import MODELS
from sim.cli import main
from sim.io.mcap_log import read_log
from sim.run.recorder import CYLINDER_FIELDS, ENERGY_FIELDS, PUMP_FIELDS, SOLVER_FIELDS, VALVE_FIELDS
from sim.run.runner import run


@pytest.fixture(scope="module")
def boom_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("logs") / "lift.mcap"
    result = run(MODELS / "boom" / "lift.scenario.toml", out=out, overrides={"duration": 1.5, "dt": 2e-3})
    assert result.status == "complete"
    return result


def test_topics_and_fields(boom_log):
    log = read_log(boom_log.log_path)
    expected = {
        "/hydroplant/joint_states", "/hydroplant/cylinders/boom_cyl", "/hydroplant/valves/boom_valve",
        "/hydroplant/pumps/pump", "/hydroplant/nodes", "/hydroplant/flows", "/hydroplant/energy",
        "/hydroplant/solver", "/hydroplant/events", "/tf", "/hydroplant/scene",
    }
    assert expected <= set(log.topics)
    for topic, fields in (
        ("/hydroplant/cylinders/boom_cyl", CYLINDER_FIELDS), ("/hydroplant/valves/boom_valve", VALVE_FIELDS),
        ("/hydroplant/pumps/pump", PUMP_FIELDS), ("/hydroplant/energy", ENERGY_FIELDS), ("/hydroplant/solver", SOLVER_FIELDS),
    ):
        data = log.topic(topic)
        for name in fields:
            assert np.all(np.isfinite(data[name])), (topic, name)
    nodes = log.topic("/hydroplant/nodes")
    for node in ("supply", "boom_cyl_cap", "boom_cyl_rod"):
        assert np.all(nodes[f"pressure_pa.{node}"] > 0)
    joints = log.topic("/hydroplant/joint_states")
    assert np.all(np.isfinite(joints["position/boom_hinge"]))
    # 100 Hz log of a 500 Hz run over 1.5 s: samples at exact multiples of 10 ms
    t = log.topic("/hydroplant/cylinders/boom_cyl").log_time
    assert len(t) == 151 and np.all(np.diff(t) == 10_000_000)


def test_metadata_attachments_strict_json_and_cdr(boom_log):
    log = read_log(boom_log.log_path)
    run_meta = log.metadata["hydroplant.run"]
    for key in ("scenario", "mode", "coupling", "dt_s", "mujoco_version", "hydroplant_version", "python_version"):
        assert run_meta[key]
    assert run_meta["mode"] == "mujoco" and float(run_meta["dt_s"]) == 2e-3
    assert log.status == "complete"
    assert set(log.attachments) == {"scenario.toml", "circuit.toml", "boom.xml"}
    assert log.attachments["boom.xml"] == (MODELS / "boom" / "boom.xml").read_bytes()

    def reject(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    decoders = DecoderFactory()
    with open(boom_log.log_path, "rb") as f:
        reader = make_reader(f)
        schemas = {s.name: s.encoding for s in reader.get_summary().schemas.values()}
        count = 0
        for schema, channel, message in reader.iter_messages():
            if channel.message_encoding == "json":  # the irregular topics: scene, events
                json.loads(message.data, parse_constant=reject)
            else:  # every numeric topic: ROS 2 CDR that Foxglove's own decoder reads
                assert channel.message_encoding == "cdr" and message.data[:4] == b"\x00\x01\x00\x00"
                decoders.decoder_for("cdr", schema)(message.data)
            count += 1
    assert schemas["foxglove_msgs/msg/JointStates"] == schemas["foxglove_msgs/msg/FrameTransforms"] == "ros2msg"
    assert schemas["hydroplant_msgs/msg/CylinderState"] == "ros2msg"
    assert schemas["foxglove.SceneUpdate"] == schemas["foxglove.Log"] == "jsonschema"
    assert count > 1000


def test_two_runs_log_identical_values(tmp_path):
    """Determinism: the same scenario and settings log identical values."""
    a = run(MODELS / "boom" / "lift.scenario.toml", out=tmp_path / "a.mcap", overrides={"duration": 1.3, "dt": 2e-3})
    b = run(MODELS / "boom" / "lift.scenario.toml", out=tmp_path / "b.mcap", overrides={"duration": 1.3, "dt": 2e-3})
    la, lb = read_log(a.log_path), read_log(b.log_path)
    for topic in ("/hydroplant/cylinders/boom_cyl", "/hydroplant/nodes", "/hydroplant/energy"):
        ta, tb = la.topic(topic), lb.topic(topic)
        assert np.array_equal(ta.log_time, tb.log_time)
        for name in ta.fields:
            assert np.array_equal(ta[name], tb[name], equal_nan=True)
    assert _messages(a.log_path) == _messages(b.log_path)


def test_cli_run_writes_log_and_bad_input_exits_2(tmp_path, capsys):
    out = tmp_path / "cli.mcap"
    assert main(["run", str(MODELS / "boom" / "hold.scenario.toml"), "--duration", "0.05", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert str(out) in printed and "real-time factor" in printed
    assert main(["log", "info", str(out)]) == 0
    assert "status: complete" in capsys.readouterr().out
    assert main(["run", str(tmp_path / "missing.toml")]) == 2
    err = capsys.readouterr().err
    assert "missing.toml" in err and "file not found" in err and err.count("\n") == 1


# ------------------------------------------------------------------------ batched logging
def test_batched_hydraulic_terms_equal_the_per_sample_functions():
    """The node relations and stored energy called on batches (rows = samples, as the run logger does) equal the
    per-sample calls to round-off, on the excavator circuit and on a circuit with every branch kind, an accumulator,
    a compliant hose and entrained air."""
    from hydraulics.circuit import load_circuit
    from hydraulics.energy import stored_energy, stored_energy_at
    from hydraulics.network import NetworkModel
    from conftest import network_from_toml
    from test_network import ALL_KINDS

    rng = np.random.default_rng(3)
    for net in (NetworkModel.from_circuit(load_circuit(MODELS / "excavator" / "excavator.circuit.toml")),
                network_from_toml(ALL_KINDS)):
        strokes = np.where(net.actuator_kind == 0, 1.0, 0.0)
        strokes[net.cylinder_actuator] = net.cylinder_stroke
        states = []
        for _ in range(9):
            x = np.where(net.actuator_kind == 0, rng.uniform(-0.05, 1.05, net.actuator_count) * strokes, rng.uniform(-3, 3, net.actuator_count))
            p = rng.uniform(2e3, 3.5e7, net.node_count)  # below and above the accumulator precharge, down to cavitation
            states.append(net.state(actuator_position=x, node_pressure=p))
        oil = np.array([s.node_oil for s in states])
        p = np.array([s.node_pressure for s in states])
        x = np.array([s.actuator_position for s in states])
        volumes = net.node_volume_at(x, p)
        energy = stored_energy_at(net, oil, p, x, volumes)
        stiffness = net.chamber_stiffness(p, x)
        assert stiffness.shape == (len(states), 2, len(net.cylinder_cap_node))
        for i, s in enumerate(states):
            v, dv = net.node_volume_at(s.actuator_position, s.node_pressure)
            np.testing.assert_allclose(volumes[0][i], v, rtol=1e-15, atol=0)
            np.testing.assert_allclose(volumes[1][i], dv, rtol=1e-15, atol=0)
            single = stored_energy(net, s)
            assert energy[i] == pytest.approx(single, rel=1e-12, abs=1e-9 * max(1.0, abs(single)))
            np.testing.assert_allclose(stiffness[i], net.chamber_stiffness(s.node_pressure, s.actuator_position), rtol=1e-14)
        assert stored_energy_at(net, oil[:0], p[:0], x[:0]).shape == (0,)
        # any number of leading axes: a (3, 3) grid of samples gives the same values as the 9 rows
        grid = net.node_volume_at(x.reshape(3, 3, -1), p.reshape(3, 3, -1))
        np.testing.assert_array_equal(grid[0].reshape(9, -1), volumes[0])
        np.testing.assert_array_equal(stored_energy_at(net, oil.reshape(3, 3, -1), p.reshape(3, 3, -1), x.reshape(3, 3, -1)).ravel(), energy)


def _messages(path):
    """Log times and message bytes per topic (bytes: NaN-safe, and stricter than decoded values)."""
    out = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append((message.log_time, bytes(message.data)))
    return out


def test_ring_size_does_not_change_the_log(tmp_path, monkeypatch):
    """Samples derived one at a time (ring of 1) or in batches that straddle the periodic flushes give the same
    file, byte for byte: the batching changes when values are computed, not what is logged."""
    import sim.run.recorder

    overrides = {"duration": 2.3, "dt": 5e-3, "log_rate_hz": 200.0}  # 460 samples, a periodic flush at 2 s
    runs = {}
    for ring in (1, 7, sim.run.recorder.RING_SIZE):
        monkeypatch.setattr(sim.run.recorder, "RING_SIZE", ring)
        result = run(MODELS / "boom" / "lift.scenario.toml", out=tmp_path / f"ring{ring}.mcap", overrides=overrides)
        assert result.status == "complete"
        runs[ring] = result
    data = {ring: r.log_path.read_bytes() for ring, r in runs.items()}
    first = data[1]
    for ring, blob in data.items():
        if blob != first:  # differ only in stamps they should not have: show where
            assert _messages(runs[ring].log_path) == _messages(runs[1].log_path), ring
            pytest.fail(f"ring {ring}: same messages, different bytes")
    assert runs[1].energy == runs[sim.run.recorder.RING_SIZE].energy
    assert runs[1].final_strokes == runs[sim.run.recorder.RING_SIZE].final_strokes


def test_energy_growth_is_found_at_the_first_offending_sample_of_a_batch(tmp_path, monkeypatch):
    """Energy growth checked per batch stops the run at the same sample, time and log as a check after every
    sample (ring of 1): the seed cylinder with the explicit coupling."""
    import sim.run.recorder

    results = {}
    for ring in (1, sim.run.recorder.RING_SIZE):
        monkeypatch.setattr(sim.run.recorder, "RING_SIZE", ring)
        results[ring] = run(MODELS / "seed_cylinder" / "closed.scenario.toml", out=tmp_path / f"seed{ring}.mcap",
                            overrides={"coupling": "explicit"})
    one, batch = results[1], results[sim.run.recorder.RING_SIZE]
    assert one.status == batch.status == "diverged" and "energy growth" in batch.message
    assert batch.message == one.message and batch.steps == one.steps and batch.simulated_time == one.simulated_time
    assert batch.energy == one.energy and batch.final_strokes == one.final_strokes
    log = read_log(batch.log_path)
    assert float(log.metadata["hydroplant.result"]["time_s"]) == batch.simulated_time
    assert log.topic("/hydroplant/energy").log_time[-1] == round(batch.simulated_time * 1e9)
    assert _messages(batch.log_path) == _messages(one.log_path)
