"""Bad input: one clear message naming the file, the field and the allowed range, exit code 2, never a traceback.

Two layers:

* hand-written cases through ``sim.cli.main(["run", ...])`` for every kind of
  error in a scenario, a circuit or the MJCF binding;
* property-based fuzzing (hypothesis) of circuit and scenario documents (random
  mutations of the shipped models, written as TOML and read back), of raw file
  bytes, of MJCF attributes and of the CLI arguments: only ``CircuitError``
  (``ScenarioError`` is one) may come out, the CLI returns 0/2/3 or exits 2.

The inputs that gave tracebacks before commit 2d99381 (found by these fuzzers)
are kept as regression tests at the end.
"""

import copy
import math
import re
import shutil
import tomllib
import xml.etree.ElementTree as ET

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from conftest import MODELS
from hydraulics.circuit import load_circuit, parse_circuit
from hydraulics.components import CircuitError
from hydraulics.network import NetworkModel
from sim import cli
from sim.io.scenario import load_scenario
from sim.plants.mujoco import MujocoPlant
from sim.run.guards import check_plant
from sim.io.scene import load_scene
from sim.tools.stability import dump_toml

FUZZ = settings(deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow], database=None)
TRACEBACK = "Traceback (most recent call last)"


# ------------------------------------------------------------------------------- helpers
def scene_dir(tmp_path, scene="seed_cylinder"):
    target = tmp_path / scene
    if not target.exists():
        shutil.copytree(MODELS / scene, target)
    return target


def edit(path, old, new):
    text = path.read_text()
    assert text.count(old) == 1, (path, old)
    path.write_text(text.replace(old, new))


def run_cli(argv, capsys):
    """(exit code, stdout, stderr) of ``hydroplant ARGV``; SystemExit is turned into its code."""
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def run_bad(scenario, capsys, *extra):
    """Run a scenario one step through the CLI and return stderr; it must fail with exit 2 and one clean line."""
    code, out, err = run_cli(["run", scenario, "--duration", "1e-3", "--dt", "1e-3", "--no-progress",
                              "--out", scenario.parent / "out.mcap", *extra], capsys)
    assert TRACEBACK not in out + err
    assert code == 2, (code, out, err)
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) >= 1 and lines[0].startswith("hydroplant: error: ")
    return err


SCENARIO_OF = {"boom": "hold.scenario.toml", "seed_cylinder": "closed.scenario.toml"}


def one_edit_error(tmp_path, capsys, scene, file, old, new):
    """stderr of a one-step run of the scene's scenario after replacing ``old`` by ``new`` in ``file``."""
    d = scene_dir(tmp_path, scene)
    edit(d / file, old, new)
    return run_bad(d / SCENARIO_OF[scene], capsys)


# ------------------------------------------------------------------------------- hand-written cases
def test_missing_scenario_file(tmp_path, capsys):
    err = run_bad(tmp_path / "nope.scenario.toml", capsys)
    assert "nope.scenario.toml" in err and "scenario file not found" in err


@pytest.mark.parametrize("field, name", [("circuit", "seed_cylinder.circuit.toml"), ("mjcf", "seed_cylinder.xml")])
def test_missing_referenced_file(tmp_path, capsys, field, name):
    d = scene_dir(tmp_path)
    (d / name).unlink()
    err = run_bad(d / "closed.scenario.toml", capsys)
    assert "closed.scenario.toml" in err and f"field 'scene.{field}'" in err and name in err and "not found" in err


def test_unknown_component_type(tmp_path, capsys):
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "seed_cylinder.circuit.toml", 'type = "cylinder"', 'type = "cylindre"')
    assert "seed_cylinder.circuit.toml" in err and "component 'cyl'" in err and "field 'type'" in err
    assert "'cylindre'" in err and "'cylinder'" in err  # names the allowed types


@pytest.mark.parametrize("old, new, field, allowed", [
    ("bore = 0.033851375012865375", 'bore = "big"', "bore", "(0, 1] m"),
    ("stroke = 10.0 ", "stroke = true ", "stroke", "[0.01, 20] m"),
    ("dead_volume_cap = 0.0 ", "dead_volume_cap = [0.0] ", "dead_volume_cap", "[0, 1] m^3"),
])
def test_wrong_type_in_circuit(tmp_path, capsys, old, new, field, allowed):
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "seed_cylinder.circuit.toml", old, new)
    assert "seed_cylinder.circuit.toml" in err and f"field '{field}'" in err and allowed in err


