"""Property tests: every compiled component law (``hydraulics/components/*``) against its independent numpy
formulation (``tests/reference/laws.py``, element-wise on arrays, the oracle), on random inputs.

The two are written differently (array ``np.where``/``np.clip`` against scalar branches; ``s**0.25`` and
``a**1.5`` against nested square roots; the orifice law from C_d, ρ, ν against its packed constants k, c), so
agreement to round-off checks each.  Tolerance: 1e-12 relative to the larger of the value and the scale of the
terms that cancel in it (a few ulp of pow against sqrt), zero slack on exact pieces (clips, ramps).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reference import laws
from hydraulics._compiled import fill_ratio_nb
from hydraulics.components import accumulator, check_valve, cylinder, motor, orifice, pumps, ramps, relief, valve_4_3
from hydraulics.fluid import Fluid

RTOL = 1e-12  # pow vs sqrt, exp/log of libm vs numpy: a few ulp
EXAMPLES = settings(max_examples=150, deadline=None)


def close(kernel, oracle, scale=0.0):
    """Each output of the kernel equals the oracle's to RTOL of max(|oracle|, ``scale``)."""
    assert len(kernel) == len(oracle)
    for k, o in zip(kernel, oracle):
        o = float(o)
        assert abs(k - o) <= RTOL * max(abs(o), scale), (kernel, oracle)


pressure = st.floats(-5e7, 5e7, allow_nan=False)
area = st.floats(0.0, 1e-3)
cd = st.floats(0.3, 1.0)
density = st.floats(700.0, 1100.0)
viscosity = st.floats(5e-6, 5e-4)


@EXAMPLES
@given(area, cd, pressure, density, viscosity)
def test_orifice(a, discharge, dp, rho, nu):
    """Orifice flow, dQ/dΔp and ∂Q/∂A."""
    k, c = orifice.coefficients(discharge, rho, nu)
    q, g = orifice.flow_with_derivative(a, float(k), float(c), dp)
    close((q, g), laws.orifice_flow_with_derivative(a, discharge, dp, rho, nu))
    close((orifice.flow_area_derivative(a, float(k), float(c), dp),),
          (laws.orifice_flow_area_derivative(a, discharge, dp, rho, nu),))


@EXAMPLES
@given(pressure, st.floats(1e5, 4e7), st.floats(1e-13, 1e-8), st.floats(1e-4, 1e-2))
def test_relief(dp, cracking, gradient, relative_width):
    """Relief flow with its C¹ blend, on every piece."""
    width = relative_width * cracking
    close(relief.flow_with_derivative(dp, cracking, gradient, width),
          laws.relief_flow_with_derivative(dp, cracking, gradient, width), scale=gradient * abs(dp - cracking))


@EXAMPLES
@given(pressure, st.floats(0.0, 1e6), st.floats(1e3, 1e6), area, st.floats(0.0, 1e-6), cd)
def test_check_valve(dp, cracking, span, max_area, leakage, discharge):
    """Check-valve area law, and its flow with the total derivative dQ/dΔp = ∂Q/∂Δp + ∂Q/∂A·dA/dΔp."""
    full = cracking + span
    close(check_valve.area_with_derivative(dp, cracking, full, max_area, leakage),
          laws.check_valve_area_with_derivative(dp, cracking, full, max_area, leakage), scale=max_area)
    fluid = Fluid()
    k, c = orifice.coefficients(discharge, fluid.density, fluid.kinematic_viscosity)
    a, da = laws.check_valve_area_with_derivative(dp, cracking, full, max_area, leakage)
    q, g = laws.orifice_flow_with_derivative(a, discharge, dp, fluid.density, fluid.kinematic_viscosity)
    g = g + laws.orifice_flow_area_derivative(a, discharge, dp, fluid.density, fluid.kinematic_viscosity) * da
    kernel = check_valve.flow_with_derivative(dp, cracking, full, max_area, leakage, float(k), float(c))
    close(kernel, (q, g), scale=abs(g - laws.orifice_flow_with_derivative(a, discharge, dp, fluid.density,
                                                                         fluid.kinematic_viscosity)[1]))


@EXAMPLES
@given(st.floats(0.0, 1e-3), st.floats(0.0, 5e7), st.floats(1e6, 4e7), st.floats(1e4, 5e6), st.floats(0.0, 200.0),
       st.floats(0.5, 1.0), pressure)
