"""``--json`` documents against their schemas (sim/schemas), with the values they carry checked against the
results themselves; exit statuses of partial failures; ``log export`` read back exactly."""

from __future__ import annotations

import csv
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import jsonschema
import numpy as np
import pytest

from conftest import MODELS
from sim import cli
from sim.io.mcap_log import read_log
from sim.jsonout import SCHEMA_NAMES, schema

SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"
BOOM = MODELS / "boom" / "lift.scenario.toml"
SCENES = Path(__file__).parent / "scenes"
ROOT = Path(__file__).resolve().parents[1]


def hydroplant_json(argv, capsys, schema_name):
    """(exit status, document) of an in-process ``hydroplant ARGV --json``: stdout is exactly one JSON document, valid
    against its schema, whose ``exit_code`` is the exit status."""
    try:
        code = cli.main([str(a) for a in argv] + ["--json"])
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    assert out.count("\n") == 1 and out.endswith("\n"), out  # one document, one line
    document = json.loads(out)
    jsonschema.Draft202012Validator(schema(schema_name)).validate(document)
    assert document["exit_code"] == code, err
    assert "Traceback" not in err
    return code, document


def test_every_schema_is_a_valid_draft_2020_12_schema_and_refuses_a_wrong_status():
    for name in SCHEMA_NAMES:
        jsonschema.Draft202012Validator.check_schema(schema(name))
    bad = {"command": "compare", "status": "ok", "exit_code": 4, "reference": {"log": "r", "settings": ""}, "report": "r",
           "merged_log": None, "figures": [], "runs": [], "failed": []}
    with pytest.raises(jsonschema.ValidationError):  # "ok" with exit status 4 is refused
        jsonschema.validate(bad, schema("compare"))
    jsonschema.validate(dict(bad, status="partial"), schema("compare"))


@pytest.fixture(scope="module")
def seed_run(tmp_path_factory):
    """A 0.05 s run of the seed cylinder (60 steps) with ``run --json`` in a subprocess through ``python -m
    hydroplant``: (document, log path, stderr)."""
    out = tmp_path_factory.mktemp("seed") / "seed.mcap"
    result = subprocess.run([sys.executable, "-m", "hydroplant", "run", "--example", "seed_cylinder/closed", "--duration",
                             "0.05", "--out", str(out), "--json"], capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-2000:]
    document = json.loads(result.stdout)
    jsonschema.validate(document, schema("run"))
    return document, out, result.stderr


def test_python_m_hydroplant_run_json_carries_the_run_result(seed_run, tmp_path):
    """The document of ``python -m hydroplant run --json`` is the RunResult of the same run done in-process (runs
    are deterministic): final strokes and joints exactly, and the log it names holds them as its last sample."""
    from sim.run.runner import run

    document, log_path, stderr = seed_run
    result = run(SEED, out=tmp_path / "again.mcap", overrides={"duration": 0.05})
    assert document["status"] == result.status == "complete" and document["exit_code"] == 0
    assert document["final_strokes_m"] == result.final_strokes and document["final_joints"] == result.final_joints
    assert document["steps"] == result.steps == 60 and document["method"] == "mujoco:implicit"
    assert document["log"] == str(log_path)
    cyl = read_log(log_path).topic("/hydroplant/cylinders/cyl")
    assert cyl["position_m"][-1] == document["final_strokes_m"]["cyl"]
    assert "status        complete" in stderr  # the text report went to stderr
    assert "\r" not in stderr  # no progress line into a pipe


def test_bad_input_with_json_prints_the_error_document(tmp_path, capsys):
    code, document = hydroplant_json(["run", tmp_path / "missing.scenario.toml"], capsys, "error")
    assert code == 2 and "missing.scenario.toml" in document["error"] and document["command"] == "run"
    code, document = hydroplant_json(["inspect", SEED, "--example", "boom/lift"], capsys, "error")
    assert code == 2 and "either a SCENARIO file or --example" in document["error"]


