"""Bad circuit files give one clear message naming the file, the component, the field and the allowed range."""

import pytest

from conftest import network_from_toml
from hydraulics.circuit import load_circuit
from hydraulics.components import CircuitError

BASE = """
[fluid]
bulk_modulus = 1.5e9
[[component]]
name = "tank"
type = "tank"
ports = { port = "tank" }
"""

CYLINDER = """
[[component]]
name = "cyl"
type = "cylinder"
bore = BORE
rod_diameter = 0.03
stroke = 0.5
ports = { cap = "a", rod = "tank" }
"""


def error_of(text, path="bad.toml"):
    with pytest.raises(CircuitError) as info:
        network_from_toml(text, source=path)
    return str(info.value)


def test_unknown_component_type():
    msg = error_of(BASE + '[[component]]\nname = "x"\ntype = "valve_9_9"\nports = {}\n')
    assert "bad.toml" in msg and "'x'" in msg and "'type'" in msg and "valve_9_9" in msg and "valve_4_3" in msg


def test_missing_parameter():
    msg = error_of(BASE + '[[component]]\nname = "o"\ntype = "orifice"\nports = { a = "tank", b = "n" }\n')
    assert "component 'o'" in msg and "missing field 'area'" in msg and "(0, 0.1] m^2" in msg


@pytest.mark.parametrize("value", ["0.0", "-0.01"])
def test_non_positive_area(value):
    msg = error_of(BASE + f'[[component]]\nname = "o"\ntype = "orifice"\narea = {value}\nports = {{ a = "tank", b = "n" }}\n')
    assert "field 'area'" in msg and "outside the allowed range (0, 0.1] m^2" in msg


def test_non_positive_volume():
    msg = error_of(BASE + '[[component]]\nname = "v"\ntype = "volume"\nvolume = 0.0\nports = { port = "n" }\n')
    assert "component 'v'" in msg and "field 'volume'" in msg and "(0, 10] m^3" in msg


def test_unit_suspicious_bore_in_millimetres():
    msg = error_of(BASE + CYLINDER.replace("BORE", "80"))
    assert "field 'bore'" in msg and "80.0" in msg and "(0, 1] m" in msg and "not millimetres" in msg


def test_wrong_type_and_nan():
    assert "expected a number" in error_of(BASE + CYLINDER.replace("BORE", '"0.08"'))
    assert "nan" in error_of(BASE + CYLINDER.replace("BORE", "nan"))


def test_rod_not_smaller_than_bore():
    assert "must be smaller than bore" in error_of(BASE + CYLINDER.replace("BORE", "0.02"))


def test_unconnected_port():
    msg = error_of(BASE + '[[component]]\nname = "o"\ntype = "orifice"\narea = 1e-6\nports = { a = "tank" }\n')
    assert "port 'b' is unconnected" in msg and "component 'o'" in msg


def test_port_connected_twice():
    msg = error_of(BASE + CYLINDER.replace("BORE", "0.08").replace('cap = "a"', 'cap = "tank"'))
    assert "ports 'cap' and 'rod' are both connected to net 'tank'" in msg


def test_unknown_port_and_field():
    assert "unknown port 'c'" in error_of(BASE + '[[component]]\nname = "o"\ntype = "orifice"\narea = 1e-6\nports = { a = "tank", b = "n", c = "m" }\n')
    assert "unknown field(s) ['bore_mm']" in error_of(BASE + CYLINDER.replace("BORE", "0.08").replace("stroke", "bore_mm = 80\nstroke"))


def test_duplicate_name():
    assert "duplicate component name 'tank'" in error_of(BASE + BASE.split("\n", 3)[3])


def test_net_without_volume():
    # a cylinder (so nothing is pruned) whose cap line leads through an orifice into a net with no volume
    msg = error_of(BASE + CYLINDER.replace("BORE", "0.08") + '[[component]]\nname = "o"\ntype = "orifice"\narea = 1e-6\nports = { a = "a", b = "dangling" }\n')
    assert "net 'dangling' has no volume" in msg


def test_fluid_errors():
    assert "field 'bulk_modulus'" in error_of(BASE.replace("1.5e9", "-1"))
    assert "unknown field 'viscosity'" in error_of(BASE.replace("bulk_modulus", "viscosity"))


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(CircuitError, match="circuit file not found"):
        load_circuit(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[[component]\nname=")
    with pytest.raises(CircuitError, match="bad.toml: not valid TOML"):
        load_circuit(bad)


@pytest.mark.parametrize("line, field, allowed", [
    ("bulk_modulus = 1.0", "bulk_modulus", "[1e+07, 1e+11] Pa"),  # 1 Pa: loads, but the oil is a gas
    ("bulk_modulus = 1.5e12", "bulk_modulus", "[1e+07, 1e+11] Pa"),
    ("density = 0.87", "density", "[500, 2000] kg/m^3"),  # g/cm^3 typed for kg/m^3
    ("kinematic_viscosity = 46.0", "kinematic_viscosity", "[1e-07, 0.01] m^2/s"),  # cSt typed for m^2/s
    ("air_fraction = 0.9", "air_fraction", "[0, 0.5] -"),
    ("cavitation_pressure = 1e6", "cavitation_pressure", "(0, 200000] Pa"),
])
def test_physically_absurd_fluid(line, field, allowed):
    msg = error_of(BASE.replace("bulk_modulus = 1.5e9", line))
    assert "bad.toml" in msg and "[fluid]" in msg and f"field '{field}'" in msg and allowed in msg


def test_hose_wall_softer_than_any_hose():
    hose = '[[component]]\nname = "h"\ntype = "hose"\nlength = 1.0\ninner_diameter = 0.02\nwall_bulk_modulus = 10.0\nports = { a = "a", b = "b" }\n'
    msg = error_of(BASE + CYLINDER.replace("BORE", "0.08") + hose)
    assert "component 'h'" in msg and "field 'wall_bulk_modulus'" in msg and "[1e+07, 1e+12] Pa" in msg


def test_fidelity_overrides_name_actuators_and_levels():
    from hydraulics.circuit import parse_circuit
    from hydraulics.network import NetworkModel
    import tomllib

    circuit = parse_circuit(tomllib.loads(BASE + CYLINDER.replace("BORE", "0.08")), "bad.toml")
    with pytest.raises(CircuitError, match=r"bad.toml: fidelity for 'arm': no cylinder or motor of that name; actuators: \['cyl'\]"):
        NetworkModel.from_circuit(circuit, actuator_fidelity={"arm": "lines"})
    with pytest.raises(CircuitError, match=r"fidelity for 'cyl': 'exact' is not one of"):
        NetworkModel.from_circuit(circuit, actuator_fidelity={"cyl": "exact"})


def test_circuit_without_any_actuator_is_refused(tmp_path):
    """A circuit whose only cylinder is deleted would build an empty network: refused in one line naming it."""
    from conftest import scene_copy
    from sim.io.scenario import ScenarioError, load_scenario
    from sim.io.scene import load_scene

    scene = scene_copy(tmp_path, "boom")
    circuit = scene / "boom.circuit.toml"
    text = circuit.read_text()
    start = text.index('name = "boom_cyl"')
    start = text.rindex("[[component]]", 0, start)
    end = text.find("[[component]]", start + 1)
    circuit.write_text(text[:start] + (text[end:] if end >= 0 else ""))
    with pytest.raises(ScenarioError, match=r"boom\.circuit\.toml: no 'cylinder' or 'motor' component") as err:
        load_scene(load_scenario(scene / "lift.scenario.toml"))
    assert "\n" not in str(err.value)
