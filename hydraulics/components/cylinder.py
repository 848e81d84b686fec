"""Double-acting cylinder, differential or double-rod: chamber volumes, piston force, seal friction.

Piston areas: A_cap = π·(D² − d_c²)/4 on the cap side (d_c = ``cap_rod_diameter``: 0 for a differential
cylinder, the diameter of a through rod leaving by the cap end otherwise; d_c = d gives the double-rod,
equal-area cylinder) and A_rod = π·(D² − d²)/4 on the rod side.  With rod extension x [m] clipped to
[0, stroke] (the end stops belong to the mechanics):

* V_cap = V_dead,cap + A_cap·x, V_rod = V_dead,rod + A_rod·(stroke − x), with dV/dx zero outside the stroke
  (:func:`chamber_volumes`);
* F = p_cap·A_cap − p_rod·A_rod − p_amb·(A_cap − A_rod), absolute pressures, the rods' own cross-sections at
  ambient pressure (:func:`pressure_force`; 0 ambient term for a double-rod cylinder);
* F_f = [F_c + F_p + (F_s − F_c)·exp(−(v/v_s)²)]·tanh(v/v_reg) + b·v, the force on the rod being −F_f
  (:func:`friction_force_with_derivative`, v_reg = :data:`FRICTION_REGULARISATION_VELOCITY`), where the
  seal load F_p = k_p·(max(p_cap − p_amb, 0)·A_cap + max(p_rod − p_amb, 0)·A_rod) (:func:`seal_load`) raises
  the sliding and the breakaway friction alike with the gauge pressures on the seals (the pressure-dependent
  Coulomb friction of Simscape Fluids' cylinder friction block; breakaway F_s + F_p, sliding F_c + F_p);
* end cushions (:func:`cushion_force_with_derivative`): within ``cushion_length_cap`` L of x = 0 (of x = stroke
  for ``cushion_length_rod``) the closing chamber's outflow A·|v| leaves through the cushion orifice (flow area
  a_k, discharge coefficient C_d), quasi-steady and turbulent: Δp_k = (ρ/2)·(A·v/(C_d·a_k))², the force on the
  piston F_k = s(d)·Δp_k·A opposing the motion, s(d) = 3t² − 2t³, t = clip(d/(L/5), 0, 1), of the depth d into
  the cushion (the spear entering its bore over the first fifth: C¹ in x).  The returning stroke's inflow
  bypasses the cushion through its check valve (no force; ``cushion_return = "check"``) or passes the cushion
  orifice too (``"orifice"``: the same force against the return).  Limitations: the cushion's own oil volume is not a
  state (its compression time β-scale is taken as short against the deceleration); the chamber's net holds the
  port-side pressure, the cushion's Δp_k shows in the applied force (its difference to the pressure force);
* k = β·A²/V, the oil column of one chamber as a spring, and ω_h = sqrt(Σk/m), the actuator's hydraulic
  frequency on an inertia m (:func:`hydraulic_stiffness`, :func:`hydraulic_natural_frequency`).

Packing: the cylinder table (columns :data:`COLUMNS`, :func:`pack`) and its index table (actuator, cap node, rod
node; :data:`INDEX_COLUMNS`, :func:`pack_index`).

Example
-------
>>> chamber_volumes(0.5, 1.0, 2e-3, 1e-3, 0.0, 0.0)
(0.001, 0.0005, 0.002, -0.001)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import clip, kernel, maximum
from .parameters import CircuitError, param, table

# Regularisation velocity of Coulomb friction: tanh(v / v_reg) reaches 76 % of the Coulomb force at 1 mm/s,
# far below any operator-commanded rod speed.
FRICTION_REGULARISATION_VELOCITY = 1e-3  # [m/s]


@dataclass(frozen=True, kw_only=True)
class Cylinder:
    """Double-acting cylinder, differential or double-rod; x = rod extension from fully retracted [m]."""

    bore: float = param("m", low=0.0, high=1.0)
    """Piston diameter [m]."""
    rod_diameter: float = param("m", low=0.0, high=1.0)
    """Rod diameter [m]; must be smaller than the bore."""
    cap_rod_diameter: float = param("m", low=0.0, high=1.0, low_open=False, default=0.0)
    """Diameter of a through rod leaving by the cap end [m]: 0 for a differential cylinder, ``rod_diameter`` for
    a double-rod (equal-area) one; must be smaller than the bore."""
    stroke: float = param("m", low=0.01, high=20.0, low_open=False)
    """Stroke [m]; at least 10 mm (short-stroke clamping cylinders), well above the 1 mm the MJCF tendon range may
    differ from it and the end stops' tolerance, so that a zero-length cylinder is refused."""
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
    friction_pressure_coefficient: float = param("-", low=0.0, high=0.5, low_open=False, default=0.0)
    """Pressure dependence k_p [-] of the seal friction: the sliding and the breakaway friction grow by
    k_p·(p_cap·A_cap + p_rod·A_rod), gauge pressures (seal friction of the order of 1–5 % of the pressure force
    on the seals: k_p ≈ 0.01–0.05); 0 turns it off.  Not at the ``incompressible`` fidelity (no chamber
    pressures while the step is solved)."""
    leakage_conductance: float = param("m^3/(s*Pa)", low=0.0, high=1e-6, low_open=False, default=0.0)
    """Internal cap↔rod leakage conductance [m³/(s·Pa)]."""
    cushion_length_cap: float = param("m", low=0.0, high=20.0, low_open=False, default=0.0)
    """Cap-end cushion length L [m] (0: no cushion): within L of full retraction the cap chamber's outflow
    passes the cushion orifice; the two cushions together must fit in the stroke."""
    cushion_length_rod: float = param("m", low=0.0, high=20.0, low_open=False, default=0.0)
    """Rod-end cushion length L [m] (0: no cushion): within L of full extension the rod chamber's outflow passes
    the cushion orifice."""
    cushion_area_cap: float = param("m^2", low=0.0, high=1.0, default=1e-6)
    """Flow area a_k of the cap-end cushion orifice [m²] (read with a cap-end cushion only)."""
    cushion_area_rod: float = param("m^2", low=0.0, high=1.0, default=1e-6)
    """Flow area a_k of the rod-end cushion orifice [m²] (read with a rod-end cushion only)."""
    cushion_discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """Discharge coefficient C_d of the cushion orifices [-]."""
    cushion_return: str = param("-", default="check", choices=("check", "orifice"))
    """The return stroke's inflow into a cushioned chamber: ``check`` bypasses the cushion through a check valve
    (free return), ``orifice`` passes the cushion orifice too (the same force against the return)."""
    PORTS = ("cap", "rod")

    def __post_init__(self):
        if self.static_friction is None:
            object.__setattr__(self, "static_friction", self.coulomb_friction)

    def check(self, where: str) -> None:
        """Raise CircuitError (prefixed by ``where``) unless the rods are thinner than the bore."""
        for name in ("rod_diameter", "cap_rod_diameter"):
            if getattr(self, name) >= self.bore:
                raise CircuitError(
                    f"{where}, field '{name}': {getattr(self, name)!r} m must be smaller than bore {self.bore!r} m")
        if self.cushion_length_cap + self.cushion_length_rod > self.stroke:
            raise CircuitError(f"{where}, field 'cushion_length_rod': cushion_length_cap + cushion_length_rod = "
                               f"{self.cushion_length_cap + self.cushion_length_rod!r} m must not exceed stroke {self.stroke!r} m")

    @property
    def cap_area(self) -> float:
        """Cap-side piston area A_cap = π·(D² − d_c²)/4 [m²] (π·D²/4 without a cap-end rod)."""
        return math.pi * (self.bore**2 - self.cap_rod_diameter**2) / 4.0

    @property
    def rod_area(self) -> float:
        """Annulus area A_rod = π·(D² − d²)/4 [m²]."""
        return math.pi * (self.bore**2 - self.rod_diameter**2) / 4.0