def test_pumps_and_motor(displacement, outlet, compensator, band, speed, efficiency, dp):
    """Compensated displacement, delivery, torque, motor flow."""
    close(pumps.compensated_displacement_with_derivative(displacement, outlet, compensator, band),
          laws.compensated_displacement_with_derivative(displacement, outlet, compensator, band), scale=displacement)
    close((pumps.flow(displacement, speed, efficiency),), (laws.pump_flow(displacement, speed, efficiency),))
    close((pumps.torque(displacement, dp),), (laws.pump_torque(displacement, dp),))
    close((motor.flow(displacement, speed),), (laws.motor_flow(displacement, speed),))


@EXAMPLES
@given(st.floats(-0.5, 3.0), st.floats(0.1, 2.0), st.floats(1e-4, 1e-1), st.floats(0.1, 0.9), st.floats(0.0, 1e-3),
       st.floats(0.0, 1e-3))
def test_chamber_volumes(x, stroke, cap_area, rod_fraction, dead_cap, dead_rod):
    """Chamber volumes and their position derivatives, inside and outside the stroke."""
    rod_area = rod_fraction * cap_area
    close(cylinder.chamber_volumes(x, stroke, cap_area, rod_area, dead_cap, dead_rod),
          laws.chamber_volumes(x, stroke, cap_area, rod_area, dead_cap, dead_rod), scale=cap_area * stroke)


@EXAMPLES
@given(pressure, pressure, st.floats(1e-4, 1e-1), st.floats(0.1, 0.9), st.floats(0.0, 2e5))
def test_pressure_force(p_cap, p_rod, cap_area, rod_fraction, ambient):
    """Piston force from absolute pressures (terms cancel: scale of the largest term)."""
    rod_area = rod_fraction * cap_area
    scale = max(abs(p_cap) * cap_area, abs(p_rod) * rod_area, ambient * cap_area)
    close((cylinder.pressure_force(p_cap, p_rod, cap_area, rod_area, ambient),),
          (laws.cylinder_pressure_force(p_cap, p_rod, cap_area, rod_area, ambient),), scale=scale)


@EXAMPLES
@given(st.floats(1e7, 3e9), st.floats(1e-5, 1e-1), st.floats(1e-6, 1e-1), st.floats(1e-5, 1e-1), st.floats(1e-6, 1e-1),
       st.floats(1e-3, 1e5))
def test_hydraulic_stiffness_and_frequency(beta, cap_area, cap_volume, rod_area, rod_volume, mass):
    """Oil-column stiffness β·A²/V of a chamber and Merritt's frequency sqrt(Σk/m) of an actuator."""
    k_cap = cylinder.hydraulic_stiffness(beta, cap_area, cap_volume)
    k_rod = cylinder.hydraulic_stiffness(beta, rod_area, rod_volume)
    close((k_cap,), (laws.hydraulic_stiffness(beta, cap_area, cap_volume),))
    close((cylinder.hydraulic_natural_frequency(k_cap + k_rod, mass),),
          (laws.hydraulic_natural_frequency(mass, beta, cap_area, cap_volume, beta, rod_area, rod_volume),))


@EXAMPLES
@given(st.floats(-2.0, 2.0), st.floats(0.0, 1e5), st.floats(0.0, 2.0), st.floats(1e-4, 0.5), st.floats(0.0, 1e5),
       st.floats(0.0, 1e5))
def test_friction(v, coulomb, static_ratio, stribeck, viscous, seal):
    """Stribeck–Coulomb–viscous friction with a seal load, its velocity and seal-load derivatives."""
    static = coulomb * static_ratio
    oracle = laws.friction_force_with_derivative(v, coulomb, static, stribeck, viscous, seal)
    kernel = cylinder.friction_force_with_derivative(v, coulomb, static, stribeck, viscous,
                                                     cylinder.FRICTION_REGULARISATION_VELOCITY, seal)
    scale = max(coulomb, static) + seal + viscous * abs(v)
    close(kernel[:1], oracle[:1], scale=scale)
    close(kernel[1:2], oracle[1:2], scale=(max(coulomb, static) + seal) / cylinder.FRICTION_REGULARISATION_VELOCITY + viscous)
    close(kernel[2:], oracle[2:], scale=1.0)


