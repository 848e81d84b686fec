"""Circuit text shared by the tests' small benches.

:func:`bench` is the head of such a circuit: the tests' oil (ISO VG 46 at 40 °C: 870 kg/m³, β 1.5e9 Pa,
ν 4.6e-5 m²/s, the package's default reference pressure), a tank on net ``tank`` and, given a pressure, an ideal
supply on net ``supply`` (a second tank held at that absolute pressure).  A test appends its own components:
:func:`orifice`, :func:`pressure_source`, :func:`pump_into_volume` (a fixed pump filling net ``supply``), and :func:`lift_cylinder` for :func:`reference.scenes.vertical_lift` (cylinder ``lift``, cap on net
``cap``, rod vented to the tank).

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


def orifice(name: str, a: str, b: str, area: float, discharge_coefficient: float = 0.7) -> str:
    """TOML text of a fixed orifice ``name`` of ``area`` [m²] between nets ``a`` and ``b``."""
    return (f'\n[[component]]\nname = "{name}"\ntype = "orifice"\narea = {float(area)!r}\n'
            f'discharge_coefficient = {float(discharge_coefficient)!r}\nports = {{ a = "{a}", b = "{b}" }}\n')


def lift_cylinder(bore: float, **fields) -> str:
    """TOML text of cylinder ``lift`` of ``bore`` [m] (28 mm rod, 0.5 m stroke, 20 mL dead volume each side), cap on
    net ``cap``, rod on the tank; ``fields``: further cylinder fields (numbers or strings)."""
    extra = "".join(f"{key} = {value!r}\n" if not isinstance(value, str) else f'{key} = "{value}"\n'
                    for key, value in fields.items())
    return (f'\n[[component]]\nname = "lift"\ntype = "cylinder"\nbore = {float(bore)!r}\nrod_diameter = 0.028\n'
            f'stroke = 0.5\ndead_volume_cap = 2.0e-5\ndead_volume_rod = 2.0e-5\n{extra}'
            f'ports = {{ cap = "cap", rod = "tank" }}\n')


def pressure_source(pressure: float) -> str:
    """TOML text of an ideal pressure source ``source`` holding net ``supply`` at ``pressure`` [Pa gauge]."""
    return (f'\n[[component]]\nname = "source"\ntype = "pressure_source"\npressure = {float(pressure)!r}\n'
            f'ports = {{ port = "supply" }}\n')


def pump_into_volume(displacement: float, speed: float, volume: float) -> str:
    """TOML text of fixed pump ``pump`` (``displacement`` [m³/rev] at ``speed`` [rev/s], no leakage) from the tank
    into net ``supply``, which holds ``volume`` [m³] (component ``supply_volume``)."""
    return (f'\n[[component]]\nname = "pump"\ntype = "pump_fixed"\ndisplacement = {float(displacement)!r}\n'
            f'speed = {float(speed)!r}\nvolumetric_efficiency = 1.0\nports = {{ inlet = "tank", outlet = "supply" }}\n'
            f'\n[[component]]\nname = "supply_volume"\ntype = "volume"\nvolume = {float(volume)!r}\n'
            f'ports = {{ port = "supply" }}\n')