@kernel
def chamber_volumes(x, stroke, cap_area, rod_area, dead_cap, dead_rod):
    """V_cap, V_rod [m³] and dV_cap/dx, dV_rod/dx [m²] at rod extension ``x`` [m]."""
    inside = 1.0 if (x > 0.0 and x < stroke) else 0.0
    xc = clip(x, 0.0, stroke)
    return dead_cap + cap_area * xc, dead_rod + rod_area * (stroke - xc), cap_area * inside, -rod_area * inside


@kernel
def pressure_force(cap_pressure, rod_pressure, cap_area, rod_area, ambient):
    """Piston force [N] (positive extends) from absolute pressures [Pa] and areas [m²]."""
    return cap_pressure * cap_area - rod_pressure * rod_area - ambient * (cap_area - rod_area)


@kernel
def seal_load(cap_pressure, rod_pressure, cap_area, rod_area, ambient, coefficient):
    """Pressure part F_p = k_p·(max(p_cap − p_amb, 0)·A_cap + max(p_rod − p_amb, 0)·A_rod) [N] of the seal
    friction at absolute chamber pressures [Pa], areas [m²], ambient pressure [Pa] and ``coefficient`` k_p [-];
    returns (F_p, ∂F_p/∂p_cap, ∂F_p/∂p_rod) [N, m², m²] (a chamber below ambient presses no seal: slope 0)."""
    gc = cap_pressure - ambient
    gr = rod_pressure - ambient
    dcap = coefficient * cap_area if gc > 0.0 else 0.0
    drod = coefficient * rod_area if gr > 0.0 else 0.0
    return dcap * gc + drod * gr, dcap, drod


