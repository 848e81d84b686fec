"""Constitutive laws of hydraulic components in numpy, element-wise on arrays: the oracle of the compiled scalar
laws of :mod:`hydraulics.components`.

Every function takes and returns SI quantities (Pa, m³/s, m, m², N, s).  Functions named ``*_with_derivative``
return the value and its analytic derivative with respect to the pressure (difference) they depend on.  The
property tests (``tests/test_law_oracles.py``, ``tests/test_network_oracle.py``) compare the compiled laws with
these on random inputs; the package itself never imports this module.

References: H. E. Merritt, *Hydraulic Control Systems*, Wiley 1967 (orifice §2.4, valve-controlled actuator and
hydraulic frequency §5.2); the seed report (*hydraulic-pbd-report*) where a docstring says so.

Example
-------
>>> float(pump_flow(1e-5, 20.0))
0.0002
"""

from __future__ import annotations

import math

import numpy as np

from hydraulics.components.cylinder import FRICTION_REGULARISATION_VELOCITY  # noqa: F401  (m/s, the friction law's)
from hydraulics.components.orifice import CRITICAL_REYNOLDS as ORIFICE_CRITICAL_REYNOLDS
from hydraulics.components.orifice import coefficients as orifice_coefficients


TEXTBOOK_CRITICAL_REYNOLDS = 150.0
"""The orifice law's critical Reynolds number as Merritt gives it (§2.4), kept apart from the package's constant so the
textbook form checks it."""