@pytest.mark.parametrize("old, new, field, allowed", [
    ('mode = "mujoco"', "mode = 3", "run.mode", "['mujoco', 'pbd', 'pbd-naive']"),
    ("dt = 0.0008333333333333334", 'dt = "fast"', "dt", "expected a number"),
    ("equilibrium = false", 'equilibrium = "no"', "initial.equilibrium", "true or false"),
    ("rate_hz = 1200", "rate_hz = [1200]", "rate_hz", "expected a number"),
    ("rate_hz = 1200", "rate_hz = 1200\ntf_rate_hz = 0", "[log]: field 'tf_rate_hz'", "[1e-06, 1000000000.0]"),
    ("rate_hz = 1200", 'rate_hz = 1200\ntf_rate_hz = "60"', "[log]: field 'tf_rate_hz'", "expected a number"),
])
def test_wrong_type_in_scenario(tmp_path, capsys, old, new, field, allowed):
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "closed.scenario.toml", old, new)
    assert "closed.scenario.toml" in err and field in err and allowed in err


@pytest.mark.parametrize("value", ["false", "true"])
def test_compiled_key_is_refused_with_what_to_do(tmp_path, capsys, value):
    """``[run] compiled`` selects nothing (the kernels always run compiled): one line naming the file and the field
    and pointing to NUMBA_DISABLE_JIT=1, exit 2; the ``--pure`` flag does not exist."""
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "closed.scenario.toml", 'mode = "mujoco"',
                         f'mode = "mujoco"\ncompiled = {value}')
    assert len(err.strip().splitlines()) == 1
    assert "closed.scenario.toml" in err and "run.compiled" in err and "NUMBA_DISABLE_JIT=1" in err
    d = scene_dir(tmp_path, "seed_cylinder")
    edit(d / "closed.scenario.toml", f"compiled = {value}\n", "")
    err = run_bad(d / "closed.scenario.toml", capsys, "--pure")
    assert "--pure" in err


@pytest.mark.parametrize("old, new, field, allowed", [
    ("bore = 0.033851375012865375", "bore = 0.0", "bore", "(0, 1] m"),
    ("bore = 0.033851375012865375", "bore = -0.05", "bore", "(0, 1] m"),
    ("stroke = 10.0 ", "stroke = -1.0 ", "stroke", "[0.01, 20] m"),
    ("dead_volume_cap = 0.0 ", "dead_volume_cap = -1e-6 ", "dead_volume_cap", "[0, 1] m^3"),
    ("bulk_modulus = 2.2e9", "bulk_modulus = 0.0", "bulk_modulus", "[1e+07, 1e+11] Pa"),
    ("bulk_modulus = 2.2e9", "bulk_modulus = 1.0", "bulk_modulus", "[1e+07, 1e+11] Pa"),
    ("density = 1000.0", "density = -870.0", "density", "[500, 2000] kg/m^3"),
    ("density = 1000.0", "density = 0.87", "density", "[500, 2000] kg/m^3"),
])
def test_zero_or_negative_geometry(tmp_path, capsys, old, new, field, allowed):
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "seed_cylinder.circuit.toml", old, new)
    assert "seed_cylinder.circuit.toml" in err and f"field '{field}'" in err and allowed in err


@pytest.mark.parametrize("volume", ["0.0", "-3e-4"])
def test_zero_or_negative_volume(tmp_path, capsys, volume):
    err = one_edit_error(tmp_path, capsys, "boom", "boom.circuit.toml", "volume = 3.0e-4 ", f"volume = {volume} ")
    assert "boom.circuit.toml" in err and "component 'supply_volume'" in err and "field 'volume'" in err and "(0, 10] m^3" in err


@pytest.mark.parametrize("mass", ["0", "-1"])
def test_zero_or_negative_mass_in_mjcf(tmp_path, capsys, mass):
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "seed_cylinder.xml", 'mass="1.0"', f'mass="{mass}"')
    assert "seed_cylinder.xml" in err and "mass" in err and "'piston'" in err


@pytest.mark.parametrize("mass", ["1e-12", "1e-6"])
def test_a_featherweight_moving_body_is_refused(tmp_path, capsys, mass):
    """A body a joint moves, lighter than a gram with what it carries: one line naming it and the range, not a
    MuJoCo reset deep in a step."""
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "seed_cylinder.xml", 'mass="1.0"', f'mass="{mass}"')
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "seed_cylinder.xml" in err and "body 'piston'" in err and "mass" in err, err
    assert "[0.001, inf) kg" in err


def test_a_zero_length_cylinder_is_refused(tmp_path, capsys):
    """A stroke far below the binding's and the end stops' tolerances (here 0.5 mm, with an MJCF tendon range of the
    same width, so the MJCF and the circuit agree): one line naming the circuit file, the field and its range."""
    d = scene_dir(tmp_path, "boom")
    edit(d / "boom.xml", 'range="0.66 1.06"', 'range="0.8600 0.8605"')
    err = one_edit_error(tmp_path, capsys, "boom", "boom.circuit.toml", "stroke = 0.40                 # m  (= MJCF",
                         "stroke = 0.0005               # m  (= MJCF")
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "boom.circuit.toml" in err and "field 'stroke'" in err and "[0.01, 20] m" in err, err