@kernel
def friction_force_with_derivative(v, coulomb, static, stribeck_velocity, viscous, v_reg, load):
    """Seal friction F_f [N] (sign of v) at rod velocity ``v`` [m/s] with the seal load ``load`` F_p [N]
    (:func:`seal_load`; 0 without pressure dependence), dF_f/dv [N·s/m] and dF_f/dF_p [-]; ``v_reg`` [m/s]."""
    vs = maximum(stribeck_velocity, 1e-12)
    r = v / vs
    stribeck = math.exp(-(r * r))
    level = coulomb + load + (static - coulomb) * stribeck
    dlevel = (static - coulomb) * stribeck * (-2.0 * v / (vs * vs))
    th = math.tanh(v / v_reg)
    dth = (1.0 - th * th) / v_reg
    return level * th + viscous * v, dlevel * th + level * dth + viscous, th


def cushion_coefficient(area, discharge_coefficient, orifice_area, density):
    """K = ρ·A³/(2·(C_d·a_k)²) [N·s²/m²] of a cushion: its fully engaged force K·v² at rod speed v, piston area A
    [m²], discharge coefficient C_d [-], cushion orifice area a_k [m²], oil density ρ [kg/m³]."""
    return density * area**3 / (2.0 * (discharge_coefficient * orifice_area) ** 2)


@kernel
def cushion_engagement(depth, length):
    """s = 3t² − 2t³, t = clip(depth/(length/5), 0, 1) [-]: how far the cushion's restriction is engaged at the
    ``depth`` [m] into a cushion of ``length`` [m], and ds/d(depth) [1/m]."""
    width = 0.2 * length
    t = clip(depth / width, 0.0, 1.0)
    inside = 1.0 if (depth > 0.0 and depth < width) else 0.0
    return t * t * (3.0 - 2.0 * t), inside * 6.0 * t * (1.0 - t) / width


@kernel
def cushion_force_with_derivative(x, v, stroke, length_cap, k_cap, length_rod, k_rod, check):
    """End-cushion force F_k [N] (sign of v: opposing the motion, the force on the rod being −F_k) at rod extension
    ``x`` [m] and velocity ``v`` [m/s] and dF_k/dv [N·s/m]: s·K·v·|v| on the chamber that closes (the cap's when
    retracting within ``length_cap`` of x = 0, the rod's when extending within ``length_rod`` of the stroke),
    K = ``k_cap`` or ``k_rod`` [N·s²/m²] (:func:`cushion_coefficient`), s = :func:`cushion_engagement`; for the
    other direction zero with a ``check`` valve (1.0), the same law without one (0.0)."""
    f = 0.0
    df = 0.0
    if length_cap > 0.0 and (v < 0.0 or check == 0.0):
        s, _ = cushion_engagement(length_cap - x, length_cap)
        f += s * k_cap * v * abs(v)
        df += 2.0 * s * k_cap * abs(v)
    if length_rod > 0.0 and (v > 0.0 or check == 0.0):
        s, _ = cushion_engagement(x - (stroke - length_rod), length_rod)
        f += s * k_rod * v * abs(v)
        df += 2.0 * s * k_rod * abs(v)
    return f, df


