"""Stability at the extremes: the implicit coupling stays stable where the explicit baseline diverges, as the maps say.

Every extreme of the stability map (bulk modulus, step size, load mass, dead
volume, valve slam, pump start against a closed centre, end-stop impact,
cavitation) is staged with :func:`sim.tools.stability.write_variant` and run briefly
(fractions of a second, coarse dt where the extreme is about dt).  The
recommended setting (implicit coupling) must finish with finite states,
pressures inside [cavitation floor, relief + override (+ the spike of a trapped
moving load)] and energy bounded by the pump work; the explicit baseline must
diverge at the same setting.  The guards must predict the same.
"""

import csv
import hashlib
import math
import tomllib
from dataclasses import replace

import mujoco
import numpy as np
import pytest

from conftest import MODELS
from sim import cli
from sim.tools import stability as st
from sim.run.guards import EXPLICIT_OMEGA_DT_LIMIT, check, check_scenario, expected_stable
from sim.io.mcap_log import read_log
from sim.plants.mujoco import MujocoPlant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene

SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"
BOOM = MODELS / "boom" / "lift.scenario.toml"
ENERGY_SLACK = 1.0  # J: round-off allowance of the energy bound
ENERGY_SWING = 0.05  # of |E0| + pump work, plus omega_h*dt: symplectic (theta = 0) steps swing the energy by ~omega_h*dt/2
PNG_LIMIT = 150_000  # B


@pytest.fixture(scope="module")
def seed_facts():
    return st.scene_facts(SEED, st.QUICK_GRID)


@pytest.fixture(scope="module")
def boom_facts():
    return st.scene_facts(BOOM, st.QUICK_GRID)


def grid_point(facts, config, directory, *, coupling, dt, duration, mode="mujoco", log_rate_hz=None, pbd_blend=False):
    """The map's point of ``config`` (variant written into ``directory``), logged every step by default."""
    path = st.write_variant(facts, config, directory / config.id)
    info = st.variant_info(path, facts.full_flow)
    method = next(label for label, m in st.METHODS.items() if m == (mode, coupling, pbd_blend))
    log = directory / f"{config.id}-{method}-{dt:.3g}.mcap"
    return {
        "config": config.id, "sweep": config.sweep, "value": config.value, "event": config.event, "scenario": str(path),
        "omega_h": info["omega_h"], "actuators": info["actuators"], "log_rate_hz": log_rate_hz or 1.0 / dt,
        "pressure_ceiling": info["pressure_ceiling"], "node_ceilings": info["node_ceilings"],
        "method": method, "mode": mode, "coupling": coupling, "pbd_blend": pbd_blend, "dt": dt, "duration": duration,
        "reference": False, "truncated": False, "log": str(log), "keep_log": True,
    }


def staged(facts, config, directory, *, coupling, dt, duration, mode="mujoco", pbd_blend=False):
    """Run ``config`` of ``facts``' scene once; returns (classified row, its MCAP log)."""
    point = grid_point(facts, config, directory, coupling=coupling, dt=dt, duration=duration, mode=mode, pbd_blend=pbd_blend)
    return st.classify(st.run_point(point), None, facts, st.QUICK_GRID.tolerance), read_log(point["log"])


def assert_stable(row, log, facts):
    """No NaN, pressures within their physical bounds, energy bounded by the pump work."""
    assert row["status"] == "complete", row["message"]
    assert row["class"] != st.CLASS_DIVERGED, row["message"]
    low = facts.cavitation_pressure if facts.cavitation_pressure is not None else -math.inf
    for node, peak in row["peak_pressure"].items():
        assert np.isfinite(peak) and peak <= row["node_ceilings"][node] * st.PRESSURE_BOUND_MARGIN, (node, peak)
        assert row["min_pressure"][node] >= low - 1.0, (node, row["min_pressure"][node])
    energy = log.topic("/hydroplant/energy")
    total = energy["kinetic_j"] + energy["potential_j"] + energy["oil_j"]
    assert np.all(np.isfinite(total))
    swing = ENERGY_SWING + row["omega_h"] * row["dt"]
    allowed = energy["pump_work_j"] + swing * (abs(total[0]) + energy["pump_work_j"]) + ENERGY_SLACK
    assert np.all(total - total[0] <= allowed), f"energy grew beyond the pump work: {np.max(total - total[0] - allowed):.4g} J over"


