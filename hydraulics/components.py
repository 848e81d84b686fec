"""Component parameter sets of a hydraulic circuit.

Each component type is a frozen, keyword-only dataclass whose fields carry
their unit and allowed range in ``field(metadata=...)``; :func:`build_component`
validates a table read from a circuit file against them, so every message names
the file, the component, the field and the allowed range.  The laws these
parameters feed live in :mod:`hydraulics.laws`.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, field, fields



class CircuitError(ValueError):
    """A circuit or scenario file is wrong; the message names file, component and field."""


def param(unit: str, *, low=None, high=None, low_open=True, default=MISSING, choices=None):
    """A dataclass field with its unit and allowed range ``(low, high]`` (``[low, high]`` if not ``low_open``)."""
    return field(default=default, metadata={"unit": unit, "low": low, "high": high, "low_open": low_open, "choices": choices})


def describe_range(meta) -> str:
    """Human text of a field's allowed range, e.g. '(0, 1] m'."""
    if meta["choices"]:
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    low = "-inf" if meta["low"] is None else f"{meta['low']:g}"
    high = "inf" if meta["high"] is None else f"{meta['high']:g}"
    left = "(" if meta["low_open"] or meta["low"] is None else "["
    return f"{left}{low}, {high}] {meta['unit']}".rstrip()


@dataclass(frozen=True, kw_only=True)
class Tank:
    """Reservoir at a fixed absolute pressure."""

    pressure: float = param("Pa", low=0.0, high=1e8, low_open=False, default=1.01325e5)
    """Absolute pressure [Pa]."""
    PORTS = ("port",)


@dataclass(frozen=True, kw_only=True)
class PumpFixed:
    """Fixed-displacement pump: Q = η_v·D·n, τ = D·Δp/(2π) (seed report)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Geometric displacement D [m³/rev]."""
    speed: float = param("rev/s", low=0.0, high=1000.0, low_open=False, default=0.0)
    """Nominal shaft speed n [rev/s]; scenarios may schedule it."""
    volumetric_efficiency: float = param("-", low=0.0, high=1.0, default=1.0)
    """η_v [-]."""
    PORTS = ("inlet", "outlet")


@dataclass(frozen=True, kw_only=True)
class PumpCompensated:
    """Pressure-compensated variable pump: full displacement below the setting, zero at setting + band."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Maximum displacement D_max [m³/rev]."""
    speed: float = param("rev/s", low=0.0, high=1000.0, low_open=False, default=0.0)
    """Nominal shaft speed n [rev/s]."""
    compensator_pressure: float = param("Pa", low=0.0, high=1e9)
    """Outlet pressure where destroking starts [Pa, absolute]."""
    compensator_band: float = param("Pa", low=0.0, high=1e8, default=1e6)
    """Pressure rise over which the displacement falls to zero [Pa]."""
    PORTS = ("inlet", "outlet")


