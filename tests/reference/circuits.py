"""Circuit text shared by the tests' small benches.

:func:`bench` is the head of such a circuit: the tests' oil (ISO VG 46 at 40 °C: 870 kg/m³, β 1.5e9 Pa,
ν 4.6e-5 m²/s, the package's default reference pressure), a tank on net ``tank`` and, given a pressure, an ideal
supply on net ``supply`` (a second tank held at that absolute pressure).  A test appends its own components.

Example
-------
>>> import tomllib
>>> [c["name"] for c in tomllib.loads(bench(1e7))["component"]]
['tank', 'supply']
"""

from __future__ import annotations

HEAD = '''
[fluid]
density = 870.0
bulk_modulus = 1.5e9
kinematic_viscosity = 4.6e-5

[[component]]
name = "tank"
type = "tank"
ports = { port = "tank" }
'''

SUPPLY = '''
[[component]]
name = "supply"
type = "tank"
pressure = %r
ports = { port = "supply" }
'''


def bench(supply_pressure: float | None = None) -> str:
    """TOML text of the fluid and the tank, and of a supply held at ``supply_pressure`` [Pa absolute] if given."""
    return HEAD + ("" if supply_pressure is None else SUPPLY % float(supply_pressure))