@pytest.mark.parametrize("where, old, new, field", [
    ("seed_cylinder.circuit.toml", "bore = 0.033851375012865375", "bore = nan", "bore"),
    ("seed_cylinder.circuit.toml", "stroke = 10.0 ", "stroke = inf ", "stroke"),
    ("seed_cylinder.circuit.toml", "bulk_modulus = 2.2e9", "bulk_modulus = -inf", "bulk_modulus"),
    ("closed.scenario.toml", "duration = 0.1 ", "duration = inf ", "duration"),
    ("closed.scenario.toml", "qpos = { x = 1.0 }", "qpos = { x = nan }", "'x'"),
    ("closed.scenario.toml", "pressures = { cyl_cap = 2.2e9 }", "pressures = { cyl_cap = inf }", "'cyl_cap'"),
])
def test_nan_or_inf_in_inputs(tmp_path, capsys, where, old, new, field):
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", where, old, new)
    assert where in err and field in err and re.search(r"nan|inf", err)


@pytest.mark.parametrize("schedule", [
    "{ t = [0.0, nan], value = [0.0, 1.0] }",
    "{ t = [0.0, 1.0], value = [0.0, inf] }",
    "-inf",
])
def test_nan_or_inf_in_schedules(tmp_path, capsys, schedule):
    err = one_edit_error(tmp_path, capsys, "boom", "hold.scenario.toml", "boom_valve = { t = [0.0], value = [0.0] }", f"boom_valve = {schedule}")
    assert "hold.scenario.toml" in err and "field 'inputs.boom_valve'" in err and "finite" in err


def test_nan_in_inputs_csv(tmp_path, capsys):
    d = scene_dir(tmp_path, "boom")
    (d / "inputs.csv").write_text("t,boom_valve\n0.0,0.0\n1.0,nan\n")
    edit(d / "hold.scenario.toml", "[scene]", 'inputs_csv = "inputs.csv"\n[scene]')
    err = run_bad(d / "hold.scenario.toml", capsys)
    assert "inputs.csv" in err and "boom_valve" in err and "finite" in err


def test_ragged_inputs_csv(tmp_path, capsys):
    d = scene_dir(tmp_path, "boom")
    (d / "inputs.csv").write_text("t,boom_valve\n0,0\n1\n")
    edit(d / "hold.scenario.toml", "[scene]", 'inputs_csv = "inputs.csv"\n[scene]')
    assert "inputs.csv" in run_bad(d / "hold.scenario.toml", capsys)


@pytest.mark.parametrize("scene, file, old, new, expected", [
    pytest.param("boom", "hold.scenario.toml", "boom_valve = {", "boom_valv = {",
                 ["field 'inputs.boom_valv'", "boom.circuit.toml", "'boom_valve'"], id="schedule_for_unknown_input"),
    pytest.param("boom", "boom.circuit.toml", 'name = "boom_cyl"', 'name = "arm_cyl"',
                 ["boom.circuit.toml", "['arm_cyl']", "boom.xml", "['boom_cyl']"], id="cylinder_name_not_in_mjcf"),
    pytest.param("boom", "boom.xml", '<general name="boom_cyl" tendon="boom_cyl"', '<general name="boom_cyl" joint="boom_hinge"',
                 ["boom.xml", "actuator 'boom_cyl'", "<spatial> tendon"], id="cylinder_bound_to_a_joint_actuator"),
    pytest.param("boom", "boom.circuit.toml", "stroke = 0.40 ", "stroke = 0.50 ",
                 ["boom.circuit.toml", "field 'stroke'", "boom.xml", "0.001 m"], id="stroke_disagrees_with_tendon_range"),
    pytest.param("boom", "boom.circuit.toml", 'ports = { cap = "boom_cyl_cap", rod = "boom_cyl_rod" }',
                 'ports = { cap = "boom_cyl_cap", rod = "boom_cyl_cap" }',
                 ["component 'boom_cyl'", "field 'ports'", "'cap' and 'rod'", "'boom_cyl_cap'"], id="port_connected_twice"),
    pytest.param("boom", "boom.circuit.toml", 'ports = { cap = "boom_cyl_cap", rod = "boom_cyl_rod" }',
                 'ports = { cap = "boom_cyl_cap", cap = "boom_cyl_rod" }',
                 ["boom.circuit.toml", "not valid TOML", "cap"], id="same_port_given_twice"),
    pytest.param("boom", "boom.circuit.toml", "bore = 0.063 ", "bore = 63.0 ",
                 ["component 'boom_cyl'", "field 'bore'", "(0, 1] m", "not millimetres"], id="unit_suspicious_bore_in_millimetres"),
    # 1200 (a rate in Hz typed where the step in s belongs) is outside (0, 1] s
    pytest.param("seed_cylinder", "closed.scenario.toml", "dt = 0.0008333333333333334", "dt = 1200",
                 ["closed.scenario.toml", "field 'dt'", "[1e-09, 1.0]"], id="unit_suspicious_step_rate_typed_as_dt"),
])
def test_mismatched_input(tmp_path, capsys, scene, file, old, new, expected):
    """A scenario, circuit and MJCF that disagree (or a value in the wrong unit): one message naming all of ``expected``."""
    err = one_edit_error(tmp_path, capsys, scene, file, old, new)
    for part in expected:
        assert part in err, (part, err)


