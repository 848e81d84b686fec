"""Component laws against hand-computed values, and analytic derivatives against finite differences."""

import math

import numpy as np
import pytest

from reference import laws
from hydraulics.fluid import Fluid

RHO = 870.0
NU = 4.6e-5


def central_difference(f, x, step):
    return (f(x + step) - f(x - step)) / (2 * step)


def test_orifice_turbulent_matches_seed_law():
    """Far above the transition, Q = Cd·A·sqrt(2Δp/ρ) (seed report's valve law)."""
    q, _ = laws.orifice_flow_with_derivative(1e-5, 0.7, 1e6, RHO, NU)
    hand = 0.7 * 1e-5 * math.sqrt(2 * 1e6 / 870.0)  # = 3.3562e-4 m^3/s
    assert q == pytest.approx(hand, rel=1e-4)
    q_rev, _ = laws.orifice_flow_with_derivative(1e-5, 0.7, -1e6, RHO, NU)
    assert q_rev == pytest.approx(-hand, rel=1e-4)


def test_orifice_laminar_slope_is_finite_at_zero():
    """At Δp = 0 the flow is 0 and the slope equals Cd·A·sqrt(2/(ρ·p_tr))."""
    area = 1e-6
    p_tr = laws.orifice_transition_pressure(area, 0.7, RHO, NU)
    q, g = laws.orifice_flow_with_derivative(area, 0.7, 0.0, RHO, NU)
    assert q == 0.0
    assert g == pytest.approx(0.7 * area * math.sqrt(2 / (RHO * p_tr)), rel=1e-12)
    # a closed orifice passes nothing and has zero slope
    assert laws.orifice_flow_with_derivative(0.0, 0.7, 1e6, RHO, NU) == (0.0, 0.0)


@pytest.mark.parametrize("dp", [-3e6, -1e3, 0.0, 5.0, 2e4, 1e7])
def test_orifice_derivatives(dp):
    area = 2e-6
    f = lambda x: laws.orifice_flow_with_derivative(area, 0.7, x, RHO, NU)[0]
    g = laws.orifice_flow_with_derivative(area, 0.7, dp, RHO, NU)[1]
    assert g == pytest.approx(central_difference(f, dp, 1e-3 * max(abs(dp), 1.0)), rel=1e-5)
    fa = lambda a: laws.orifice_flow_with_derivative(a, 0.7, dp, RHO, NU)[0]
    assert laws.orifice_flow_area_derivative(area, 0.7, dp, RHO, NU) == pytest.approx(
        central_difference(fa, area, 1e-9), rel=1e-5, abs=1e-12
    )


def test_relief_flow_and_derivative():
    """Q = G·(Δp − p_crack) above cracking plus the blend; zero below."""
    g, crack, width = 2e-10, 2e7, 2e4
    assert laws.relief_flow_with_derivative(1.9e7, crack, g, width)[0] == 0.0
    q, dq = laws.relief_flow_with_derivative(2.1e7, crack, g, width)
    assert q == pytest.approx(g * (1e6 - width / 2))
    assert dq == pytest.approx(g)
    f = lambda x: laws.relief_flow_with_derivative(x, crack, g, width)[0]
    for dp in (crack + 0.3 * width, crack + 5 * width):
        assert laws.relief_flow_with_derivative(dp, crack, g, width)[1] == pytest.approx(central_difference(f, dp, 1.0), rel=1e-6)


def test_check_valve_area():
    area, darea = laws.check_valve_area_with_derivative(np.array([-1e5, 5e4, 2e5]), 1e4, 1e5, 1e-4, 1e-9)
    assert area.tolist() == pytest.approx([1e-9, 1e-9 + 1e-4 * 4e4 / 9e4, 1e-9 + 1e-4])
    assert darea[1] == pytest.approx(1e-4 / 9e4)


def test_pump_and_motor_laws():
    """Seed report: Q = D·n and τ = D·Δp/(2π)."""
    assert laws.pump_flow(1e-5, 20.0) == pytest.approx(2e-4)
    assert laws.pump_flow(1e-5, 20.0, 0.95) == pytest.approx(1.9e-4)
    assert laws.pump_torque(1e-5, 2e7) == pytest.approx(1e-5 * 2e7 / (2 * math.pi))
    assert laws.motor_flow(1e-4, 2 * math.pi * 10) == pytest.approx(1e-3)
    d, dd = laws.compensated_displacement_with_derivative(1e-4, np.array([1e7, 2.05e7, 3e7]), 2e7, 1e6)
    assert d.tolist() == pytest.approx([1e-4, 0.5e-4, 0.0])
    assert dd[1] == pytest.approx(-1e-4 / 1e6)


def test_spool_step_is_exact_first_order_response():
    s = laws.spool_step(np.array([0.0]), np.array([1.0]), np.array([0.02]), 0.02)
    assert s[0] == pytest.approx(1 - math.exp(-1))
    assert laws.spool_step(np.array([0.3]), np.array([1.0]), np.array([0.0]), 1e-3)[0] == 1.0


