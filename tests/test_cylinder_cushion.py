"""End cushions of the cylinder (``cushion_length_cap``/``_rod``, ``cushion_area_cap``/``_rod``).

Within the cushion length of an end the closing chamber's outflow A·|v| passes the cushion orifice a_k:
Δp_k = (ρ/2)·(A·v/(C_d·a_k))², a force Δp_k·A against the motion (quasi-steady), engaged C¹ over the cushion's
first fifth; the returning stroke bypasses it (check valve) or, with ``cushion_return = "orifice"``, meets it too.

* The law: the network's effort equals the oracle's at both ends, none on the return stroke (but without the check
  valve), none outside the cushion, the full Δp_k·A inside it; the slope is its velocity derivative.
* Into the end (scenario, both modes): a 200 kg load on a vertical slide lowers itself on its 50 mm cylinder, the
  cap's oil leaving through a 3 mm² orifice to the tank (rod side on the tank), into a 30 mm cap-end cushion with
  a 1.5 mm² orifice (C_d = 0.7 both).  Quasi-steady, with Q = A·v·φ(p) leaving the cap:

      before the cushion   m·g = A·Δp_line(Q)                              → v₀ (the known entry speed)
      in the cushion       m·g = A·(Δp_line(Q) + Δp_k),  Δp_k = (ρ/2)·(A·v/(C_d·a_k))²   → v_end, Δp_k

  The rod enters at v₀ and ends at v_end; the cushion pressure (the applied force's excess over the chamber
  pressures' force, over A) peaks at Δp_k: its inertia overshoot is small, the deceleration's time constant
  m/(2·K·v) (0.3 ms) being short against the 0.15 s the spear takes to engage.
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from scipy.optimize import brentq

from reference import laws
from reference import network_eval as ref
from reference.laws import orifice_textbook
from reference.circuits import bench, lift_cylinder, orifice
from reference.scenes import vertical_lift
from hydraulics.circuit import load_circuit, parse_circuit
from hydraulics.components import CircuitError, build_component
from hydraulics.network import NetworkModel
from sim.io.mcap_log import read_log
from sim.run.runner import run

MASS = 200.0  # kg
BORE = 0.05  # m
AREA = math.pi / 4 * BORE**2  # m²
LINE = 3.0e-6  # m², cap → tank
CUSHION = 1.5e-6  # m², cushion orifice
LENGTH = 0.03  # m
CD = 0.7
G = 9.81

CIRCUIT = (bench() + orifice("drain", "cap", "tank", LINE, CD)
           + lift_cylinder(BORE, cushion_length_cap=LENGTH, cushion_area_cap=CUSHION, cushion_length_rod=0.04,
                           cushion_area_rod=1.0e-6, cushion_discharge_coefficient=CD))


def _model(text=CIRCUIT):
    return NetworkModel.from_circuit(parse_circuit(tomllib.loads(text), "cushion"))


def test_cushion_force_and_slope():
    """Full Δp_k·A inside either cushion against the closing motion, none on the return stroke or outside, the
    oracle's everywhere (the transition included), its slope the central difference."""
    m = _model()
    rho = m.fluid.density
    p = np.full(m.node_count, m.fluid.reference_pressure)
    rod_area = math.pi / 4 * (BORE**2 - 0.028**2)
    for x, v, expected in ((0.01, -0.05, 0.5 * rho * (AREA * 0.05 / (CD * CUSHION)) ** 2 * AREA),
                           (0.47, 0.05, -0.5 * rho * (rod_area * 0.05 / (CD * 1e-6)) ** 2 * rod_area),
                           (0.01, 0.05, 0.0), (0.2, -0.05, 0.0), (0.2, 0.05, 0.0), (0.47, -0.05, 0.0)):
        effort, _ = m.friction_effort(np.array([v]), p, np.array([x]))
        assert effort[0] == pytest.approx(expected, rel=1e-12, abs=1e-9), (x, v)
    for x in np.linspace(0.0, 0.5, 41):
        for v in (-0.1, -1e-3, 0.0, 2e-3, 0.3):
            for k, o in zip(m.friction_effort(np.array([v]), p, np.array([x])),
                            ref.friction_effort(m, np.array([v]), p, np.array([x]))):
                np.testing.assert_allclose(k, o, rtol=1e-6, atol=1e-6)
    # without the check valve the return stroke out of the cushion meets the same orifice law
    free = _model(CIRCUIT.replace("cushion_discharge_coefficient", 'cushion_return = "orifice"\ncushion_discharge_coefficient'))
    for x, v, expected in ((0.01, 0.05, -0.5 * rho * (AREA * 0.05 / (CD * CUSHION)) ** 2 * AREA),
                           (0.47, -0.05, 0.5 * rho * (rod_area * 0.05 / (CD * 1e-6)) ** 2 * rod_area),
                           (0.01, -0.05, 0.5 * rho * (AREA * 0.05 / (CD * CUSHION)) ** 2 * AREA), (0.2, 0.05, 0.0)):
        effort, _ = free.friction_effort(np.array([v]), p, np.array([x]))
        assert effort[0] == pytest.approx(expected, rel=1e-12, abs=1e-9), (x, v)
    for x in np.linspace(0.0, 0.5, 21):
        for v in (-0.1, 0.0, 2e-3, 0.3):
            for k, o in zip(free.friction_effort(np.array([v]), p, np.array([x])),
                            ref.friction_effort(free, np.array([v]), p, np.array([x]))):
                np.testing.assert_allclose(k, o, rtol=1e-6, atol=1e-6)
    # without positions (the rigid actuators) and at fidelity 'incompressible': no cushion
    assert m.friction_effort(np.array([-0.05]), p)[0][0] == 0.0
    with pytest.raises(CircuitError, match="field 'cushion_length_cap'"):
        NetworkModel.from_circuit(parse_circuit(tomllib.loads(CIRCUIT), "c.toml"), fidelity="incompressible")