def assert_diverged(row):
    assert row["class"] == st.CLASS_DIVERGED, f"explicit baseline did not diverge: {row['status']} {row['message']}"
    assert row["fail_component"], row
    assert row["fail_time"] is not None and row["fail_time"] > 0.0, row


# (id, scene, config, dt of the extreme, implicit duration, explicit duration)
SEED_EXTREMES = [
    ("dt-1e-5 (beta 1e10)", st.Config("beta", 1e10, "none", bulk_modulus=1e10), 1e-5, 0.004, 0.04),
    ("bulk-modulus-1e8", st.Config("beta", 1e8, "none", bulk_modulus=1e8), 1e-3, 0.2, 0.2),
    ("bulk-modulus-1e10", st.Config("beta", 1e10, "none", bulk_modulus=1e10), 1e-4, 0.02, 0.02),
    ("mass-1/100", st.Config("mass", 0.01, "none", mass_scale=0.01), 1e-4, 0.01, 0.01),
    ("mass-100", st.Config("mass", 100.0, "none", mass_scale=100.0), 1e-3, 0.3, 0.3),
]
BOOM_EXTREMES = [
    ("dt-1/30 (valve slam)", st.Config("nominal", None, "valve_slam")),
    ("bulk-modulus-1e10", st.Config("beta", 1e10, "valve_slam", bulk_modulus=1e10)),
    ("mass-1/100", st.Config("mass", 0.01, "valve_slam", mass_scale=0.01)),
    ("mass-100", st.Config("mass", 100.0, "valve_slam", mass_scale=100.0)),
    ("dead-volume-1e-7", st.Config("dead", 1e-7, "valve_slam", dead_volume=1e-7)),
    ("pump-start-closed-centre", st.Config("event", "pump_start", "pump_start")),
    ("end-stop-impact", st.Config("event", "end_stop", "end_stop")),
    ("cavitation", st.Config("event", "cavitation", "cavitation")),
]


@pytest.mark.parametrize("name, config, dt, implicit_duration, explicit_duration", SEED_EXTREMES, ids=[e[0] for e in SEED_EXTREMES])
def test_seed_extreme_implicit_stable_explicit_diverges(name, config, dt, implicit_duration, explicit_duration, seed_facts, tmp_path):
    """The undamped seed cylinder: implicit stays stable, forward-Euler co-simulation diverges at any dt."""
    row, log = staged(seed_facts, config, tmp_path, coupling="implicit", dt=dt, duration=implicit_duration)
    assert_stable(row, log, seed_facts)
    row, _ = staged(seed_facts, config, tmp_path, coupling="explicit", dt=dt, duration=explicit_duration)
    assert_diverged(row)
    assert "energy growth" in row["fail_component"]


@pytest.mark.parametrize("name, config, dt, implicit_duration, explicit_duration", SEED_EXTREMES, ids=[e[0] for e in SEED_EXTREMES])
def test_seed_extreme_pbd_stable(name, config, dt, implicit_duration, explicit_duration, seed_facts, tmp_path):
    """PBD mode on the undamped seed at the same extremes: finite, physical, no energy growth (θ = 1, and rosenbrock with
    the θ-rule)."""
    row, log = staged(seed_facts, config, tmp_path, mode="pbd", coupling="implicit", dt=dt, duration=implicit_duration)
    assert_stable(row, log, seed_facts)
    # and with rosenbrock per substep and MuJoCo mode's θ-rule (explicit pressure forces where ω·h < √2)
    row, log = staged(seed_facts, config, tmp_path, mode="pbd", coupling="rosenbrock", dt=dt, duration=implicit_duration,
                      pbd_blend=True)
    assert_stable(row, log, seed_facts)