def test_valve_openings():
    assert laws.metering_opening(np.array([0.0, 0.05, 0.525, 1.0, -1.0]), 0.05).tolist() == pytest.approx([0, 0, 0.5, 1, 0])
    assert laws.centre_opening(np.array([0.0, 0.05, 0.2]), 0.1).tolist() == pytest.approx([1.0, 0.5, 0.0])


def test_cylinder_geometry_and_force():
    a_cap, a_rod = math.pi * 0.05**2 / 4, math.pi * (0.05**2 - 0.028**2) / 4
    vc, vr, dvc, dvr = laws.chamber_volumes(0.1, 0.5, a_cap, a_rod, 2e-5, 3e-5)
    assert (vc, vr) == pytest.approx((2e-5 + a_cap * 0.1, 3e-5 + a_rod * 0.4))
    assert (dvc, dvr) == pytest.approx((a_cap, -a_rod))
    f = laws.cylinder_pressure_force(1e7, 2e6, a_cap, a_rod, 1e5)
    assert f == pytest.approx(1e7 * a_cap - 2e6 * a_rod - 1e5 * (a_cap - a_rod))


@pytest.mark.parametrize("v", [-0.2, -1e-3, 0.0, 2e-4, 0.005, 0.3])
def test_friction_derivative_and_limits(v):
    args = (500.0, 800.0, 0.01, 2000.0)
    f, df, _ = laws.friction_force_with_derivative(v, *args)
    assert df == pytest.approx(central_difference(lambda x: laws.friction_force_with_derivative(x, *args)[0], v, 1e-7), rel=1e-5)
    if abs(v) > 0.1:  # well past Stribeck: Coulomb + viscous
        assert f == pytest.approx(math.copysign(500.0, v) + 2000.0 * v, rel=1e-6)


def test_accumulator_and_wall():
    v0, p0, n = 1e-3, 5e6, 1.4
    liquid, dl = laws.accumulator_liquid_volume_with_derivative(np.array([4e6, 1e7]), v0, p0, n)
    assert liquid[0] == 0.0
    assert liquid[1] == pytest.approx(v0 * (1 - 0.5 ** (1 / n)))
    fd = central_difference(lambda p: laws.accumulator_liquid_volume_with_derivative(p, v0, p0, n)[0], 1e7, 10.0)
    assert dl[1] == pytest.approx(fd, rel=1e-6)
    ext, dext = laws.wall_expansion_with_derivative(1e7, 1e-3, 1e9, 1e5)
    assert ext == pytest.approx(1e-3 * 9.9e6 / 1e9) and dext == pytest.approx(1e-12)


def test_merritt_frequency_formula():
    w = laws.hydraulic_natural_frequency(100.0, 1.5e9, 2e-3, 1e-3, 1.5e9, 1e-3, 1e-3)
    assert w == pytest.approx(math.sqrt((1.5e9 * 4e-6 / 1e-3 + 1.5e9 * 1e-6 / 1e-3) / 100.0))


@pytest.mark.parametrize("air", [0.0, 0.01])
def test_fluid_fill_ratio_inverse_and_derivative(air):
    fluid = Fluid(air_fraction=air)
    p = np.array([5e3, 1e5, 1e6, 3e7])
    phi, dphi = fluid.fill_ratio(p)
    assert fluid.pressure_from_fill_ratio(phi) == pytest.approx(p, rel=1e-9)
    fd = np.array([central_difference(lambda x: fluid.fill_ratio(x)[0], x, 1e-4 * x) for x in p])
    assert dphi == pytest.approx(fd, rel=1e-6)
    beta = fluid.effective_bulk_modulus(p)
    if air == 0:
        assert beta == pytest.approx(np.full(4, 1.5e9))
    else:  # entrained air softens the oil at low pressure, dissolves in stiffness at high pressure
        assert beta[0] < 0.01 * 1.5e9 and beta[-1] > 0.5 * 1.5e9


def test_law_pieces_are_where_the_laws_change_slope():
    """ramp_piece / clip_piece name the piece of the C¹ ramp and of the unit clip: slope 0, in between, 1."""
    z = np.linspace(-2.0, 3.0, 501)
    _, slope = laws.smooth_ramp_with_derivative(z, 1.5)
    piece = laws.ramp_piece(z, 1.5)
    assert set(piece.tolist()) == {0, 1, 2}
    assert np.all(slope[piece == 0] == 0.0) and np.all(slope[piece == 2] == 1.0)
    assert np.all((slope[piece == 1] > 0.0) & (slope[piece == 1] < 1.0))
    _, dclip = laws.unit_clip_with_derivative(z)
    cpiece = laws.clip_piece(z)
    assert np.all(dclip[cpiece == 1] == 1.0) and np.all(dclip[cpiece != 1] == 0.0)