# ------------------------------------------------------------------------------- loads, but NaN at t = 0 (refused at load)
STROKE_OUT = ["closed.scenario.toml", "field 'initial.qpos'", "cylinder 'cyl'", "outside its stroke [0, 10] m", "seed_cylinder.xml"]


@pytest.mark.parametrize("scene, file, old, new, expected", [
    pytest.param("boom", "hold.scenario.toml", "qpos = { boom_hinge = 0.2003 }", "qpos = { boom_hinge = 3.0 }",
                 ["hold.scenario.toml", "field 'initial.qpos.boom_hinge'", "[-0.2448, 0.771] rad"], id="initial_joint_outside_its_range"),
    # the seed's slide joint is unlimited: a start beyond the stroke would give a chamber of negative length
    pytest.param("seed_cylinder", "closed.scenario.toml", "qpos = { x = 1.0 }", "qpos = { x = 12.0 }",
                 STROKE_OUT, id="start_pose_outside_the_stroke-12.0"),
    pytest.param("seed_cylinder", "closed.scenario.toml", "qpos = { x = 1.0 }", "qpos = { x = 10.5 }",
                 STROKE_OUT, id="start_pose_outside_the_stroke-10.5"),
    # x = 0 with no cap dead volume: V_cap = 0 and the pressure m/V is NaN
    pytest.param("seed_cylinder", "closed.scenario.toml", "qpos = { x = 1.0 }", "qpos = { x = 0.0 }",
                 ["cylinder 'cyl'", "cap chamber volume of 0 m^3", "> 0 m^3", "'dead_volume_cap'"], id="start_pose_with_an_empty_chamber"),
    pytest.param("seed_cylinder", "closed.scenario.toml", "pressures = { cyl_cap = 2.2e9 }", "pressures = { cyl_cap = -1e5 }",
                 ["closed.scenario.toml", "[initial.pressures]", "'cyl_cap'", "[0.0, 10000000000.0]"], id="negative_absolute_initial_pressure"),
])
def test_start_state_refused_at_load(tmp_path, capsys, scene, file, old, new, expected):
    """A start state that would give NaN at t = 0 is refused at load with one message naming all of ``expected``."""
    err = one_edit_error(tmp_path, capsys, scene, file, old, new)
    for part in expected:
        assert part in err, (part, err)


@pytest.mark.parametrize("old, new, field, allowed", [
    ("bulk_modulus = 1.5e9", "bulk_modulus = 1.0", "bulk_modulus", "[1e+07, 1e+11] Pa"),
    ("bulk_modulus = 1.5e9", "bulk_modulus = 1e13", "bulk_modulus", "[1e+07, 1e+11] Pa"),
    ("wall_bulk_modulus = 1.0e9", "wall_bulk_modulus = 1.0", "wall_bulk_modulus", "[1e+07, 1e+12] Pa"),
])
def test_physically_absurd_fluid(tmp_path, capsys, old, new, field, allowed):
    d = scene_dir(tmp_path, "boom")
    text = (d / "boom.circuit.toml").read_text()
    (d / "boom.circuit.toml").write_text(text.replace(old, new, 1))
    err = run_bad(d / "hold.scenario.toml", capsys)
    assert "boom.circuit.toml" in err and f"field '{field}'" in err and allowed in err


def test_every_numeric_circuit_field_has_a_range():
    from dataclasses import fields as dataclass_fields

    from hydraulics.circuit import FLUID_FIELDS
    from hydraulics.components import COMPONENT_TYPES

    metas = [(f"{kind}.{f.name}", f.metadata) for kind, cls in COMPONENT_TYPES.items() for f in dataclass_fields(cls)]
    metas += [(f"fluid.{name}", meta) for name, meta in FLUID_FIELDS.items()]
    for name, meta in metas:
        assert meta.get("unit") is not None, name
        if meta.get("tables"):  # knot tables: their travel and area ranges are checked in metering.check_table
            continue
        if not meta["choices"]:
            assert meta["low"] is not None and meta["high"] is not None, f"{name} has no allowed range"