@pytest.mark.parametrize("name, config", BOOM_EXTREMES, ids=[e[0] for e in BOOM_EXTREMES])
def test_boom_extreme_implicit_stable_explicit_diverges(name, config, boom_facts, tmp_path):
    """The boom at its extremes: implicit stable at the default 1 ms and at 30 Hz; explicit diverges at 30 Hz."""
    duration = boom_facts.duration  # 0.1 s: the events fire at 0.01 s (slams close at 0.05 s)
    for dt in (1e-3, 1.0 / 30.0):
        row, log = staged(boom_facts, config, tmp_path, coupling="implicit", dt=dt, duration=max(duration, 10 * dt))
        assert_stable(row, log, boom_facts)
        if config.event == "cavitation":  # the load really pulls a chamber down to the vapour floor
            assert min(row["min_pressure"].values()) == pytest.approx(boom_facts.cavitation_pressure)
        if config.event == "end_stop" and dt == 1e-3:  # it really hits the stop at full speed
            x = log.topic("/hydroplant/cylinders/boom_cyl")["position_m"]
            assert x.max() == pytest.approx(boom_facts.stroke["boom_cyl"], abs=2e-3)
    row, _ = staged(boom_facts, config, tmp_path, coupling="explicit", dt=1.0 / 30.0, duration=10.0 / 30.0)
    assert_diverged(row)


@pytest.mark.parametrize("name, config", BOOM_EXTREMES, ids=[e[0] for e in BOOM_EXTREMES])
def test_boom_extreme_rosenbrock_stable(name, config, boom_facts, tmp_path):
    """The boom's extremes with the rosenbrock coupling (one Newton step per step unless the step leaves the trust
    region): stable at 1 ms and at 30 Hz, with the implicit coupling's bounds."""
    duration = boom_facts.duration
    for dt in (1e-3, 1.0 / 30.0):
        row, log = staged(boom_facts, config, tmp_path, coupling="rosenbrock", dt=dt, duration=max(duration, 10 * dt))
        assert_stable(row, log, boom_facts)
        if config.event == "cavitation":
            assert min(row["min_pressure"].values()) == pytest.approx(boom_facts.cavitation_pressure)


@pytest.mark.parametrize("name, config", BOOM_EXTREMES, ids=[e[0] for e in BOOM_EXTREMES])
def test_boom_extreme_pbd_stable_at_30hz(name, config, boom_facts, tmp_path):
    """The other recommended method: PBD mode (implicit hydraulics inside XPBD) at 30 Hz stays physical at every extreme."""
    row, log = staged(boom_facts, config, tmp_path, mode="pbd", coupling="implicit", dt=1.0 / 30.0, duration=10.0 / 30.0)
    assert_stable(row, log, boom_facts)


@pytest.mark.parametrize("name, config", BOOM_EXTREMES, ids=[e[0] for e in BOOM_EXTREMES])
def test_boom_extreme_pbd_rosenbrock_blend_stable(name, config, boom_facts, tmp_path):
    """PBD mode's fastest accurate setting (rosenbrock per substep, MuJoCo mode's θ-rule) at every extreme, at 1 ms × 1
    substep (θ mostly 0: explicit pressure forces wherever the oil column is resolved) and at 30 Hz × 20: physical."""
    for dt, substeps in ((1e-3, 1), (1.0 / 30.0, 20)):
        point = grid_point(boom_facts, config, tmp_path, coupling="rosenbrock", dt=dt, duration=max(boom_facts.duration, 10 * dt),
                           mode="pbd", pbd_blend=True)
        point["pbd_substeps"] = substeps
        row = st.classify(st.run_point(point), None, boom_facts, st.QUICK_GRID.tolerance)
        assert_stable(row, read_log(point["log"]), boom_facts)


def test_boom_explicit_stable_at_default_step(boom_facts, tmp_path):
    """The explicit baseline does not fail where the map says it is stable (valve slam at 1 ms, omega_h*dt = 0.04)."""
    row, log = staged(boom_facts, st.Config("nominal", None, "valve_slam"), tmp_path, coupling="explicit", dt=1e-3, duration=0.1)
    assert_stable(row, log, boom_facts)