@dataclass(frozen=True, kw_only=True)
class Orifice:
    """Fixed orifice (see :func:`hydraulics.laws.orifice_flow_with_derivative`)."""

    area: float = param("m^2", low=0.0, high=0.1)
    """Open area A [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("a", "b")


@dataclass(frozen=True, kw_only=True)
class Valve43:
    """Proportional 4/3 directional control valve (ports P, T, A, B).

    Spool s ∈ [−1, 1] follows its command through a first-order lag.  s > 0
    opens P→A and B→T, s < 0 opens P→B and A→T; each metering edge opens
    linearly beyond the overlap.  Centre: ``closed`` (all blocked but leakage),
    ``open`` (P, T, A, B all connected at s = 0), ``tandem`` (P→T open, A and B
    blocked at s = 0).
    """

    max_area: float = param("m^2", low=0.0, high=0.01)
    """Area of each metering edge fully open [m²]."""
    centre: str = param("-", default="closed", choices=("closed", "open", "tandem"))
    """Centre type."""
    centre_area: float = param("m^2", low=0.0, high=0.01, low_open=False, default=0.0)
    """Area of the centre passages at s = 0 [m²] (open/tandem)."""
    overlap: float = param("-", low=0.0, high=0.5, low_open=False, default=0.05)
    """Dead band of each edge as a fraction of spool travel [-]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-9)
    """Area of every edge when closed (spool clearance) [m²]."""
    time_constant: float = param("s", low=0.0, high=10.0, low_open=False, default=0.03)
    """First-order spool time constant τ [s]; 0 = ideal spool."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("P", "T", "A", "B")


@dataclass(frozen=True, kw_only=True)
class ReliefValve:
    """Direct pressure-relief valve: Q = G·(Δp − p_crack) above cracking."""

    cracking_pressure: float = param("Pa", low=0.0, high=1e9)
    """Differential cracking pressure [Pa]."""
    gradient: float = param("m^3/(s*Pa)", low=0.0, high=1e-3)
    """Pressure–flow gradient G [m³/(s·Pa)]; override = Q/G."""
    PORTS = ("inlet", "outlet")


@dataclass(frozen=True, kw_only=True)
class CheckValve:
    """Check valve: closed below cracking, area rising linearly to full opening."""

    cracking_pressure: float = param("Pa", low=0.0, high=1e8, low_open=False, default=1e4)
    """Differential pressure where it starts to open [Pa]."""
    full_open_pressure: float = param("Pa", low=0.0, high=1e8, default=1e5)
    """Differential pressure where it is fully open [Pa]."""
    area: float = param("m^2", low=0.0, high=0.01)
    """Fully open area [m²]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-10)
    """Closed area [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    PORTS = ("inlet", "outlet")


@dataclass(frozen=True, kw_only=True)
class Volume:
    """A lumped oil volume (line, manifold, port volume)."""

    volume: float = param("m^3", low=0.0, high=10.0)
    """Volume at the reference pressure [m³]."""
    wall_bulk_modulus: float = param("Pa", low=1e7, high=1e12, low_open=False, default=math.inf)
    """Wall compliance as a bulk modulus [Pa]; inf = rigid."""
    PORTS = ("port",)


@dataclass(frozen=True, kw_only=True)
class Hose:
    """A hose; at ``compressible`` fidelity its volume joins the net its ends connect."""

    length: float = param("m", low=0.0, high=200.0)
    """Length [m]."""
    inner_diameter: float = param("m", low=0.0, high=0.5)
    """Inner diameter [m]."""
    wall_bulk_modulus: float = param("Pa", low=1e7, high=1e12, low_open=False, default=math.inf)
    """Wall compliance as a bulk modulus [Pa] (rubber hose ≈ 1e8–1e9); inf = rigid."""
    PORTS = ("a", "b")

    @property
    def volume(self) -> float:
        """Internal volume π·d²/4·L [m³]."""
        return math.pi * self.inner_diameter**2 / 4.0 * self.length


@dataclass(frozen=True, kw_only=True)
class Cylinder:
    """Double-acting differential cylinder; x = rod extension from fully retracted [m]."""

    bore: float = param("m", low=0.0, high=1.0)
    """Piston diameter [m]."""
    rod_diameter: float = param("m", low=0.0, high=1.0)
    """Rod diameter [m]; must be smaller than the bore."""
    stroke: float = param("m", low=0.0, high=20.0)
    """Stroke [m]."""
    dead_volume_cap: float = param("m^3", low=0.0, high=1.0, low_open=False, default=0.0)
    """Cap-side volume at x = 0 (ports, cushion) [m³]."""
    dead_volume_rod: float = param("m^3", low=0.0, high=1.0, low_open=False, default=0.0)
    """Rod-side volume at x = stroke [m³]."""
    coulomb_friction: float = param("N", low=0.0, high=1e7, low_open=False, default=0.0)
    """Coulomb (sliding) seal friction F_c [N]."""
    static_friction: float = param("N", low=0.0, high=1e7, low_open=False, default=None)
    """Breakaway friction F_s [N] (Stribeck peak); defaults to F_c."""
    stribeck_velocity: float = param("m/s", low=0.0, high=10.0, default=0.01)
    """Stribeck velocity v_s [m/s]."""
    viscous_friction: float = param("N*s/m", low=0.0, high=1e8, low_open=False, default=0.0)
    """Viscous friction coefficient b [N·s/m]."""
    leakage_conductance: float = param("m^3/(s*Pa)", low=0.0, high=1e-6, low_open=False, default=0.0)
    """Internal cap↔rod leakage conductance [m³/(s·Pa)]."""
    PORTS = ("cap", "rod")

    def __post_init__(self):
        if self.static_friction is None:
            object.__setattr__(self, "static_friction", self.coulomb_friction)

    @property
    def cap_area(self) -> float:
        """Piston area A_cap = π·D²/4 [m²]."""
        return math.pi * self.bore**2 / 4.0

    @property
    def rod_area(self) -> float:
        """Annulus area A_rod = π·(D² − d²)/4 [m²]."""
        return math.pi * (self.bore**2 - self.rod_diameter**2) / 4.0


@dataclass(frozen=True, kw_only=True)
class Motor:
    """Hydraulic motor: swallows Q = D·ω/(2π) from port a to b; torque τ = D·(p_a − p_b)/(2π)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Displacement D [m³/rev]."""
    leakage_conductance: float = param("m^3/(s*Pa)", low=0.0, high=1e-6, low_open=False, default=0.0)
    """Cross-port leakage conductance [m³/(s·Pa)]."""
    PORTS = ("a", "b")


@dataclass(frozen=True, kw_only=True)
class Accumulator:
    """Gas-charged accumulator (polytropic gas)."""

    gas_volume: float = param("m^3", low=0.0, high=10.0)
    """Gas volume at precharge V_0 [m³]."""
    precharge_pressure: float = param("Pa", low=0.0, high=1e9)
    """Precharge absolute pressure p_0 [Pa]."""
    polytropic_index: float = param("-", low=1.0, high=1.67, low_open=False, default=1.4)
    """Polytropic index n [-] (1 isothermal, 1.4 adiabatic)."""
    PORTS = ("port",)


COMPONENT_TYPES = {
    "tank": Tank,
    "pump_fixed": PumpFixed,
    "pump_compensated": PumpCompensated,
    "orifice": Orifice,
    "valve_4_3": Valve43,
    "relief_valve": ReliefValve,
    "check_valve": CheckValve,
    "volume": Volume,
    "hose": Hose,
    "cylinder": Cylinder,
    "motor": Motor,
    "accumulator": Accumulator,
}
"""Circuit-file ``type`` name → parameter class."""


def check_number(value, meta, where: str) -> float:
    """Validate one numeric value against a field's range; raise CircuitError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CircuitError(f"{where}: expected a number in {describe_range(meta)}, got {value!r}")
    try:
        value = float(value)
    except OverflowError:
        raise CircuitError(f"{where}: {value!r} is outside the allowed range {describe_range(meta)}") from None
    low, high = meta["low"], meta["high"]
    ok = math.isfinite(value) or (value == math.inf and high is not None and high >= 1e12)
    if ok and low is not None:
        ok = value > low if meta["low_open"] else value >= low
    if ok and high is not None and value != math.inf:
        ok = value <= high
    if not ok:
        hint = ""
        if high is not None and math.isfinite(value) and value > high and meta["unit"] in ("m", "m^2", "m^3"):
            hint = " (SI units: metres, not millimetres)"
        raise CircuitError(f"{where}: {value!r} is outside the allowed range {describe_range(meta)}{hint}")
    return value