# ------------------------------------------------------------------------------- per-actuator fidelity
@pytest.mark.parametrize("table, expected", [
    ('[fidelity]\nboom_cyl = "lines"\narm_cyl = "lines"\n', ["field 'fidelity.arm_cyl'", "no cylinder or motor called 'arm_cyl'", "'boom_cyl'"]),
    ('[fidelity]\nboom_cyl = "exact"\n', ["field 'fidelity.boom_cyl'", "'exact'", "'incompressible', 'compressible', 'lines'"]),
    ('[fidelity]\ndefault = "lines"\n', ["field 'fidelity.default'", "contradicts field 'run.fidelity'"]),
    ('fidelity = "lines"\n', ["[fidelity] must be a table"]),
])
def test_bad_fidelity_table(tmp_path, capsys, table, expected):
    d = scene_dir(tmp_path, "boom")
    edit(d / "hold.scenario.toml", "[run]", "[run]\nfidelity = \"compressible\"")
    text = (d / "hold.scenario.toml").read_text()
    (d / "hold.scenario.toml").write_text(table + text if not table.startswith("[") else text + "\n" + table)
    err = run_bad(d / "hold.scenario.toml", capsys)
    assert "hold.scenario.toml" in err
    for part in expected:
        assert part in err, (part, err)


def test_rigid_actuator_joined_to_a_pressure_node_is_refused(tmp_path, capsys):
    """'incompressible' for one cylinder whose chamber net an orifice joins to the supply: exit 2, naming the
    scenario's [fidelity] table, the component and the remedy."""
    d = scene_dir(tmp_path, "excavator")
    circuit = d / "excavator.circuit.toml"
    circuit.write_text(circuit.read_text() + '\n[[component]]\nname = "bleed"\ntype = "orifice"\narea = 1e-6\n'
                       'ports = { a = "supply", b = "boom_cyl_cap" }\n')
    text = (d / "dig.scenario.toml").read_text()
    (d / "dig.scenario.toml").write_text(text + '\n[fidelity]\nboom_cyl = "incompressible"\n')
    err = run_bad(d / "dig.scenario.toml", capsys)
    assert "dig.scenario.toml" in err and "[fidelity]" in err and "component 'bleed'" in err
    assert "give 'boom_cyl' the fidelity 'compressible' or 'lines'" in err


@pytest.mark.parametrize("argv, expected", [
    (["--dt=-1e-3"], "must be a positive finite number"),
    (["--dt", "nan"], "must be a positive finite number"),
    (["--duration", "inf"], "must be a positive finite number"),
    (["--substeps", "0"], "must be >= 1"),
    (["--mode", "rk4"], "invalid choice"),
])
def test_bad_cli_arguments(tmp_path, capsys, argv, expected):
    d = scene_dir(tmp_path)
    code, out, err = run_cli(["run", d / "closed.scenario.toml", *argv], capsys)
    assert code == 2 and expected in err and TRACEBACK not in err


def test_log_commands_on_missing_files(tmp_path, capsys):
    for argv in (["log", "info", tmp_path / "x.mcap"], ["log", "recover", tmp_path / "x.mcap.partial"]):
        code, out, err = run_cli(argv, capsys)
        assert code == 2 and "not found" in err and TRACEBACK not in err


# ------------------------------------------------------------------------------- fuzzing helpers
def must_be_clean(call, *args, **kwargs):
    """Call; success or a CircuitError (a user error, with a message) is fine, anything else fails the test."""
    try:
        result = call(*args, **kwargs)
        event(f"{getattr(call, '__name__', 'call')}: ok")
        return result
    except CircuitError as exc:
        event(f"{getattr(call, '__name__', 'call')}: {type(exc).__name__}")
        assert str(exc).strip(), "an empty error message"
        return exc


# ------------------------------------------------------------------------------- fuzzing strategies
def _safe_text(max_size=10):
    return st.text(st.characters(blacklist_categories=("Cs",)), max_size=max_size)


SPECIAL = st.sampled_from([0, -1, 1, 0.0, -0.0, 1e-300, 1e300, 80, 0.08, 2**63 - 1, -(2**63),
                           math.nan, math.inf, -math.inf, "", "tank", "closed", "cylinder", "valve_4_3", "cyl", "boom_cyl"])
SCALARS = st.one_of(st.integers(-(2**63), 2**63 - 1), st.floats(allow_nan=True, allow_infinity=True), st.booleans(), _safe_text(), SPECIAL)
VALUES = st.recursive(SCALARS, lambda children: st.lists(children, max_size=3) | st.dictionaries(_safe_text(6), children, max_size=3),
                      max_leaves=6)


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _paths(value, prefix + (key,))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from _paths(value, prefix + (i,))