def test_map_agrees_with_guards(tmp_path, monkeypatch):
    """A small boom map: implicit never diverges; explicit diverges exactly where the guards predict (omega_h*dt > limit)."""
    monkeypatch.setattr(st, "REFERENCE_DT_RANGE", (1e-3, 1e-3))  # references = the 1 ms implicit runs (cheap)
    grid = st.Grid(dts=(1e-3, 1.0 / 30.0), sweeps=("event",), methods=("mujoco:implicit", "mujoco:explicit"),
                   duration_min=0.1, duration_max=0.1, max_steps=200, min_steps=10)
    result = st.stability_map(BOOM, grid=grid, out_dir=tmp_path, workers=1)
    runs = [r for r in result.rows if not r["reference"]]
    assert {r["config"] for r in runs} == {"nominal-valve_slam", "event-pump_start", "event-end_stop", "event-cavitation"}
    for r in runs:
        if r["method"] == "mujoco:implicit":
            assert r["class"] != st.CLASS_DIVERGED, r
        else:
            predicted_stable = expected_stable("explicit", r["omega_h"] * r["dt"], 0.0025)
            assert (r["class"] != st.CLASS_DIVERGED) == predicted_stable, r
    assert all(r["class"] == st.CLASS_ACCURATE for r in runs if r["method"] == "mujoco:implicit" and r["dt"] == 1e-3)
    boundaries = result.boundaries()
    assert all(b["first_diverged_dt"] == pytest.approx(1 / 30) for b in boundaries["mujoco:explicit"].values())
    assert all(b["first_diverged_dt"] is None for b in boundaries["mujoco:implicit"].values())
    for method, png in result.files.items():
        assert png.stat().st_size <= PNG_LIMIT
    assert (tmp_path / "stability.csv").read_text().count("\n") == 1 + len(result.rows)


# ------------------------------------------------------------------------------------ guards
def test_guard_numbers_match_the_seed_analysis():
    """Seed: k = beta*A/x, omega_h = sqrt(k/m) = 1407 rad/s at x = 1 m (models/seed_cylinder/README.md)."""
    report = check_scenario(SEED)
    (row,) = report.rows
    assert row.effective_mass == pytest.approx(1.0)
    assert row.stiffness == pytest.approx(2.2e9 * 9e-4 / 1.0, rel=1e-3)
    assert row.omega_h == pytest.approx(1407, rel=1e-3)
    assert row.omega_h_dt == pytest.approx(1407 / 1200, rel=1e-3)
    assert row.k_dt2_over_m == pytest.approx(row.omega_h_dt**2)
    assert report.warnings == ()  # implicit: always stable


def test_guard_effective_mass_is_the_plants():
    """The guards use the same 1/(J M^-1 J^T) as MujocoPlant.effective_mass; boom: 1573/0.412^2 kg, f_h 7.0 Hz."""
    scene = load_scene(load_scenario(BOOM))
    plant = MujocoPlant(scene)
    report = check(scene, plant.net_state)
    expected = plant.effective_mass(plant.moments().copy())
    assert report.rows[0].effective_mass == pytest.approx(expected[0], rel=1e-9)
    assert report.rows[0].effective_mass == pytest.approx(9286, rel=0.01)
    assert report.rows[0].frequency_hz == pytest.approx(7.0, abs=0.1)


def test_guard_warns_for_explicit_and_says_what_is_stable():
    undamped = check_scenario(SEED, overrides={"coupling": "explicit"})
    (text,) = undamped.warnings
    assert "cyl" in text and "unstable at any dt" in text and "use coupling implicit" in text
    fast = check_scenario(BOOM, overrides={"coupling": "explicit", "dt": 1.0 / 30.0})
    assert any("boom_cyl" in w and "dt <= 0.00229 s" in w for w in fast.warnings)
    assert any("relief 'relief'" in w and "dt < 0.00202 s" in w for w in fast.warnings)
    assert fast.rows[0].explicit_max_dt == pytest.approx(EXPLICIT_OMEGA_DT_LIMIT / fast.rows[0].omega_h)
    assert check_scenario(BOOM, overrides={"coupling": "explicit"}).warnings == ()  # 1 ms: omega_h*dt = 0.044
    assert check_scenario(BOOM, overrides={"dt": 1.0 / 30.0}).warnings == ()  # implicit: stable at any dt


