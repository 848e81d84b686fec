"""Circuit files: a TOML netlist of components whose ports name nets.

Example::

    [fluid]
    density = 870.0            # kg/m^3
    bulk_modulus = 1.5e9       # Pa

    [[component]]
    name = "pump"
    type = "pump_fixed"
    displacement = 2.0e-5      # m^3/rev
    ports = { inlet = "tank", outlet = "supply" }

Ports sharing a net name are connected.  :func:`load_circuit` validates
everything and raises :class:`~hydraulics.components.CircuitError` with the
file, the component and the field in the message.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from .components import COMPONENT_TYPES, CircuitError, build_component, check_number, param
from .files import read_text
from .fluid import Fluid

FLUID_FIELDS = {
    # ranges of real hydraulic fluids (mineral oils, water glycols, esters, water), so that a typo
    # such as a bulk modulus of 1 Pa or a density in g/cm^3 is refused instead of simulated
    "density": param("kg/m^3", low=500.0, high=2000.0, low_open=False),
    "bulk_modulus": param("Pa", low=1e7, high=1e11, low_open=False),
    "kinematic_viscosity": param("m^2/s", low=1e-7, high=1e-2, low_open=False),
    "reference_pressure": param("Pa", low=0.0, high=1e6, low_open=False),
    "cavitation_pressure": param("Pa", low=0.0, high=2e5),
    "air_fraction": param("-", low=0.0, high=0.5, low_open=False),
    "polytropic_index": param("-", low=1.0, high=1.67, low_open=False),
}
FLUID_FIELDS = {name: f.metadata for name, f in FLUID_FIELDS.items()}


@dataclass(frozen=True)
class ComponentSpec:
    """One component of a circuit: its name, type, validated parameters and port → net map."""

    name: str
    kind: str
    params: object
    ports: dict


@dataclass(frozen=True)
class Circuit:
    """A validated circuit: fluid, components in file order, and the file it came from."""

    fluid: Fluid
    components: tuple
    source: str = "<memory>"

    def by_kind(self, *kinds):
        """Components whose type is one of ``kinds``, in file order."""
        return [c for c in self.components if c.kind in kinds]

    def component(self, name):
        """The component called ``name`` (KeyError if absent)."""
        for c in self.components:
            if c.name == name:
                return c
        raise KeyError(name)


def parse_fluid(table, where: str) -> Fluid:
    """Validate the ``[fluid]`` table into a :class:`Fluid`."""
    if not isinstance(table, dict):
        raise CircuitError(f"{where}: [fluid] must be a table")
    values = {}
    cavitation = table.get("cavitation", True)
    if not isinstance(cavitation, bool):
        raise CircuitError(f"{where}, field 'cavitation': expected true or false, got {cavitation!r}")
    for key, value in table.items():
        if key == "cavitation":
            continue
        if key not in FLUID_FIELDS:
            raise CircuitError(f"{where}: unknown field '{key}'; allowed: {sorted(FLUID_FIELDS) + ['cavitation']}")
        values[key] = check_number(value, FLUID_FIELDS[key], f"{where}, field '{key}'")
    if not cavitation:
        if "cavitation_pressure" in values:
            raise CircuitError(f"{where}: 'cavitation = false' contradicts 'cavitation_pressure'")
        values["cavitation_pressure"] = None
    try:
        return Fluid(**values)
    except ValueError as exc:
        raise CircuitError(f"{where}: {exc}") from None


def parse_circuit(data: dict, source: str = "<memory>") -> Circuit:
    """Validate a parsed circuit document (the dict of a TOML file)."""
    if not isinstance(data, dict):
        raise CircuitError(f"{source}: the circuit must be a TOML document of tables")
    unknown = sorted(set(data) - {"fluid", "component"})
    if unknown:
        raise CircuitError(f"{source}: unknown top-level key(s) {unknown}; allowed: 'fluid', 'component'")
    fluid = parse_fluid(data.get("fluid", {}), f"{source}: [fluid]")
    tables = data.get("component", [])
    if not isinstance(tables, list) or not tables:
        raise CircuitError(f"{source}: no [[component]] tables; a circuit needs at least one component")
    components, names = [], set()
    for index, table in enumerate(tables):
        where = f"{source}: component #{index + 1}"
        if not isinstance(table, dict):
            raise CircuitError(f"{where}: must be a table")
        name = table.get("name")
        if not isinstance(name, str) or not name:
            raise CircuitError(f"{where}: missing field 'name' (a non-empty string)")
        where = f"{source}: component '{name}'"
        if name in names:
            raise CircuitError(f"{where}: duplicate component name '{name}'")
        names.add(name)
        kind = table.get("type")
        if not isinstance(kind, str) or kind not in COMPONENT_TYPES:
            raise CircuitError(f"{where}, field 'type': unknown component type {kind!r}; allowed: {sorted(COMPONENT_TYPES)}")
        cls = COMPONENT_TYPES[kind]
        ports = table.get("ports")
        if not isinstance(ports, dict):
            raise CircuitError(f"{where}: missing field 'ports' (a table of port = \"net\"; ports {list(cls.PORTS)})")
        for port in cls.PORTS:
            if port not in ports:
                raise CircuitError(f"{where}, field 'ports': port '{port}' is unconnected; type '{kind}' has ports {list(cls.PORTS)}")
        optional = tuple(getattr(cls, "OPTIONAL_PORTS", ()))
        for port, net in ports.items():
            if port not in cls.PORTS + optional:
                raise CircuitError(f"{where}, field 'ports': unknown port '{port}'; type '{kind}' has ports {list(cls.PORTS)}"
                                   + (f" and optionally {list(optional)}" if optional else ""))
            if not isinstance(net, str) or not net:
                raise CircuitError(f"{where}, field 'ports.{port}': net name must be a non-empty string, got {net!r}")
        if len(cls.PORTS) > 1 and len(set(ports.values())) < len(ports) and kind != "hose":
            seen = {}
            for port, net in ports.items():
                if net in seen:
                    raise CircuitError(
                        f"{where}, field 'ports': ports '{seen[net]}' and '{port}' are both connected to net '{net}' (a port short-circuited)"
                    )
                seen[net] = port
        params = build_component(kind, {k: v for k, v in table.items() if k not in ("name", "type", "ports")}, where)
        components.append(ComponentSpec(name, kind, params, dict(ports)))
    return Circuit(fluid, tuple(components), source)


def read_toml(path: Path, what: str, error: type[CircuitError] = CircuitError) -> dict:
    """The document of a UTF-8 TOML file, or ``error`` naming the file.

    ``what`` names the kind of file in the messages ("circuit", "scenario");
    ``error`` is the :class:`CircuitError` subclass raised (missing file, not a
    regular file, over :data:`hydraulics.files.MAX_INPUT_BYTES`, a NUL byte, not
    UTF-8, not valid TOML; see :func:`hydraulics.files.read_text`).
    """
    text = read_text(path, what, error)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML: {exc}") from None
    except RecursionError:  # thousands of nested arrays or inline tables
        raise error(f"{path}: not valid TOML: nested too deeply") from None


def load_circuit(path) -> Circuit:
    """Read and validate a circuit TOML file."""
    path = Path(path)
    return parse_circuit(read_toml(path, "circuit"), str(path))


def finite(value) -> bool:
    """True for a finite real number."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