@kernel
def hydraulic_stiffness(bulk_modulus, area, volume):
    """Oil-column spring stiffness k = β·A²/V [N/m] of one chamber: β [Pa], A [m²], V [m³] (a motor port: A → D/2π
    [m³/rad], k [N·m/rad])."""
    return bulk_modulus * area * area / volume


@kernel
def hydraulic_natural_frequency(stiffness, mass):
    """Merritt's hydraulic frequency ω_h = sqrt(k/m) [rad/s] of an actuator whose chambers sum to the stiffness
    ``stiffness`` k = Σ β·A²/V [N/m] (:func:`hydraulic_stiffness`) on the inertia ``mass`` [kg] (H. E. Merritt,
    *Hydraulic Control Systems*, 1967, §5.2: ω_h² = (β_c·A_c²/V_c + β_r·A_r²/V_r)/m)."""
    return math.sqrt(stiffness / mass)


COLUMNS = ("cap_area", "rod_area", "stroke", "dead_cap", "dead_rod", "coulomb", "static", "stribeck", "viscous",
           "pressure_friction", "cushion_cap", "cushion_k_cap", "cushion_rod", "cushion_k_rod", "cushion_check")
"""Cylinder table: areas [m²], stroke [m], dead volumes [m³], friction F_c, F_s [N], v_s [m/s], b [N·s/m], k_p [-],
cushion lengths [m] and coefficients K [N·s²/m²] (:func:`cushion_coefficient`) at the cap and the rod end, 1.0
for a check valve on the cushions' return (0.0: none)."""
(CYL_CAP_AREA, CYL_ROD_AREA, CYL_STROKE, CYL_DEAD_CAP, CYL_DEAD_ROD, CYL_COULOMB, CYL_STATIC, CYL_STRIBECK, CYL_VISCOUS,
 CYL_PRESSURE_FRICTION, CYL_CUSHION_CAP, CYL_CUSHION_K_CAP, CYL_CUSHION_ROD, CYL_CUSHION_K_ROD, CYL_CUSHION_CHECK) = \
    range(len(COLUMNS))
INDEX_COLUMNS = ("actuator", "cap", "rod")
"""Cylinder index table: actuator number, cap node, rod node."""
CI_ACT, CI_CAP, CI_ROD = range(len(INDEX_COLUMNS))


def pack(model) -> np.ndarray:
    """The cylinder table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`COLUMNS`."""
    m = model
    rho, cd = m.fluid.density, m.cylinder_cushion_cd
    return table(COLUMNS, len(m.cylinder_actuator), cap_area=m.cylinder_cap_area, rod_area=m.cylinder_rod_area,
                 stroke=m.cylinder_stroke, dead_cap=m.cylinder_dead_cap, dead_rod=m.cylinder_dead_rod,
                 coulomb=m.cylinder_coulomb, static=m.cylinder_static, stribeck=m.cylinder_stribeck,
                 viscous=m.cylinder_viscous, pressure_friction=m.cylinder_pressure_friction,
                 cushion_cap=m.cylinder_cushion_length_cap,
                 cushion_k_cap=cushion_coefficient(m.cylinder_cap_area, cd, m.cylinder_cushion_area_cap, rho),
                 cushion_rod=m.cylinder_cushion_length_rod,
                 cushion_k_rod=cushion_coefficient(m.cylinder_rod_area, cd, m.cylinder_cushion_area_rod, rho),
                 cushion_check=m.cylinder_cushion_check)


def pack_index(model) -> np.ndarray:
    """The cylinder index table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`INDEX_COLUMNS`."""
    count = len(model.cylinder_actuator)
    return np.column_stack([np.asarray(c, np.int64).reshape(count) for c in
                            (model.cylinder_actuator, model.cylinder_cap_node, model.cylinder_rod_node)])