def _mutate(doc, data):
    """Apply 1–3 random edits (replace, delete, insert, duplicate) to a copy of a TOML document."""
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 3), label="edits")):
        paths = [p for p in _paths(doc) if p]
        if not paths:
            break
        path = data.draw(st.sampled_from(paths), label="path")
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        key = path[-1]
        op = data.draw(st.sampled_from(["replace", "replace", "delete", "insert", "duplicate"]), label="op")
        if op == "replace":
            parent[key] = data.draw(VALUES, label="value")
        elif op == "delete":
            del parent[key]
        elif op == "insert" and isinstance(parent, dict):
            parent[data.draw(_safe_text(8), label="new key")] = data.draw(VALUES, label="value")
        elif op == "duplicate" and isinstance(parent, list):
            parent.append(copy.deepcopy(parent[key]))
    return doc


CIRCUITS = {name: tomllib.loads((MODELS / name / f"{name}.circuit.toml").read_text()) for name in ("seed_cylinder", "boom", "excavator")}
SCENARIOS = {
    "seed_cylinder": tomllib.loads((MODELS / "seed_cylinder" / "closed.scenario.toml").read_text()),
    "boom": tomllib.loads((MODELS / "boom" / "lift.scenario.toml").read_text()),
}


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    for scene in ("seed_cylinder", "boom"):
        shutil.copytree(MODELS / scene, root / scene)
    return root


# ------------------------------------------------------------------------------- property tests
@settings(FUZZ, max_examples=300)
@given(doc=st.dictionaries(_safe_text(6), VALUES, max_size=4) | st.sampled_from(list(CIRCUITS.values()) + list(SCENARIOS.values())),
       data=st.data())
def test_dump_toml_round_trips(doc, data):
    """The variant writer's TOML is read back identically (NaN compared as NaN)."""
    doc = _mutate(doc, data) if doc and data.draw(st.booleans(), label="mutate") else doc
    back = tomllib.loads(dump_toml(doc))
    assert _nan_equal(back, doc)


def test_dump_toml_quotes_awkward_keys():
    doc = {"0\n": [{}], "a.b": {"": 1}, "x\x7f": "\x7f\"\\", "ok-key_1": [1.5, -math.inf]}
    assert tomllib.loads(dump_toml(doc)) == doc