@EXAMPLES
@given(st.floats(0.0, 5e7), st.floats(0.0, 5e7), st.floats(1e-4, 0.1), st.floats(1e-4, 0.1), st.floats(0.0, 0.5))
def test_seal_load(p_cap, p_rod, cap_area, rod_area, coefficient):
    """Pressure part of the seal friction and its pressure slopes (absolute pressures around 1 bar ambient)."""
    kernel = cylinder.seal_load(p_cap, p_rod, cap_area, rod_area, 1e5, coefficient)
    close(kernel[:1], (laws.seal_load(p_cap, p_rod, cap_area, rod_area, 1e5, coefficient),), scale=5e6)
    close(kernel[1:], (coefficient * cap_area * (p_cap > 1e5), coefficient * rod_area * (p_rod > 1e5)), scale=0.1)


@EXAMPLES
@given(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.one_of(st.just(0.0), st.floats(1e-6, 0.2)), st.floats(1e-5, 0.1),
       st.floats(0.0, 0.5))
def test_valve(spool, command, tau, dt, overlap):
    """Spool step, metering and centre openings."""
    close((valve_4_3.spool_step(spool, command, tau, dt),), (laws.spool_step(spool, command, tau, dt),), scale=1.0)
    close((valve_4_3.metering_opening(spool, overlap),), (laws.metering_opening(spool, overlap),), scale=1.0)
    close((valve_4_3.centre_opening(spool, overlap),), (laws.centre_opening(spool, overlap),), scale=1.0)


@EXAMPLES
@given(st.floats(0.0, 5e7), st.floats(1e-5, 1.0), st.floats(1e5, 3e7), st.floats(1.0, 1.67))
def test_accumulator(p, gas, precharge, index):
    """Polytropic accumulator liquid volume and its pressure derivative."""
    close(accumulator.liquid_volume_with_derivative(p, gas, precharge, index),
          laws.accumulator_liquid_volume_with_derivative(p, gas, precharge, index), scale=gas / max(p, precharge))


@EXAMPLES
@given(st.floats(-10.0, 10.0), st.floats(1e-3, 5.0))
def test_ramps(z, width):
    """Smooth ramp, unit clip and their piece numbers: exact (no rounding difference allowed)."""
    assert ramps.smooth_ramp_with_derivative(z, width) == tuple(map(float, laws.smooth_ramp_with_derivative(z, width)))
    assert ramps.unit_clip_with_derivative(z) == tuple(map(float, laws.unit_clip_with_derivative(z)))
    assert ramps.ramp_piece(z, width) == int(laws.ramp_piece(z, width))


@EXAMPLES
@given(st.floats(1e3, 5e7), st.floats(0.0, 0.1), st.floats(1.0, 1.4), st.floats(1e9, 2e9))
def test_fill_ratio(p, air, index, beta):
    """Fluid fill ratio φ(p) and dφ/dp, with and without entrained air."""
    fluid = Fluid(bulk_modulus=beta, air_fraction=air, polytropic_index=index)
    phi, dphi = fluid.fill_ratio(p)
    close(fill_ratio_nb(p, fluid.reference_pressure, beta, air, index), (phi, dphi))


@EXAMPLES
@given(st.sampled_from([-1.0, 0.0, 1.0]), st.floats(1e-4, 1e-1), st.floats(1e-4, 1e-1), st.floats(0.0, 1e-4),
       st.floats(0.0, 1e-4), st.floats(1e5, 4e7), st.floats(0.0, 1e6), density, st.floats(0.0, 2e5))
def test_metered_actuator_force(direction, area_in, area_out, orifice_in, orifice_out, supply, tank, rho, ambient):
    """Rigid-oil force of a valve-metered actuator: drive force and velocity-squared resistance (inf when shut)."""
    kernel = valve_4_3.metered_actuator_force(direction, area_in, area_out, orifice_in, orifice_out, supply, tank, rho, ambient)
    with np.errstate(divide="ignore"):
        oracle = laws.metered_actuator_force(direction, area_in, area_out, np.float64(orifice_in), np.float64(orifice_out),
                                             supply, tank, rho, ambient)
    close(kernel[:1], oracle[:1], scale=max(supply, tank, ambient) * max(area_in, area_out))
    if np.isfinite(oracle[1]):
        assert kernel[1] == pytest.approx(float(oracle[1]), rel=RTOL)
    else:
        assert kernel[1] == math.inf and oracle[1] == math.inf


def test_oracles_are_independent_formulations():
    """The oracle is not the kernel: the numpy laws are array functions, the kernels scalar compiled ones."""
    x = np.linspace(-1.0, 1.0, 5)
    assert laws.metering_opening(x, 0.05).shape == (5,)
    with pytest.raises(Exception):
        valve_4_3.metering_opening(x, 0.05)  # a scalar law: arrays are not its domain