def test_log_info_json_lists_what_read_log_reads(seed_run, tmp_path, capsys):
    _, log_path, _ = seed_run
    code, document = hydroplant_json(["log", "info", log_path], capsys, "log-info")
    log = read_log(log_path)
    assert code == 0 and document["status"] == "ok" and document["run_status"] == "complete"
    assert {t["name"]: t["messages"] for t in document["topics"]} == log.message_counts
    assert document["end_time_s"] == pytest.approx(0.05) and document["run"]["scene"] == "seed_cylinder"
    damaged = tmp_path / "damaged.mcap"
    data = bytearray(log_path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte inside the (single) chunk
    damaged.write_bytes(bytes(data))
    code, document = hydroplant_json(["log", "info", damaged], capsys, "log-info")
    assert code == 1 and document["status"] == "damaged" and document["damage"]


def test_inspect_json_gives_the_explicit_bound_that_decides_stability(capsys):
    """Boom, explicit coupling: a step just above the largest stable dt inspect reports is unstable, one below stable."""
    code, doc = hydroplant_json(["inspect", "--example", "boom/lift", "--method", "mujoco:explicit"], capsys, "inspect")
    assert code == 0 and doc["method"] == "mujoco:explicit" and doc["coupling"] == "explicit"
    bound = doc["largest_stable_dt_s"]
    assert bound is not None and 0 < bound < 1
    _, above = hydroplant_json(["inspect", BOOM, "--method", "mujoco:explicit", "--dt", bound * 1.2], capsys, "inspect")
    _, below = hydroplant_json(["inspect", BOOM, "--method", "mujoco:explicit", "--dt", bound * 0.8], capsys, "inspect")
    assert not all(a["stable"] for a in above["actuators"]) and all(a["stable"] for a in below["actuators"])
    _, implicit = hydroplant_json(["inspect", BOOM, "--method", "mujoco:implicit"], capsys, "inspect")
    assert implicit["largest_stable_dt_s"] is None  # unbounded (inf) is null in JSON
    assert [b["name"] for b in implicit["bodies"]] and implicit["total_mass_kg"] > 0


def test_check_json_counts_the_failed_checks(tmp_path, capsys):
    code, doc = hydroplant_json(["check", SCENES / "hold.scenario.toml"], capsys, "check")
    assert code == 0 and doc["status"] == "ok" and doc["problems"] == 0 and doc["scenarios"][0]["passed"]
    for name in ("hold.scenario.toml", "loop.circuit.toml"):
        shutil.copy(SCENES / name, tmp_path / name)
    xml = (SCENES / "loop_arm.xml").read_text().replace('range="-0.2218 0.2531"', 'range="-0.5 0.8"')
    (tmp_path / "loop_arm.xml").write_text(xml)
    code, doc = hydroplant_json(["check", tmp_path / "hold.scenario.toml"], capsys, "check")
    assert code == 1 and doc["status"] == "failed"
    assert doc["problems"] == len(doc["scenarios"][0]["failed_checks"]) >= 1
    assert any("OUTSIDE the stroke" in line for line in doc["scenarios"][0]["failed_checks"])


# ---------------------------------------------------------------------------------------
# Partial failure: exit status 4
# ---------------------------------------------------------------------------------------


def test_compare_with_a_diverged_run_exits_4_and_names_it(tmp_path, capsys):
    from test_compare import sine, write_log

    ref = write_log(tmp_path / "ref.mcap", 1e-3, 0.5, stroke=sine)
    good = write_log(tmp_path / "good.mcap", 2e-3, 0.5, stroke=lambda t: sine(t) + 0.001)
    bad = write_log(tmp_path / "bad.mcap", 1e-3, 0.5, stroke=sine, diverged_at=0.2)
    code, doc = hydroplant_json(["compare", ref, good, bad, "--out", tmp_path / "out"], capsys, "compare")
    assert code == 4 and doc["status"] == "partial" and doc["failed"] == ["bad"]
    runs = {r["label"]: r for r in doc["runs"]}
    assert runs["good"]["stable"] and runs["good"]["errors"]["stroke"]["max_abs"] == pytest.approx(0.001, rel=1e-6)
    assert runs["bad"]["status"] == "diverged" and runs["bad"]["diverged_at_s"] == pytest.approx(0.2)
    assert Path(doc["report"]).is_file() and Path(doc["merged_log"]).is_file()
    code, doc = hydroplant_json(["compare", ref, good, "--out", tmp_path / "out2"], capsys, "compare")
    assert code == 0 and doc["status"] == "ok" and doc["failed"] == []


def failing_point(point: dict) -> dict:
    """A tradeoff sweep function whose every setting fails (as a setting the plant refuses does)."""
    return {"status": "error", "message": "RuntimeError: refused", "diverged_at_s": math.nan, "wall_per_sim_s": math.nan,
            "wall_per_sim_s_runs": [], "energy": {}, "signals": {}}


def test_tradeoff_with_failed_settings_exits_4_and_writes_the_report(tmp_path, monkeypatch, capsys):
    """Seed cylinder, 20 ms, MuJoCo mode only: the explicit coupling diverges at the coarse steps (exit 4, the failed
    settings named); with every setting failing there is no figure and no traceback, still exit 4."""
    monkeypatch.chdir(tmp_path)  # reference and sweep caches, default outputs: here
    argv = ["tradeoff", SEED, "--quick", "--duration", "0.02", "--modes", "mujoco", "--fidelities", "compressible",
            "--workers", "1", "--out", tmp_path / "out"]
    code, doc = hydroplant_json(argv, capsys, "tradeoff")
    statuses = {s["label"]: s["status"] for s in doc["settings"]}
    assert code == 4 and doc["status"] == "partial"
    assert doc["failed"] == [label for label, status in statuses.items() if status != "complete"] != []
    assert all(s["status"] == "complete" for s in doc["settings"] if s["method"] == "mujoco:implicit")
    assert all(s["error"] == "" for s in doc["settings"] if s["status"] != "error")  # diverged is not an error
    assert any(s["pareto"]["stroke"] for s in doc["settings"]) and Path(doc["figure"]).is_file()
    with open(doc["csv"], newline="") as f:
        assert [r["status"] for r in csv.DictReader(f)] == list(statuses.values())

    import sim.tools.tradeoff as tradeoff

    monkeypatch.setattr(tradeoff, "run_point", failing_point)
    code, doc = hydroplant_json(argv[:-1] + [tmp_path / "all-failed"], capsys, "tradeoff")
    assert code == 4 and doc["figure"] is None and len(doc["failed"]) == len(doc["settings"]) > 0
    assert all(s["status"] == "error" and s["error"] == "RuntimeError: refused" for s in doc["settings"])
    report = Path(doc["report"]).read_text()
    assert "No figure" in report and "RuntimeError: refused" in report


# ---------------------------------------------------------------------------------------
# log export
# ---------------------------------------------------------------------------------------


def _same(a, b) -> bool:
    return np.array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float), equal_nan=True)


