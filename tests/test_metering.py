"""Valve edges' metering characteristics (linear, exponential, tabulated) and the variable orifice.

The tabulated edge is checked against scipy's monotone cubic (PCHIP) evaluated independently of the kernel, the
exponential edge against its closed form; the variable orifice's steady pressure against the textbook orifice law
solved for the pump's flow, open loop and under a PID pressure controller, in both modes.
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from scipy.interpolate import PchipInterpolator
from scipy.optimize import brentq

from conftest import network_from_toml
from hydraulics.circuit import parse_circuit
from hydraulics.components import CircuitError
from hydraulics.components.metering import knot_slopes
from hydraulics.fluid import Fluid
from reference.circuits import bench, pump_into_volume
from reference.scenes import BENCH
from reference.laws import orifice_textbook
from sim.io.mcap_log import read_log
from sim.run.runner import run

LEAK, FULL, OVERLAP = 1e-9, 5e-5, 0.05
TABLE_PA = [[0.05, 0.0], [0.2, 2e-6], [0.5, 1.2e-5], [0.8, 3.5e-5], [1.0, 5e-5]]
TABLE_AT = [[0.1, 0.0], [0.6, 4e-5], [1.0, 6e-5]]


def valve(name: str, metering: str = "", nets=("supply", "tank", "a", "b")) -> str:
    """TOML text of a closed-centre 4/3 valve ``name`` with the metering fields ``metering`` (TOML lines)."""
    P, T, A, B = nets
    return (f'\n[[component]]\nname = "{name}"\ntype = "valve_4_3"\nmax_area = {FULL!r}\noverlap = {OVERLAP!r}\n'
            f'leakage_area = {LEAK!r}\n{metering}ports = {{ P = "{P}", T = "{T}", A = "{A}", B = "{B}" }}\n')


def edge_areas(model, spool):
    """Open area [m²] of each named orifice branch at the valves' spools ``spool``."""
    area = model.valve_areas(np.asarray(spool, float))
    return dict(zip(model.branch_names, area))


CYLINDER = ('\n[[component]]\nname = "cyl"\ntype = "cylinder"\nbore = 0.05\nrod_diameter = 0.028\nstroke = 0.5\n'
            'ports = { cap = "a", rod = "b" }\n')
TABLED = valve("v", 'metering = "table"\narea_table = { "P-A" = %s, "A-T" = %s }\n' % (TABLE_PA, TABLE_AT))


@pytest.mark.parametrize("spool", np.linspace(-1.0, 1.0, 41).tolist() + [0.05, 0.2, 0.35, -0.6, -0.999])
def test_tabulated_edges_follow_the_monotone_cubic_and_the_others_stay_linear(spool):
    """Edges with a table give leakage + PCHIP(x) at the travel x along their opening direction, held at the end
    values outside the table; the edges without one keep the linear law beyond the overlap."""
    model = network_from_toml(bench(2e7) + TABLED + "\n" + volume_nets())
    area = edge_areas(model, [spool])
    for edge, table, x in (("P-A", TABLE_PA, spool), ("A-T", TABLE_AT, -spool)):
        knots = np.array(table)
        expected = LEAK + float(PchipInterpolator(knots[:, 0], knots[:, 1])(np.clip(x, knots[0, 0], knots[-1, 0])))
        assert area[f"v.{edge}"] == pytest.approx(expected, rel=1e-12, abs=1e-18)
    for edge, x in (("B-T", spool), ("P-B", -spool)):
        linear = LEAK + FULL * min(max((x - OVERLAP) / (1.0 - OVERLAP), 0.0), 1.0)
        assert area[f"v.{edge}"] == linear


