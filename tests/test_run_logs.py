"""Run logs: every declared topic and field present, metadata and attachments, strict JSON, exact sim-time stamps."""

import json

import numpy as np
import pytest
from mcap.reader import make_reader

from conftest import MODELS
from sim.cli import main
from sim.mcap_log import read_log
from sim.recorder import CYLINDER_FIELDS, ENERGY_FIELDS, PUMP_FIELDS, SOLVER_FIELDS, VALVE_FIELDS
from sim.runner import run


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


def test_metadata_attachments_and_strict_json(boom_log):
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

    with open(boom_log.log_path, "rb") as f:
        reader = make_reader(f)
        schemas = {s.name for s in reader.get_summary().schemas.values()}
        count = 0
        for schema, channel, message in reader.iter_messages():
            json.loads(message.data, parse_constant=reject)
            count += 1
    assert {"foxglove.JointStates", "foxglove.FrameTransforms", "foxglove.SceneUpdate", "foxglove.Log"} <= schemas
    assert count > 1000


def test_two_runs_log_identical_values(tmp_path):
    """Determinism: the same scenario and settings log identical values."""
    a = run(MODELS / "boom" / "lift.scenario.toml", out=tmp_path / "a.mcap", overrides={"duration": 1.3, "dt": 2e-3})
    b = run(MODELS / "boom" / "lift.scenario.toml", out=tmp_path / "b.mcap", overrides={"duration": 1.3, "dt": 2e-3})
    la, lb = read_log(a.log_path), read_log(b.log_path)
    for topic in ("/hydroplant/cylinders/boom_cyl", "/hydroplant/nodes", "/hydroplant/energy"):
        ta, tb = la.topic(topic), lb.topic(topic)
        assert np.array_equal(ta.log_time, tb.log_time)
        for name in ta.fields if hasattr(ta, "fields") else []:
            assert np.array_equal(ta[name], tb[name])
        assert [m for m in ta.messages] == [m for m in tb.messages]


def test_cli_run_writes_log_and_bad_input_exits_2(tmp_path, capsys):
    out = tmp_path / "cli.mcap"
    assert main(["run", str(MODELS / "boom" / "hold.scenario.toml"), "--duration", "0.05", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert str(out) in printed and "real-time factor" in printed
    assert main(["log", "info", str(out)]) == 0
    assert "status: complete" in capsys.readouterr().out
    assert main(["run", str(tmp_path / "missing.toml")]) == 2
    assert "scenario file not found" in capsys.readouterr().err