def test_guard_treats_pbd_naive_like_explicit():
    scene = load_scene(load_scenario(SEED))
    plant = MujocoPlant(scene)
    (text,) = check(scene, plant.net_state, mode="pbd-naive").warnings
    assert "mode pbd-naive" in text and "h = dt/20" in text and "use mode pbd" in text
    assert check(scene, plant.net_state, mode="pbd").warnings == ()


def test_guard_skips_incompressible_fidelity():
    report = check_scenario(MODELS / "excavator" / "push.scenario.toml")
    assert report.rows == () and report.warnings == () and "incompressible" in report.notes[0]


# ------------------------------------------------------------------------------------ variants
def _tree_digest(folder):
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            digest.update(str(path).encode() + path.read_bytes())
    return digest.hexdigest()


def test_variants_are_copies_and_do_what_they_say(boom_facts, tmp_path):
    before = _tree_digest(MODELS)
    config = st.Config("mass", 100.0, "valve_slam", mass_scale=100.0, bulk_modulus=1e10, dead_volume=1e-7)
    path = st.write_variant(boom_facts, config, tmp_path / "v")
    assert _tree_digest(MODELS) == before, "models/ must never be touched"
    scenario = load_scenario(path)
    assert scenario.path.parent == tmp_path / "v" and scenario.mjcf.parent == tmp_path / "v" / "model"
    (tmp_path / "v").rename(tmp_path / "moved")  # self-contained: its files named relative to each other
    assert load_scenario(tmp_path / "moved" / path.name).mjcf == tmp_path / "moved" / "model" / "boom-mass.xml"
    (tmp_path / "moved").rename(tmp_path / "v")
    circuit = tomllib.loads(scenario.circuit.read_text())
    assert circuit["fluid"]["bulk_modulus"] == 1e10
    cylinder = next(c for c in circuit["component"] if c["type"] == "cylinder")
    assert cylinder["dead_volume_cap"] == cylinder["dead_volume_rod"] == 1e-7
    assert next(c for c in circuit["component"] if c["type"] == "valve_4_3")["time_constant"] == 0.0
    original = mujoco.MjModel.from_xml_path(str(MODELS / "boom" / "boom.xml"))
    scaled = mujoco.MjModel.from_xml_path(str(scenario.mjcf))
    assert np.allclose(scaled.body_mass, 100.0 * original.body_mass)
    assert np.allclose(scaled.body_inertia, 100.0 * original.body_inertia)
    valve = scenario.inputs["boom_valve"]
    at = st.EVENT_START * boom_facts.duration
    assert valve(at - 2 * st.STEP_EDGE) == 0.0 and valve(at) == 1.0 and valve(st.SLAM_CLOSE * boom_facts.duration) == 0.0


def test_seed_bulk_modulus_variant_keeps_the_compression(seed_facts, tmp_path):
    """P(0) = beta in the seed: a 1e8 Pa variant starts at 1e8 Pa (same oil content, same physics scaled)."""
    path = st.write_variant(seed_facts, st.Config("beta", 1e8, "none", bulk_modulus=1e8), tmp_path)
    assert load_scenario(path).pressures["cyl_cap"] == pytest.approx(1e8)


# ------------------------------------------------------------------------------------ CLI
@pytest.fixture
def stability_cli(monkeypatch):
    if "sim.tools.stability" not in cli.TOOL_MODULES:
        monkeypatch.setattr(cli, "TOOL_MODULES", (*cli.TOOL_MODULES, "sim.tools.stability"))
    return cli.main