def build_component(kind: str, table: dict, where: str):
    """Build and validate a component of type ``kind`` from a circuit-file table.

    ``where`` prefixes every error (e.g. ``"circuit.toml: component 'pump'"``).
    Keys ``name``, ``type`` and ``ports`` are handled by the caller.
    """
    cls = COMPONENT_TYPES[kind]
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise CircuitError(f"{where}: unknown field(s) {unknown} for type '{kind}'; allowed: {sorted(known)}")
    values = {}
    for name, f in known.items():
        meta = f.metadata
        if name not in table:
            if f.default is MISSING:
                raise CircuitError(f"{where}: missing field '{name}' ({describe_range(meta)})")
            continue
        value = table[name]
        if meta["choices"]:
            if value not in meta["choices"]:
                raise CircuitError(f"{where}, field '{name}': {value!r} is not {describe_range(meta)}")
            values[name] = value
        else:
            values[name] = check_number(value, meta, f"{where}, field '{name}'")
    component = cls(**values)
    if isinstance(component, Cylinder) and component.rod_diameter >= component.bore:
        raise CircuitError(
            f"{where}, field 'rod_diameter': {component.rod_diameter!r} m must be smaller than bore {component.bore!r} m"
        )
    if isinstance(component, CheckValve) and component.full_open_pressure <= component.cracking_pressure:
        raise CircuitError(f"{where}, field 'full_open_pressure': must exceed cracking_pressure")
    return component