def test_log_export_csv_and_hdf5_hold_read_logs_arrays_exactly(seed_run, tmp_path, capsys):
    _, source, _ = seed_run
    log_path = tmp_path / "seed.mcap"
    shutil.copy(source, log_path)
    log = read_log(log_path)
    code, doc = hydroplant_json(["log", "export", log_path, "--format", "csv"], capsys, "log-export")
    assert code == 0 and doc["out"] == str(tmp_path / "seed-csv")
    exported = {t["topic"]: t for t in doc["topics"]}
    assert set(exported) == {t for t in log.topics if t != "/hydroplant/scene"}
    for topic, entry in exported.items():
        data = log.topic(topic)
        with open(entry["file"], newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
        header, body = rows[0], rows[1:]
        assert header == ["t"] + data.fields + data.text_fields and len(body) == len(data)
        numeric = np.array([[float(v) for v in row[:1 + len(data.fields)]] for row in body]).reshape(len(data), -1)
        assert _same(numeric[:, 0], data.t)
        for k, name in enumerate(data.fields, 1):
            assert _same(numeric[:, k], data[name]), (topic, name)
    cyl = np.loadtxt(tmp_path / "seed-csv" / "hydroplant.cylinders.cyl.csv", delimiter=",", skiprows=1)
    assert _same(cyl[:, 5], log.topic("/hydroplant/cylinders/cyl")["p_cap_pa"])  # numpy reads it as it is

    before = (tmp_path / "seed-csv" / "tf.csv").read_bytes()
    code, doc = hydroplant_json(["log", "export", log_path], capsys, "error")  # the files exist: refused
    assert code == 2 and "--overwrite" in doc["error"]
    assert (tmp_path / "seed-csv" / "tf.csv").read_bytes() == before
    code, _ = hydroplant_json(["log", "export", log_path, "--overwrite"], capsys, "log-export")
    assert code == 0

    code, doc = hydroplant_json(["log", "export", log_path, "--format", "hdf5", "--topics", "/hydroplant/cylinders/cyl",
                                 "/hydroplant/joint_states"], capsys, "log-export")
    assert code == 0 and doc["files"] == [str(tmp_path / "seed.h5")]
    with h5py.File(tmp_path / "seed.h5", "r") as f:
        assert all(f[g["group"]].attrs["topic"] == g["topic"] for g in doc["topics"])
        for topic in ("/hydroplant/cylinders/cyl", "/hydroplant/joint_states"):
            group, data = f[topic], log.topic(topic)
            assert _same(group["t"][()], data.t)
            for name in data.fields:
                assert _same(group[name][()], data[name]), (topic, name)
        assert f.attrs["hydroplant.run.scene"] == "seed_cylinder"
    code, doc = hydroplant_json(["log", "export", log_path, "--format", "hdf5", "--topics", "/nope"], capsys, "error")
    assert code == 2 and "/nope" in doc["error"]


def test_a_diverged_run_json_says_so_with_exit_3(tmp_path, capsys):
    """The seed cylinder with the explicit coupling diverges within its first steps (docs/figures/seed-compare.md):
    status ``diverged``, exit 3, the message naming the time, and the log kept with that status."""
    code, doc = hydroplant_json(["run", SEED, "--method", "mujoco:explicit", "--duration", "0.05", "--out",
                                 tmp_path / "explicit.mcap"], capsys, "run")
    assert code == 3 and doc["status"] == "diverged" and doc["method"] == "mujoco:explicit"
    assert doc["simulated_time_s"] < 0.05 and "t = " in doc["message"]
    assert read_log(doc["log"]).status == "diverged"