def orifice_textbook(area, cd, dp, fluid):
    """Q [m³/s] of the laminar–turbulent orifice law in its textbook form (Merritt §2.4), scalar: area [m²], discharge
    coefficient cd [-], pressure drop dp [Pa] in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
    if area == 0.0:
        return 0.0
    hydraulic_diameter = math.sqrt(4.0 * area / math.pi)
    p_tr = 0.5 * fluid.density * (TEXTBOOK_CRITICAL_REYNOLDS * fluid.kinematic_viscosity / (cd * hydraulic_diameter)) ** 2
    return cd * area * math.sqrt(2.0 / fluid.density) * dp / (dp * dp + p_tr * p_tr) ** 0.25


# --------------------------------------------------------------------------
# Smooth switching helpers
# --------------------------------------------------------------------------
def smooth_ramp_with_derivative(z, width):
    """C¹ ramp: 0 for z ≤ 0, z²/(2w) for 0 < z < w, z − w/2 for z ≥ w.

    Used for relief and check valve opening so that Newton's method sees a
    continuous slope at the cracking point.  ``width`` [same unit as z] > 0.
    """
    z = np.asarray(z, dtype=float)
    w = np.asarray(width, dtype=float)
    inside = (z > 0.0) & (z < w)
    above = z >= w
    value = np.where(above, z - 0.5 * w, np.where(inside, z * z / (2.0 * w), 0.0))
    slope = np.where(above, 1.0, np.where(inside, z / w, 0.0))
    return value, slope


def ramp_piece(z, width):
    """Which piece of :func:`smooth_ramp_with_derivative` ``z`` lies on: 0 (z ≤ 0), 1 (0 < z < w), 2 (z ≥ w)."""
    z = np.asarray(z, dtype=float)
    return np.where(z >= width, 2, np.where(z > 0.0, 1, 0))


def clip_piece(z):
    """Which piece of :func:`unit_clip_with_derivative` ``z`` lies on: 0 (z ≤ 0), 1 (0 < z < 1), 2 (z ≥ 1)."""
    return ramp_piece(z, 1.0)


def unit_clip_with_derivative(z):
    """Clip to [0, 1] with the derivative (1 inside, 0 outside)."""
    z = np.asarray(z, dtype=float)
    inside = (z > 0.0) & (z < 1.0)
    return np.clip(z, 0.0, 1.0), inside.astype(float)


# --------------------------------------------------------------------------
# Orifice (turbulent with a laminar region)
# --------------------------------------------------------------------------
def orifice_transition_pressure(area, discharge_coefficient, density, kinematic_viscosity):
    """Pressure drop [Pa] at which the orifice law turns from laminar to turbulent.

    p_tr = (ρ/2)·(Re_c·ν / (C_d·D_h))², with the hydraulic diameter
    D_h = sqrt(4A/π) and Re_c = ``ORIFICE_CRITICAL_REYNOLDS``.  Infinite for a
    closed orifice (A = 0), where the law gives zero flow.
    """
    area = np.asarray(area, dtype=float)
    with np.errstate(divide="ignore"):
        hydraulic_diameter_sq = 4.0 * area / np.pi
        return 0.5 * density * (ORIFICE_CRITICAL_REYNOLDS * kinematic_viscosity) ** 2 / (
            discharge_coefficient**2 * hydraulic_diameter_sq
        )


def orifice_flow_with_derivative(area, discharge_coefficient, delta_p, density, kinematic_viscosity):
    """Orifice flow Q [m³/s] from the upstream to the downstream side and dQ/dΔp.

    The seed report's directional-valve law Q = C_d·A·sqrt(2Δp/ρ) holds for
    |Δp| ≫ p_tr.  Near Δp = 0 it is blended into a laminar (linear) law by the
    rule

        Q = C_d·A·sqrt(2/ρ) · Δp / (Δp² + p_tr²)^(1/4),

    with p_tr from :func:`orifice_transition_pressure`; Q and dQ/dΔp stay finite
    everywhere (at Δp = 0 the slope is C_d·A·sqrt(2/(ρ·p_tr))).

    Parameters
    ----------
    area : array_like
        Open area [m²], ≥ 0.
    discharge_coefficient : array_like
        C_d [-].
    delta_p : array_like
        Upstream minus downstream pressure [Pa].
    density : float
        ρ [kg/m³].
    kinematic_viscosity : float
        ν [m²/s].

    Returns
    -------
    flow, dflow_ddelta_p : ndarray
        [m³/s] and [m³/(s·Pa)].
    """
    area = np.asarray(area, dtype=float)
    delta_p = np.asarray(delta_p, dtype=float)
    # Written with A^(3/2) so that A = 0 gives exactly zero flow and slope:
    # Q = Cd·sqrt(2/ρ)·Δp·A^{3/2} / (A²Δp² + c²)^{1/4}, c = p_tr·A.
    k, c = orifice_coefficients(discharge_coefficient, density, kinematic_viscosity)
    a_dp_sq = (area * delta_p) ** 2
    s = a_dp_sq + c * c
    root4 = s**0.25
    a32 = area**1.5
    flow = k * delta_p * a32 / root4
    slope = k * a32 * (0.5 * a_dp_sq + c * c) / (s * root4)
    return flow, slope


def orifice_flow_area_derivative(area, discharge_coefficient, delta_p, density, kinematic_viscosity):
    """∂Q/∂A [m/s] of :func:`orifice_flow_with_derivative` (for pressure-opened valves)."""
    area = np.asarray(area, dtype=float)
    delta_p = np.asarray(delta_p, dtype=float)
    k, c = orifice_coefficients(discharge_coefficient, density, kinematic_viscosity)
    a_dp_sq = (area * delta_p) ** 2
    s = a_dp_sq + c * c
    return k * delta_p * np.sqrt(area) * (a_dp_sq + 1.5 * c * c) / (s * s**0.25)


def orifice_area_for_flow(flow, delta_p, discharge_coefficient, density):
    """Turbulent area [m²] passing ``flow`` [m³/s] at ``delta_p`` [Pa]: A = Q/(C_d·sqrt(2Δp/ρ))."""
    return flow / (discharge_coefficient * np.sqrt(2.0 * delta_p / density))


# --------------------------------------------------------------------------
# Valves
# --------------------------------------------------------------------------
def spool_step(spool, command, time_constant, dt):
    """First-order spool dynamics τ·ds/dt = u − s advanced exactly over ``dt`` [s].

    s(t+dt) = u + (s − u)·exp(−dt/τ); exact for a command held over the step, so
    the spool never limits the step size.  ``time_constant`` = 0 means an ideal
    spool (s = u).
    """
    tau = np.asarray(time_constant, dtype=float)
    with np.errstate(divide="ignore"):
        decay = np.where(tau > 0.0, np.exp(-dt / np.where(tau > 0.0, tau, 1.0)), 0.0)
    return command + (spool - command) * decay


def metering_opening(spool, overlap):
    """Opening fraction [0, 1] of a metering edge that opens for positive spool.

    Zero inside the overlap (dead band) |s| ≤ ε, then linear to fully open at
    s = 1: y = clip((s − ε)/(1 − ε), 0, 1).
    """
    return np.clip((np.asarray(spool, dtype=float) - overlap) / (1.0 - overlap), 0.0, 1.0)


def centre_opening(spool, overlap):
    """Opening fraction of an open/tandem centre passage: 1 at s = 0, closed at |s| ≥ max(ε, 0.1)."""
    closing = np.maximum(overlap, 0.1)
    return np.clip(1.0 - np.abs(np.asarray(spool, dtype=float)) / closing, 0.0, 1.0)


def relief_flow_with_derivative(delta_p, cracking_pressure, gradient, regularisation_width):
    """Pressure-relief flow Q = G·(Δp − p_crack) above cracking, 0 below (C¹-smoothed).

    Parameters: ``delta_p`` inlet − outlet [Pa], ``cracking_pressure`` [Pa],
    ``gradient`` G [m³/(s·Pa)], ``regularisation_width`` [Pa] of the quadratic
    blend at the cracking point.  Returns Q [m³/s] and dQ/dΔp.
    """
    ramp, slope = smooth_ramp_with_derivative(np.asarray(delta_p) - cracking_pressure, regularisation_width)
    return gradient * ramp, gradient * slope


def check_valve_area_with_derivative(delta_p, cracking_pressure, full_open_pressure, max_area, leakage_area):
    """Open area [m²] of a check valve: linear from cracking to full opening, and dA/dΔp."""
    span = full_open_pressure - cracking_pressure
    frac, dfrac = unit_clip_with_derivative((np.asarray(delta_p) - cracking_pressure) / span)
    return leakage_area + max_area * frac, max_area * dfrac / span


# --------------------------------------------------------------------------
# Pumps and motors (seed report: Q = D·n, τ = D·Δp/(2π))
# --------------------------------------------------------------------------
def pump_flow(displacement, speed, volumetric_efficiency=1.0):
    """Fixed-displacement pump delivery Q = η_v·D·n [m³/s]; D [m³/rev], n [rev/s]."""
    return volumetric_efficiency * displacement * speed


def pump_torque(displacement, delta_p):
    """Ideal pump (or motor) shaft torque τ = D·Δp/(2π) [N·m]; D [m³/rev], Δp [Pa]."""
    return displacement * delta_p / (2.0 * np.pi)


def compensated_displacement_with_derivative(max_displacement, outlet_pressure, compensator_pressure, band):
    """Pressure-compensated pump displacement [m³/rev] and dD/dp_out.

    Full displacement below ``compensator_pressure``, falling linearly to zero
    over ``band`` [Pa] above it.
    """
    frac, dfrac = unit_clip_with_derivative((compensator_pressure + band - np.asarray(outlet_pressure)) / band)
    return max_displacement * frac, -max_displacement * dfrac / band


def motor_flow(displacement, shaft_speed):
    """Flow [m³/s] swallowed by a hydraulic motor: Q = D·ω/(2π); ω [rad/s], D [m³/rev]."""
    return displacement * shaft_speed / (2.0 * np.pi)


# --------------------------------------------------------------------------
# Cylinders
# --------------------------------------------------------------------------
def chamber_volumes(position, stroke, cap_area, rod_area, dead_volume_cap, dead_volume_rod):
    """Cap and rod chamber volumes [m³] at rod extension ``position`` [m].

    V_cap = V_dead,cap + A_cap·x and V_rod = V_dead,rod + A_rod·(stroke − x),
    with x clipped to [0, stroke] (the end stops belong to the mechanics).
    Also returns dV_cap/dx and dV_rod/dx [m²] (zero outside the stroke).
    """
    x = np.asarray(position, dtype=float)
    inside = ((x > 0.0) & (x < stroke)).astype(float)
    xc = np.clip(x, 0.0, stroke)
    return (
        dead_volume_cap + cap_area * xc,
        dead_volume_rod + rod_area * (stroke - xc),
        cap_area * inside,
        -rod_area * inside,
    )


def cylinder_pressure_force(cap_pressure, rod_pressure, cap_area, rod_area, ambient_pressure):
    """Piston force [N] (positive extends): F = p_cap·A_cap − p_rod·A_rod − p_amb·(A_cap − A_rod).

    Pressures are absolute; the rod's own cross-section sees the ambient pressure.
    """
    return cap_pressure * cap_area - rod_pressure * rod_area - ambient_pressure * (cap_area - rod_area)


def seal_load(cap_pressure, rod_pressure, cap_area, rod_area, ambient_pressure, coefficient):
    """Pressure part of the seal friction [N]: F_p = k_p·(max(p_cap − p_amb, 0)·A_cap + max(p_rod − p_amb, 0)·A_rod)."""
    return coefficient * (max(cap_pressure - ambient_pressure, 0.0) * cap_area
                          + max(rod_pressure - ambient_pressure, 0.0) * rod_area)


def cushion_force(x, v, stroke, cap_area, rod_area, length_cap, length_rod, orifice_cap, orifice_rod, cd, density,
                  check=True):
    """End-cushion force [N] opposing motion (sign of v): the closing chamber's outflow A·|v| through the cushion
    orifice, Δp = (ρ/2)·(A·v/(C_d·a))², force s·Δp·A with the engagement s = smoothstep of the depth into the
    cushion over its first fifth; no force on the returning stroke with a ``check`` valve, the same law without."""
    def engagement(depth, length):
        t = min(max(depth / (0.2 * length), 0.0), 1.0)
        return t * t * (3.0 - 2.0 * t)

    force = 0.0
    if length_cap > 0.0 and (v < 0.0 or not check):
        dp = 0.5 * density * (cap_area * v / (cd * orifice_cap)) ** 2
        force += math.copysign(engagement(length_cap - x, length_cap) * dp * cap_area, v)
    if length_rod > 0.0 and (v > 0.0 or not check):
        dp = 0.5 * density * (rod_area * v / (cd * orifice_rod)) ** 2
        force += math.copysign(engagement(x - (stroke - length_rod), length_rod) * dp * rod_area, v)
    return force


def friction_force_with_derivative(velocity, coulomb, static, stribeck_velocity, viscous, seal=0.0):
    """Seal friction [N] opposing motion, its derivative with respect to velocity and to the seal load.

    F_f = [F_c + F_p + (F_s − F_c)·exp(−(v/v_s)²)]·tanh(v/v_reg) + b·v, with
    v_reg = ``FRICTION_REGULARISATION_VELOCITY`` and the seal load F_p = ``seal`` [N].  F_s = F_c turns
    the Stribeck term off.  The sign is that of v: the force on the rod is −F_f; ∂F_f/∂F_p = tanh(v/v_reg).
    """
    v = np.asarray(velocity, dtype=float)
    vs = np.maximum(stribeck_velocity, 1e-12)
    stribeck = np.exp(-((v / vs) ** 2))
    level = coulomb + seal + (static - coulomb) * stribeck
    dlevel = (static - coulomb) * stribeck * (-2.0 * v / vs**2)
    th = np.tanh(v / FRICTION_REGULARISATION_VELOCITY)
    dth = (1.0 - th * th) / FRICTION_REGULARISATION_VELOCITY
    return level * th + viscous * v, dlevel * th + level * dth + viscous, th


def metered_actuator_force(direction, area_in, area_out, orifice_in, orifice_out, supply_pressure, tank_pressure, density,
                           ambient_pressure):
    """Valve-metered actuator with rigid oil (Merritt §5.2, quasi-static): F(v) = F_d − R·v·|v| [N or N·m].

    With the metering edges P → inlet chamber (effective area ``orifice_in`` = C_d·a_in [m²]) and outlet
    chamber → T (``orifice_out``), piston areas A_in, A_out [m²] (D/2π [m³/rad] for a motor) of the
    commanded ``direction`` (+1 extending: A_in = A_cap; −1 retracting: A_in = A_rod), and the
    ambient pressure p_a on the rod side of the piston (as :func:`cylinder_pressure_force`):

        F_d = direction·((p_s − p_a)·A_in − (p_t − p_a)·A_out),
        R = (ρ/2)·(A_in³/(C_d·a_in)² + A_out³/(C_d·a_out)²).

    Returns (F_d [N], R [N·s²/m²]); R is inf where an edge is shut.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        resistance = 0.5 * density * (area_in**3 / orifice_in**2 + area_out**3 / orifice_out**2)
    return direction * ((supply_pressure - ambient_pressure) * area_in - (tank_pressure - ambient_pressure) * area_out), resistance