def test_a_tabulated_edge_is_c1_and_monotone_through_its_knots():
    """The slope of the tabulated area is continuous at every inner knot (one-sided differences agree to the
    truncation of the difference) and never negative for monotone data."""
    model = network_from_toml(bench(2e7) + TABLED + "\n" + volume_nets())
    index = model.branch_names.index("v.P-A")

    def area(s):
        return model.valve_areas(np.array([s]))[index]

    h = 1e-6
    for x, _ in TABLE_PA[1:-1]:
        left, right = (area(x) - area(x - h)) / h, (area(x + h) - area(x)) / h
        assert right == pytest.approx(left, rel=1e-3, abs=1e-9)
    values = [area(s) for s in np.linspace(0.0, 1.0, 401)]
    assert np.all(np.diff(values) >= -1e-20)


@pytest.mark.parametrize("seed", range(12))
def test_knot_slopes_are_scipys_pchip_slopes(seed):
    """The knots' slopes equal scipy's PchipInterpolator's derivative at the knots on random tables: monotone,
    with flat stretches, and with turning points (two to nine knots, uneven spacing)."""
    rng = np.random.default_rng(seed)
    count = int(rng.integers(2, 10))
    travel = np.sort(rng.uniform(-1.0, 1.0, count))
    area = rng.uniform(0.0, 1e-4, count)
    if seed % 3 == 0:
        area = np.sort(area)
    if seed % 3 == 1 and count > 3:
        area[1:3] = area[1]
    expected = PchipInterpolator(travel, area).derivative()(travel)
    np.testing.assert_allclose(knot_slopes(travel, area), expected, rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("exponent", [3.0, -2.0, 0.5])
def test_exponential_edges_follow_their_closed_form(exponent):
    """A_leak + A_max·(e^(a·y) − 1)/(e^a − 1), y the linear opening beyond the overlap, on every metering edge."""
    model = network_from_toml(bench(2e7) + valve("v", f'metering = "exponential"\nmetering_exponent = {exponent!r}\n')
                              + volume_nets())
    for spool in np.linspace(-1.0, 1.0, 21):
        area = edge_areas(model, [spool])
        for edge, x in (("P-A", spool), ("B-T", spool), ("P-B", -spool), ("A-T", -spool)):
            y = min(max((x - OVERLAP) / (1.0 - OVERLAP), 0.0), 1.0)
            expected = LEAK + FULL * math.expm1(exponent * y) / math.expm1(exponent)
            assert area[f"v.{edge}"] == pytest.approx(expected, rel=1e-13, abs=1e-20)


def volume_nets() -> str:
    return ''.join(f'\n[[component]]\nname = "vol_{n}"\ntype = "volume"\nvolume = 1.0e-4\nports = {{ port = "{n}" }}\n'
                   for n in ("a", "b"))


@pytest.mark.parametrize(("fields", "message"), [
    ('metering = "table"\n', "field 'area_table': metering = \"table\" needs a table"),
    ('area_table = { "P-A" = [[0.0, 0.0], [1.0, 1e-5]] }\n', "set metering = \"table\""),
    ('metering_exponent = 2.0\n', "field 'metering_exponent': given with metering = 'linear'"),
    ('metering = "table"\nmetering_exponent = -1.5\narea_table = { "P-A" = [[0.0, 0.0], [1.0, 1e-5]] }\n',
     "field 'metering_exponent': given with metering = 'table'"),
    ('metering = "table"\narea_table = { "P-X" = [[0.0, 0.0], [1.0, 1e-5]] }\n', "unknown edge(s) ['P-X']"),
    ('metering = "table"\narea_table = { "P-A" = [[0.5, 0.0], [0.2, 1e-5]] }\n', "table 'P-A': expected a list"),
    ('metering = "table"\narea_table = { "P-A" = [[0.0, 0.0], [1.0, 0.5]] }\n', "area in [0, 0.01] m^2"),
    ('metering = "table"\narea_table = { "P-A" = [[0.0, 0.0]] }\n', "at least two"),
    ('metering = "table"\narea_table = [1, 2]\n', "field 'area_table': expected a table of name"),
])
def test_bad_metering_fields_are_refused_naming_the_field(fields, message):
    with pytest.raises(CircuitError) as error:
        parse_circuit(tomllib.loads(bench(2e7) + valve("v", fields) + volume_nets()), "valves.toml")
    assert message in str(error.value) and "valves.toml" in str(error.value)


@pytest.mark.parametrize(("fields", "message"), [
    ('metering = "table"\narea_table = { "a-b" = [[-0.5, 0.0], [1.0, 1e-5]] }\n', "outside the command range [0, 1]"),
    ('metering = "table"\narea_table = { "P-A" = [[0.0, 0.0], [1.0, 1e-5]] }\n', "unknown edge(s) ['P-A']; edges: ['a-b']"),
    ('metering = "table"\narea_table = { "a-b" = [[false, 0.0], [true, 1e-5]] }\n', "table 'a-b': expected a list"),
    ('metering = "table"\narea_table = { "a-b" = [["0", 0.0], [1.0, 1e-5]] }\n', "table 'a-b': expected a list"),
    ('max_area = 2.0\n', "field 'max_area': 2.0 is outside the allowed range (0, 0.01] m^2"),
])
def test_bad_throttle_fields_are_refused_naming_the_field(fields, message):
    text = bench(2e7) + ('\n[[component]]\nname = "t"\ntype = "variable_orifice"\n'
                         + ("" if "max_area" in fields else "max_area = 1e-5\n") + fields
                         + 'ports = { a = "supply", b = "tank" }\n')
    with pytest.raises(CircuitError) as error:
        parse_circuit(tomllib.loads(text), "throttle.toml")
    assert message in str(error.value) and "throttle.toml: component 't'" in str(error.value)


def test_a_throttle_in_an_incompressible_network_is_refused():
    """The rigid oil law knows 4/3 valves only: a variable orifice there is refused, naming its type."""
    throttle = '\n[[component]]\nname = "t"\ntype = "variable_orifice"\nmax_area = 1e-5\nports = { a = "a", b = "tank" }\n'
    with pytest.raises(CircuitError, match="component 't', type 'variable_orifice' at fidelity 'incompressible'"):
        network_from_toml(bench(2e7) + valve("v") + CYLINDER + throttle, actuator_fidelity={"cyl": "incompressible"})


def test_a_throttle_command_below_zero_holds_it_shut():
    """The kernels hold a variable orifice's command to [0, 1] (a 4/3 valve's to [−1, 1]): a negative command leaves
    its opening at 0, not below, so it reopens without delay."""
    model = network_from_toml(bench(2e7) + valve("v") + volume_nets()
                              + '\n[[component]]\nname = "t"\ntype = "variable_orifice"\nmax_area = 1e-5\n'
                                'time_constant = 0.01\nports = { a = "a", b = "tank" }\n')
    assert model.valve_names == ("v", "t")
    assert model.valve_commands([-0.7, -0.7]).tolist() == [-0.7, 0.0]


def test_a_shaped_valve_on_an_incompressible_actuator_is_refused():
    """The rigid oil law meters linearly: a non-linear characteristic there is refused, naming the field."""
    text = bench(2e7) + valve("v", 'metering = "exponential"\n') + CYLINDER
    with pytest.raises(CircuitError, match="field 'metering'"):
        network_from_toml(text, source="rigid.toml", actuator_fidelity={"cyl": "incompressible"})
    network_from_toml(bench(2e7) + valve("v") + CYLINDER, actuator_fidelity={"cyl": "incompressible"})


# ---------------------------------------------------------------------------------------------------- variable orifice
DISPLACEMENT, SPEED, VOLUME, THROTTLE_AREA = 1.0e-5, 20.0, 2.0e-3, 1.0e-5  # m³/rev, rev/s, m³, m²
RIG = bench() + pump_into_volume(DISPLACEMENT, SPEED, VOLUME) + f"""
[[component]]
name = "throttle"
type = "variable_orifice"
max_area = {THROTTLE_AREA!r}
leakage_area = 0.0
time_constant = 0.01
ports = {{ a = "supply", b = "tank" }}

[[component]]
name = "relief"
type = "relief_valve"
cracking_pressure = 1.5e7
gradient = 2.0e-10
ports = {{ inlet = "supply", outlet = "tank" }}
"""
SCENARIO = """
[scene]
mjcf = "rig.xml"
circuit = "rig.circuit.toml"

[run]
mode = "{mode}"
dt = 0.001
duration = {duration}

{inputs}

[log]
rate_hz = 100
"""


def steady_drop(area: float) -> float:
    """Δp [Pa] at which the textbook orifice law passes the pump's flow through ``area``."""
    flow = DISPLACEMENT * SPEED
    return brentq(lambda dp: orifice_textbook(area, 0.7, dp, Fluid()) - flow, 1.0, 1e9, xtol=1e-6, rtol=1e-13)


def run_rig(tmp_path, mode, inputs, duration):
    (tmp_path / "rig.xml").write_text(BENCH, encoding="utf-8")
    (tmp_path / "rig.circuit.toml").write_text(RIG, encoding="utf-8")
    scenario = tmp_path / f"rig-{mode}.scenario.toml"
    scenario.write_text(SCENARIO.format(mode=mode, inputs=inputs, duration=duration), encoding="utf-8")
    result = run(scenario, out=tmp_path / f"rig-{mode}.mcap")
    assert result.status == "complete", result.message
    return read_log(result.log_path)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_a_commanded_throttle_holds_the_orifice_law_pressure_of_its_opening(tmp_path, mode):
    """Open loop: the opening commanded 0.6, then 0.3 at 0.5 s; at the end of each plateau the supply pressure
    stands where the orifice law through 0.6 and 0.3 of the full area passes the pump's flow (within 0.1 %)."""
    inputs = '[inputs]\nthrottle = { t = [0.0, 0.5, 0.5001], value = [0.6, 0.6, 0.3] }\n'
    log = run_rig(tmp_path, mode, inputs, 1.0)
    nodes = log.topic("/hydroplant/nodes")
    tank = Fluid().reference_pressure
    for t_end, opening in ((0.5, 0.6), (1.0, 0.3)):
        k = int(np.searchsorted(nodes.t, t_end - 1e-9)) - 1
        drop = nodes["pressure_pa.supply"][k] - tank
        assert drop == pytest.approx(steady_drop(opening * THROTTLE_AREA), rel=1e-3)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_a_pid_holds_the_supply_pressure_through_the_throttle(tmp_path, mode):
    """Closed loop: a PI controller reads the supply pressure and commands the throttle (negative gains: opening
    it lowers the pressure), from rest with the throttle shut and the pump's flow over the relief; the pressure
    settles at the 60 bar set point (within 0.2 %) with the opening where the
    orifice law says (within 0.5 %)."""
    setpoint = 60e5
    inputs = ('[controllers.hold]\ntype = "pid"\noutput = "throttle"\nsensor = "pressure:supply"\n'
              f'setpoint = {setpoint!r}\nkp = -5.0e-8\nki = -1.0e-6\nlow = 0.0\nhigh = 1.0\n')
    log = run_rig(tmp_path, mode, inputs, 1.5)
    nodes = log.topic("/hydroplant/nodes")
    assert nodes["pressure_pa.supply"][-1] == pytest.approx(setpoint, rel=2e-3)
    opening = log.topic("/hydroplant/valves/throttle")
    expected = steady_drop_area(setpoint - Fluid().reference_pressure) / THROTTLE_AREA
    assert opening["spool"][-1] == pytest.approx(expected, rel=5e-3)


def steady_drop_area(drop: float) -> float:
    """Area [m²] through which the textbook orifice law passes the pump's flow at ``drop`` [Pa]."""
    flow = DISPLACEMENT * SPEED
    return brentq(lambda a: orifice_textbook(a, 0.7, drop, Fluid()) - flow, 1e-12, 1e-3, xtol=1e-20, rtol=1e-13)