def test_cushions_must_fit_in_the_stroke():
    with pytest.raises(CircuitError, match="field 'cushion_length_rod'.*must not exceed stroke"):
        build_component("cylinder", {"bore": 0.05, "rod_diameter": 0.028, "stroke": 0.1, "cushion_length_cap": 0.06,
                                     "cushion_length_rod": 0.05}, "c.toml: component 'c'")


def quasi_steady(fluid, cushion):
    """(v [m/s, lowering], Δp_k [Pa]) of the module docstring's balance, with (True) or without the cushion."""
    rho = fluid.density

    def residual(speed):
        dp_k = 0.5 * rho * (AREA * speed / (CD * CUSHION)) ** 2 if cushion else 0.0
        p_cap = MASS * G / AREA - dp_k  # gauge
        flow = AREA * speed * float(fluid.fill_ratio(fluid.reference_pressure + p_cap)[0])
        return flow - orifice_textbook(LINE, CD, p_cap, fluid)

    speed = brentq(residual, 1e-6, 1.0, xtol=1e-15, rtol=1e-13)
    return speed, 0.5 * rho * (AREA * speed / (CD * CUSHION)) ** 2 if cushion else 0.0


@pytest.fixture(scope="module")
def lowered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cushion")
    (tmp / "lift.xml").write_text(vertical_lift(mass=MASS, inertia=0.1, gravity=G))
    (tmp / "lift.circuit.toml").write_text(CIRCUIT)
    out = {}
    for mode in ("mujoco", "pbd"):
        path = tmp / f"{mode}.scenario.toml"
        path.write_text(f'[scene]\nmjcf = "lift.xml"\ncircuit = "lift.circuit.toml"\n[run]\nmode = "{mode}"\n'
                        'dt = 0.001\nduration = 1.5\n[initial]\nqpos = { z = 0.56 }\nequilibrium = true\n'
                        '[log]\nrate_hz = 500\n')
        result = run(path, out=tmp / f"{mode}.mcap", progress=False)
        assert result.status == "complete", result.message
        out[mode] = read_log(result.log_path).topic("/hydroplant/cylinders/lift")
    return out, load_circuit(tmp / "lift.circuit.toml").fluid


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_the_cushion_brakes_the_rod_to_its_orifice_law_speed(lowered, mode):
    """Entry speed v₀ = 51.2 mm/s (steady before the cushion) and end speed v_end = 22.9 mm/s (steady in the engaged
    cushion) within 1e-6 (measured 4e-13 MuJoCo, 5e-10 PBD; 1e-10, 2e-9), the cushion pressure Δp_k = 7.99 bar
    within 1e-6 over the engaged cushion (8e-11, 3e-9) and at its peak within 1e-3 (the inertia's overshoot:
    measured 2.8e-4, 2.4e-4); none before the cushion."""
    logs, fluid = lowered
    cyl = logs[mode]
    x, v = cyl["position_m"], cyl["velocity_mps"]
    v0, _ = quasi_steady(fluid, False)
    v_end, dp_k = quasi_steady(fluid, True)
    assert 0.045 < v0 < 0.06 and 0.4 * v0 < v_end < 0.5 * v0 and 7e5 < dp_k < 9e5
    entry = (x > LENGTH + 0.003) & (x < LENGTH + 0.02)
    engaged = (x > 0.004) & (x < 0.8 * LENGTH - 0.002)
    assert entry.sum() > 20 and engaged.sum() > 100
    assert float(-np.mean(v[entry])) == pytest.approx(v0, rel=1e-6)
    assert float(-np.mean(v[engaged])) == pytest.approx(v_end, rel=1e-6)
    cushion_pressure = (cyl["force_n"] - cyl["pressure_force_n"]) / AREA
    peak = float(np.max(cushion_pressure[x < LENGTH]))
    assert dp_k <= peak < (1 + 1e-3) * dp_k
    assert float(np.mean(cushion_pressure[engaged])) == pytest.approx(dp_k, rel=1e-6)
    assert float(np.max(np.abs(cushion_pressure[entry]))) < 1e-6 * dp_k  # none before the cushion