def test_cli_stability_quick_map(stability_cli, tmp_path, capsys):
    out = tmp_path / "map"
    code = stability_cli(["stability", str(SEED), "--quick", "--dt", "1e-4,1/30", "--sweeps", "beta", "--workers", "1",
                          "--out", str(out)])
    assert code == 4  # the map is written, and runs diverged
    captured = capsys.readouterr()
    printed = captured.out
    assert "mujoco:explicit" in printed and "smallest diverged omega_h*dt" in printed
    assert "runs diverged or failed" in captured.err and "\r" not in captured.err
    for name in ("stability.csv", "summary.txt", "stability-seed_cylinder-mujoco-implicit.png", "stability-seed_cylinder-mujoco-explicit.png"):
        assert (out / name).is_file(), name
    assert (out / "stability-seed_cylinder-mujoco-explicit.png").stat().st_size <= PNG_LIMIT
    with open(out / "stability.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["reference"] == "False"]
    assert {r["config"] for r in rows} == {"nominal-none", "beta-1e+08-none", "beta-1e+10-none"}
    explicit = {(r["config"], float(r["dt"])): r for r in rows if r["method"] == "mujoco:explicit"}
    assert all(r["class"] == st.CLASS_DIVERGED for (config, dt), r in explicit.items() if dt > 0.03 or config != "beta-1e+08-none")
    assert all(r["fail_component"] and float(r["fail_time"]) > 0 for r in explicit.values() if r["class"] == st.CLASS_DIVERGED)
    assert not any(r["class"] == st.CLASS_DIVERGED for r in rows if r["method"] == "mujoco:implicit")
    # a second call reads every run from the cache; its --json document counts the diverged runs of the CSV
    import json

    import jsonschema

    from sim.jsonout import schema

    assert stability_cli(["stability", str(SEED), "--quick", "--dt", "1e-4,1/30", "--sweeps", "beta", "--workers", "1",
                          "--out", str(out), "--json"]) == 4
    document = json.loads(capsys.readouterr().out)
    jsonschema.validate(document, schema("stability"))
    assert document["status"] == "partial" and document["exit_code"] == 4
    with open(out / "stability.csv", newline="") as f:
        every = list(csv.DictReader(f))  # references included
    assert document["diverged"] + document["errors"] == sum(r["class"] == st.CLASS_DIVERGED for r in every) > 0
    assert len(document["runs"]) == len(every)
    assert [r["error"] for r in document["runs"]] == [r["error"] for r in every]  # "" for every run that was made
    assert document["methods"]["mujoco:explicit"]["counts"][st.CLASS_DIVERGED] == sum(
        r["class"] == st.CLASS_DIVERGED for r in explicit.values())
    assert {"mujoco:implicit", "mujoco:explicit"} <= set(document["figures"])


def test_cli_stability_check_prints_guards(stability_cli, capsys):
    assert stability_cli(["stability", str(BOOM), "--check"]) == 0
    out = capsys.readouterr().out
    assert "boom_cyl" in out and "w_h*dt" in out


@pytest.mark.parametrize("argv, expected", [
    (["--dt", "0,1e-3"], "positive finite"),
    (["--dt", "2"], "--dt"),
    (["--methods", "rk4"], "choose from"),
    (["--tolerance", "nan"], "positive finite"),
])
def test_cli_stability_bad_options_exit_2(stability_cli, argv, expected, capsys):
    with pytest.raises(SystemExit) as info:
        code = stability_cli(["stability", str(SEED), *argv])
        raise SystemExit(code)
    assert info.value.code == 2
    assert expected in capsys.readouterr().err


def test_cli_stability_bad_scenarios_exit_2(stability_cli, tmp_path, capsys):
    assert stability_cli(["stability", str(tmp_path / "missing.scenario.toml")]) == 2
    assert "scenario file not found" in capsys.readouterr().err
    push = MODELS / "excavator" / "push.scenario.toml"
    assert stability_cli(["stability", str(push), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(push) in err and "run.fidelity" in err and "incompressible" in err


def test_run_prints_and_logs_guard_warnings(tmp_path, capsys):
    """``hydroplant run`` warns (not fails) when the chosen method is known to be unstable, and logs the warning."""
    out = tmp_path / "seed.mcap"
    assert cli.main(["run", str(SEED), "--coupling", "explicit", "--duration", "1e-3", "--out", str(out)]) in (0, 3)
    assert "warning: cyl: omega_h = 1407 rad/s" in capsys.readouterr().err
    events = read_log(out).topic("/hydroplant/events").messages
    assert any(m["level"] == 3 and "use coupling implicit" in m["message"] for m in events)


# ------------------------------------------------------------------------------------ per-step extremes
def test_map_classifies_on_per_step_extremes_not_logged_samples(boom_facts, tmp_path):
    """Block stepping logs every 500th step here; the pressure extremes the map checks still cover every step.

    Valve slam at dt = 1e-4 s logged at 20 Hz: the rod chamber's minimum (1.0e5 Pa) falls between
    samples (logged minimum 4.3e5 Pa).  ``run_point`` must report the per-step extremes, equal to the
    per-step MujocoPlant run's, and a pressure floor between the two minima must classify the run as
    diverged at that node.
    """
    import dataclasses

    from sim.run.runner import run

    point = grid_point(boom_facts, st.Config("nominal", None, "valve_slam"), tmp_path, coupling="implicit", dt=1e-4,
                       duration=0.1, log_rate_hz=20.0)
    result = st.run_point(point)
    assert result["status"] == "complete" and result["extremes_every_step"] is True
    overrides = {"mode": "mujoco", "coupling": "implicit", "dt": 1e-4, "duration": 0.1, "log_rate_hz": 20.0}
    per_step = run(point["scenario"], out=tmp_path / "per-step.mcap", overrides=overrides, fast=False)
    for node, peak in per_step.peak_pressure.items():
        assert result["peak_pressure"][node] == pytest.approx(peak, rel=1e-9)
        assert result["min_pressure"][node] == pytest.approx(per_step.min_pressure[node], rel=1e-9)
    logged = [p for p in result["samples"]["p"]["boom_cyl_rod"] if p is not None]
    true_min = result["min_pressure"]["boom_cyl_rod"]
    assert true_min < 0.5 * min(logged), "the logged samples should miss the minimum (else the test shows nothing)"
    floor = math.sqrt(true_min * min(logged))  # between the per-step and the logged minimum
    # the cap chamber sits at the vapour floor all along: classify the rod chamber alone
    only_rod = dict(result, peak_pressure={"boom_cyl_rod": result["peak_pressure"]["boom_cyl_rod"]},
                    min_pressure={"boom_cyl_rod": true_min})
    row = st.classify(only_rod, None, dataclasses.replace(boom_facts, cavitation_pressure=floor), st.QUICK_GRID.tolerance)
    assert row["class"] == st.CLASS_DIVERGED and row["fail_component"] == "node boom_cyl_rod", row["message"]


def test_run_point_repeats_a_run_without_per_step_extremes(boom_facts, tmp_path, monkeypatch):
    """A run whose extremes cover only the logged samples is repeated with ``fast=False`` (per-step checks)."""
    import sim.run.runner

    real_run, calls = sim.run.runner.run, []

    def sampled_only(*args, fast=True, **kwargs):  # a plant without node_pressure_max/min
        calls.append(fast)
        result = real_run(*args, fast=fast, **kwargs)
        if fast:
            result.extremes_every_step = False
            result.min_pressure = {k: v + 1e5 for k, v in result.min_pressure.items()}  # what the samples would say
        return result

    monkeypatch.setattr(sim.run.runner, "run", sampled_only)
    point = grid_point(boom_facts, st.Config("event", "cavitation", "cavitation"), tmp_path, coupling="implicit", dt=1e-3,
                       duration=0.1, log_rate_hz=100.0)
    result = st.run_point(point)
    assert calls == [True, False]
    assert result["extremes_every_step"] is True
    assert min(result["min_pressure"].values()) == pytest.approx(boom_facts.cavitation_pressure)


# ------------------------------------------------------------------------------------ the committed maps
def _map_cells(scene):
    """{(method, config, dt): row} of the committed map docs/stability/<scene>.csv (runs only; method names as
    :func:`sim.methods.parse_method` writes them, whichever spelling the file has)."""
    from conftest import ROOT
    from sim.methods import parse_method

    with open(ROOT / "docs" / "stability" / f"{scene}.csv", newline="") as f:
        return {(parse_method(r["method"], warn=None).name, r["config"], round(float(r["dt"]), 12)): r
                for r in csv.DictReader(f) if r["reference"] == "False"}


@pytest.mark.parametrize("scene", ["seed_cylinder", "boom", "excavator"])
def test_maps_show_the_default_coupling_in_the_class_of_implicit_in_every_cell(scene):
    """The default coupling (sim.methods.DEFAULT_COUPLING) is the default because the committed maps give it, in both
    modes, the class (stable-accurate, stable-inaccurate, diverged) of the implicit coupling in every cell: no extreme
    that implicit survives is lost by the switch (the boom's 1/30 s column is rerun below)."""
    from sim.methods import DEFAULT_COUPLING

    cells = _map_cells(scene)
    for mode in ("mujoco", "pbd"):
        implicit = {key[1:]: row["class"] for key, row in cells.items() if key[0] == f"{mode}:implicit"}
        default = {key[1:]: row["class"] for key, row in cells.items() if key[0] == f"{mode}:{DEFAULT_COUPLING}"}
        assert len(implicit) > 40 and default.keys() == implicit.keys(), (mode, len(implicit), len(default))
        differ = {cell: (implicit[cell], default[cell]) for cell in implicit if implicit[cell] != default[cell]}
        assert not differ, (mode, differ)


def test_boom_map_cells_at_30hz_are_reproduced(tmp_path, monkeypatch):
    """docs/stability/boom.csv says which method diverges at each boom extreme at dt = 1/30 s; a fresh run agrees.

    The same grid as the map (configuration duration 0.3 s, runs lengthened to 20 steps; references
    at 1 ms instead of 0.1 ms, which only set the pressure bound where their peak exceeds the
    relief ceiling): the explicit baseline fails in exactly the cells the map marks diverged, the
    implicit coupling and PBD stay stable where it says so.
    """
    monkeypatch.setattr(st, "REFERENCE_DT_RANGE", (1e-3, 1e-3))
    cells = _map_cells("boom")
    methods = ("mujoco:implicit", "mujoco:rosenbrock", "mujoco:explicit", "pbd:implicit", "pbd:rosenbrock")
    grid = replace(st.DEFAULT_GRID, dts=(1.0 / 30.0,), methods=methods)
    result = st.stability_map(BOOM, grid=grid, out_dir=tmp_path, workers=1, write=False)
    runs = [r for r in result.rows if not r["reference"]]
    assert len(runs) == len(methods) * (len(BOOM_EXTREMES) + 2)  # + the beta 1e8 and 1e9 configurations
    for r in runs:
        committed = cells[(r["method"], r["config"], round(r["dt"], 12))]
        assert (r["class"] == st.CLASS_DIVERGED) == (committed["class"] == st.CLASS_DIVERGED), (r["method"], r["config"], r["message"])
    explicit = [r for r in runs if r["method"] == "mujoco:explicit"]
    assert sum(r["class"] == st.CLASS_DIVERGED for r in explicit) >= len(explicit) - 1  # all but beta 1e8 (omega_h*dt 0.42)


def test_mass_scaling_ignores_static_bodies_whose_mass_is_inferred(tmp_path):
    """A floor slab welded to the world, its mass inferred from its geom's default density (100 t): its mass moves
    nothing, so the mass sweep scales the moving bodies and is not refused over the slab."""
    from sim.tools.stability import scale_mjcf_masses

    source = tmp_path / "boom.xml"
    text = (MODELS / "boom" / "boom.xml").read_text()
    source.write_text(text.replace("<worldbody>", '<worldbody>\n    <body name="slab" pos="0 0 -1"><geom type="box" '
                                   'size="5 5 0.5"/></body>', 1))
    target = tmp_path / "scaled.xml"
    scale_mjcf_masses(source, target, 0.01)
    before, after = (mujoco.MjModel.from_xml_path(str(p)) for p in (source, target))
    moving = np.asarray(before.body_weldid) != 0
    assert float(before.body_mass[~moving].sum()) > 1e4  # the slab is there, with its inferred mass
    assert after.body_mass[moving] == pytest.approx(0.01 * before.body_mass[moving])