def _nan_equal(a, b):
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_nan_equal(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_nan_equal(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


@settings(FUZZ, max_examples=1000)
@given(name=st.sampled_from(sorted(CIRCUITS)), data=st.data())
def test_fuzz_circuit_documents(name, data):
    """Mutated circuits either build a network or raise one CircuitError naming the file."""
    doc = _mutate(CIRCUITS[name], data)
    result = must_be_clean(parse_circuit, doc, "fuzz.circuit.toml")
    if isinstance(result, CircuitError):
        assert "fuzz.circuit.toml" in str(result)
    elif not isinstance(result, Exception):
        for fidelity in ("compressible", "lines"):
            built = must_be_clean(NetworkModel.from_circuit, result, fidelity=fidelity)
            if isinstance(built, CircuitError):
                assert "fuzz.circuit.toml" in str(built)


@pytest.mark.filterwarnings("ignore::RuntimeWarning", "ignore:An ill-conditioned matrix")  # NaN initial states of absurd inputs
@settings(FUZZ, max_examples=600)
@given(scene=st.sampled_from(sorted(SCENARIOS)), target=st.sampled_from(["scenario", "circuit"]), data=st.data())
def test_fuzz_scenarios_and_bindings(fuzz_dir, scene, target, data):
    """Mutated scenarios (or circuits bound to the MJCF) load and bind, or raise one ScenarioError/CircuitError."""
    folder = fuzz_dir / scene
    scenario_doc = copy.deepcopy(SCENARIOS[scene])
    circuit_doc = CIRCUITS[scene]
    if target == "scenario":
        scenario_doc = _mutate(scenario_doc, data)
    else:
        circuit_doc = _mutate(circuit_doc, data)
    (folder / "fuzz.circuit.toml").write_text(dump_toml(circuit_doc))
    scene_table = scenario_doc.get("scene")
    if isinstance(scene_table, dict) and scene_table.get("circuit") == f"{scene}.circuit.toml":
        scene_table["circuit"] = "fuzz.circuit.toml"
    path = folder / "fuzz.scenario.toml"
    path.write_text(dump_toml(scenario_doc))
    scenario = must_be_clean(load_scenario, path)
    if isinstance(scenario, Exception):
        return
    loaded = must_be_clean(load_scene, scenario)
    if isinstance(loaded, CircuitError):
        assert str(folder) in str(loaded)
    elif not isinstance(loaded, Exception):
        plant = must_be_clean(MujocoPlant, loaded)  # initial state: equilibrium solve, effective masses
        if not isinstance(plant, Exception):
            # a scenario that loads must start finite, or be refused at load with a message (exit 2)
            guarded = must_be_clean(check_plant, plant)
            if isinstance(guarded, CircuitError):
                assert str(folder) in str(guarded)
            else:
                assert plant.finite(), "a scenario loaded whose state is not finite at t = 0"


@settings(FUZZ, max_examples=300)
@given(raw=st.binary(max_size=200) | _safe_text(200).map(lambda s: s.encode()), kind=st.sampled_from(["circuit", "scenario", "csv"]))
def test_fuzz_raw_file_bytes(fuzz_dir, raw, kind):
    """Arbitrary bytes as a circuit, scenario or inputs CSV file give a CircuitError or a known bug, never anything else."""
    folder = fuzz_dir / "seed_cylinder"
    if kind == "circuit":
        (folder / "raw.circuit.toml").write_bytes(raw)
        must_be_clean(load_circuit, folder / "raw.circuit.toml")
    elif kind == "scenario":
        (folder / "raw.scenario.toml").write_bytes(raw)
        must_be_clean(load_scenario, folder / "raw.scenario.toml")
    else:
        (folder / "raw.csv").write_bytes(raw)
        text = (MODELS / "seed_cylinder" / "closed.scenario.toml").read_text().replace("[log]", 'inputs_csv = "raw.csv"\n[log]')
        (folder / "csv.scenario.toml").write_text(text)
        must_be_clean(load_scenario, folder / "csv.scenario.toml")


MJCF_TEXT = (MODELS / "boom" / "boom.xml").read_text()
MJCF_ATTRIBUTES = [(e.tag, k) for e in ET.fromstring(MJCF_TEXT).iter() for k in e.attrib]


@settings(FUZZ, max_examples=200)
@given(edits=st.lists(st.tuples(st.sampled_from(MJCF_ATTRIBUTES),
                                st.one_of(st.sampled_from(["0", "-1", "nan", "inf", "1e300", "", "abc", "0 0 0", "1 2"]),
                                          st.floats(allow_nan=True).map(repr))), min_size=1, max_size=3))
def test_fuzz_mjcf_attributes(fuzz_dir, edits):
    """A mangled MJCF is rejected by load_mjmodel/bind with a ScenarioError naming it, or loads."""
    root = ET.fromstring(MJCF_TEXT)
    for (tag, attr), value in edits:
        element = next(e for e in root.iter(tag) if attr in e.attrib)
        element.set(attr, value)
    folder = fuzz_dir / "boom"
    (folder / "fuzz.xml").write_text(ET.tostring(root, encoding="unicode"))
    text = (MODELS / "boom" / "hold.scenario.toml").read_text().replace('mjcf = "boom.xml"', 'mjcf = "fuzz.xml"')
    (folder / "mjcf.scenario.toml").write_text(text)
    result = must_be_clean(lambda: load_scene(load_scenario(folder / "mjcf.scenario.toml")))
    if isinstance(result, CircuitError):
        assert "fuzz.xml" in str(result) or "boom.circuit.toml" in str(result)


CLI_WORDS = ["run", "log", "info", "recover", "demo", "stability", "inspect", "--mode", "--coupling", "--dt", "--duration",
             "--substeps", "--pbd-substeps", "--iterations", "--out", "--no-progress", "--check", "--quick", "--help",
             "mujoco", "pbd", "explicit", "implicit", "0", "-1", "1e-3", "nan", "inf", "1e400", "abc", "", "--", "-x"]


@pytest.fixture
def quiet_cli(monkeypatch, tmp_path):
    """The CLI with stepping stubbed out: scenarios are loaded, overridden and bound, but never run."""
    from sim.run import runner

    def fake_run(scenario, *, out=None, overrides=None, progress=False, overwrite=True, stop=None, warn=None):
        scenario = load_scenario(scenario)
        if overrides:
            scenario = scenario.with_overrides(**overrides)
        load_scene(scenario)
        raise SystemExit(0)

    monkeypatch.setattr(runner, "run", fake_run)
    if "sim.tools.stability" not in cli.TOOL_MODULES:
        monkeypatch.setattr(cli, "TOOL_MODULES", (*cli.TOOL_MODULES, "sim.tools.stability"))
    import sim.tools.stability as stability

    monkeypatch.setattr(stability, "stability_map", lambda *a, **k: (_ for _ in ()).throw(SystemExit(0)))
    monkeypatch.setattr("sim.tools.demo.main", lambda: 0, raising=False)
    monkeypatch.chdir(tmp_path)
    return cli.main


@settings(FUZZ, max_examples=300)
@given(words=st.lists(st.sampled_from(CLI_WORDS) | _safe_text(8), max_size=6),
       scenario=st.sampled_from([None, MODELS / "seed_cylinder" / "closed.scenario.toml", MODELS / "boom" / "hold.scenario.toml", MODELS]))
def test_fuzz_cli_arguments(quiet_cli, capsys, words, scenario):
    """Random argument lists: the CLI returns or exits with 0, 2 or 3, and never prints a traceback."""
    argv = list(words)
    if scenario is not None:
        argv.insert(min(2, len(argv)), str(scenario))
    try:
        code = quiet_cli(argv)
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    assert code in (0, 2, 3, None), (argv, code, err)
    assert TRACEBACK not in out + err


# ------------------------------------------------------------------------------- regressions (tracebacks before 2d99381)
def test_component_type_given_as_array(tmp_path, capsys):
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "seed_cylinder.circuit.toml", 'type = "cylinder"', 'type = ["cylinder"]')
    assert "component 'cyl'" in err and "field 'type'" in err


@pytest.mark.parametrize("where, old, new", [
    ("seed_cylinder.circuit.toml", "bore = 0.033851375012865375", "bore = 1" + "0" * 400),
    ("closed.scenario.toml", "duration = 0.1 ", "duration = 1" + "0" * 400 + " "),
])
def test_integer_beyond_float_range(tmp_path, capsys, where, old, new):
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", where, old, new)
    assert where in err


@pytest.mark.parametrize("name", ["seed_cylinder.circuit.toml", "closed.scenario.toml"])
def test_file_not_utf8(tmp_path, capsys, name):
    d = scene_dir(tmp_path)
    (d / name).write_bytes(b"\xff\xfe" + (d / name).read_bytes())
    err = run_bad(d / "closed.scenario.toml", capsys)
    assert name in err and "UTF-8" in err


def test_inputs_csv_with_a_leading_blank_line_is_read(tmp_path, capsys):
    d = scene_dir(tmp_path, "boom")
    (d / "inputs.csv").write_text("\nt,boom_valve\n0,0\n")
    edit(d / "hold.scenario.toml", "[scene]", 'inputs_csv = "inputs.csv"\n[scene]')
    assert set(load_scenario(d / "hold.scenario.toml").inputs) == {"boom_valve", "pump"}


def test_inputs_csv_is_a_directory(tmp_path, capsys):
    d = scene_dir(tmp_path, "boom")
    (d / "inputs.csv").mkdir()
    edit(d / "hold.scenario.toml", "[scene]", 'inputs_csv = "inputs.csv"\n[scene]')
    err = run_bad(d / "hold.scenario.toml", capsys)
    assert "inputs.csv" in err


@pytest.mark.parametrize("command, content", [("info", b""), ("info", b"\x89MCAP0\r\n"), ("info", b"not an mcap file at all"),
                                              ("recover", b""), ("recover", b"not an mcap file at all")])
def test_log_commands_on_non_mcap_files(tmp_path, capsys, content, command):
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    code, out, err = run_cli(["log", command, path, tmp_path / "out.mcap"][: 3 if command == "info" else 4], capsys)
    assert TRACEBACK not in out + err
    assert code == 2 and "bad.mcap" in err


@pytest.mark.parametrize("table, key", [("log", "rate"), ("initial", "equilibrim"), ("scene", "mjfc")])
def test_unknown_keys_in_scenario_tables(tmp_path, capsys, table, key):
    """A typo in [log], [initial] or [scene] was silently ignored (the run used the default)."""
    err = one_edit_error(tmp_path, capsys, "seed_cylinder", "closed.scenario.toml", f"[{table}]", f"[{table}]\n{key} = 1")
    assert f"'{key}'" in err and table in err


def test_negative_body_mass_compensated_by_a_child(tmp_path, capsys):
    """MuJoCo compiles a negative body mass (and zeroes it) when the subtree's total is positive; the scene loader must not."""
    err = one_edit_error(tmp_path, capsys, "boom", "boom.xml", 'mass="150"', 'mass="-150"')
    assert "boom.xml" in err and "'boom'" in err and "mass" in err


def test_backstop_refuses_a_non_finite_initial_state():
    """Causes the loaders miss are still refused before the first step, naming the node (exit 2, not a NaN run)."""
    import numpy as np

    from sim.run.guards import check_plant
    from sim.io.scenario import ScenarioError

    plant = MujocoPlant(load_scene(load_scenario(MODELS / "boom" / "hold.scenario.toml")))
    check_plant(plant)  # the shipped scene starts finite
    node = plant.network.node("boom_cyl_cap")
    plant.net_state.node_pressure[node] = np.nan
    with pytest.raises(ScenarioError, match=r"hold.scenario.toml, \[initial\]: the initial pressure of node 'boom_cyl_cap' is nan Pa"):
        check_plant(plant)