def line_conductance(inner_diameter, length, dynamic_viscosity):
    """Hagen–Poiseuille conductance of a pipe, G = π·d⁴/(128·μ·L) [m³/(s·Pa)]; d, L [m], μ [Pa·s]."""
    return np.pi * np.asarray(inner_diameter, dtype=float) ** 4 / (128.0 * dynamic_viscosity * length)


def hydraulic_stiffness(bulk_modulus, area, volume):
    """Oil-column spring stiffness k = β·A²/V [N/m] of one chamber."""
    return bulk_modulus * area**2 / volume


def hydraulic_natural_frequency(mass, bulk_modulus_cap, cap_area, cap_volume, bulk_modulus_rod, rod_area, rod_volume):
    """Merritt's hydraulic frequency ω_h [rad/s]: ω_h² = (1/m)·(β_c·A_c²/V_c + β_r·A_r²/V_r)."""
    return np.sqrt(
        (hydraulic_stiffness(bulk_modulus_cap, cap_area, cap_volume) + hydraulic_stiffness(bulk_modulus_rod, rod_area, rod_volume))
        / mass
    )


# --------------------------------------------------------------------------
# Accumulator and hose compliance
# --------------------------------------------------------------------------
def accumulator_liquid_volume_with_derivative(pressure, gas_volume, precharge_pressure, polytropic_index):
    """Liquid volume [m³] in a gas accumulator and its derivative [m³/Pa].

    Polytropic gas: p·V_g^n = p_0·V_0^n, so V_liquid = V_0·(1 − (p_0/p)^(1/n))
    above the precharge p_0 and zero below (the bladder rests on its seat).
    """
    p = np.maximum(np.asarray(pressure, dtype=float), precharge_pressure)
    ratio = (precharge_pressure / p) ** (1.0 / polytropic_index)
    charged = np.asarray(pressure) > precharge_pressure
    volume = np.where(charged, gas_volume * (1.0 - ratio), 0.0)
    slope = np.where(charged, gas_volume * ratio / (polytropic_index * p), 0.0)
    return volume, slope


def wall_expansion_with_derivative(pressure, volume, wall_bulk_modulus, reference_pressure):
    """Extra volume [m³] of an elastic hose wall: ΔV = V·(p − p_ref)/β_wall, and dΔV/dp."""
    slope = np.asarray(volume, dtype=float) / wall_bulk_modulus
    return slope * (np.asarray(pressure) - reference_pressure), slope
