"""The pressure inversion of a pure-oil node with an elastic wall (``hydraulics._compiled._invert_wall_node``).

The node's oil content m fixes its pressure p through ln(V(p)·φ(p)/m) = 0 with V = V_g + w·(p − p_ref) and
φ = exp((p − p_ref)/β), i.e. f(p) = ln(1 + w·(p − p_ref)/V_g) + (p − rigid)/β = 0, rigid = p_ref + β·ln(m/V_g).
The kernel solves it by safeguarded Newton to |f| < PRESSURE_INVERSION_TOLERANCE and returns a Newton iterate
without evaluating f there when the Taylor remainder ½·(w·δ/V_min)² of the step δ proves |f| below a quarter of
the tolerance.  Checked here on states spanning the shipped circuits' wall compliances (w·β/V_g from 1e-4 to
5; the excavator's and the boom's chambers and supplies lie between 0.15 and 1.5) and pressures from 0.5 bar to
400 bar, each built from a known root p*:

* the returned pressure meets the tolerance, |f(p)| < tolerance (f evaluated here, independently);
* it lies within 2·β·tolerance/(1 + w·β/V) of p*, plus round-off (f' = 1/β + w/V over the step: the tolerance
  bounds the pressure error);
* it is the pressure the same iteration returns when it evaluates f after every step (the loop below, a copy of
  the kernel's without the remainder test), bit for bit: the test only saves the evaluation.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hydraulics import _compiled as C
from hydraulics.network import PRESSURE_INVERSION_MAX_ITERATIONS, PRESSURE_INVERSION_TOLERANCE

P_REF = 101325.0  # Pa
BETA = 1.5e9  # Pa, the shipped circuits' oil
TOL = PRESSURE_INVERSION_TOLERANCE


def residual(p, geometric, rigid, wall):
    """f(p) = ln(1 + w·(p − p_ref)/V_g) + (p − rigid)/β [-]."""
    return math.log1p(wall * (p - P_REF) / geometric) + (p - rigid) / BETA


def evaluated_every_step(geometric, rigid, wall, tol=TOL, max_iterations=PRESSURE_INVERSION_MAX_ITERATIONS):
    """The kernel's iteration (start, safeguards, stopping test) evaluating f after every step."""
    inv_geometric, inv_beta = 1.0 / geometric, 1.0 / BETA
    au = wall * inv_geometric
    ab = 1.0 + au * BETA
    u1 = (rigid - P_REF) / ab
    p = P_REF + u1 + BETA * au * au * u1 * u1 / (2.0 * ab)
    if not (math.isfinite(p) and 1.0 + au * (p - P_REF) > 0.0):
        p = rigid
    extra = wall * (p - P_REF)
    value = math.log1p(extra * inv_geometric) + (p - rigid) * inv_beta
    slope = wall / (geometric + extra) + inv_beta
    lo = p if value <= 0 else -math.inf
    hi = p if value > 0 else math.inf
    for _ in range(max_iterations):
        if abs(value) < tol:
            break
        newton = p - value / slope
        if not math.isfinite(lo):
            newton = max(newton, 0.5 * p if p > 0 else p - 1e6)
        bracketed = math.isfinite(lo) and math.isfinite(hi)
        outside = newton <= lo or newton >= hi
        p = 0.5 * (lo + hi) if (bracketed and outside) else newton
        extra = wall * (p - P_REF)
        value = math.log1p(extra * inv_geometric) + (p - rigid) * inv_beta
        slope = wall / (geometric + extra) + inv_beta
        if value <= 0:
            lo = max(lo, p)
        if value > 0:
            hi = min(hi, p)
    return p


def states():
    """(V_g [m³], rigid [Pa], w [m³/Pa], p* [Pa]) over compliances, volumes and roots (deterministic)."""
    rng = np.random.default_rng(7)
    out = []
    for stiffness in (1e-4, 1e-2, 0.1, 0.5, 1.0, 2.0, 5.0):  # w·β/V_g
        for geometric in (2e-5, 4e-4, 6e-3):
            wall = stiffness * geometric / BETA
            for root in np.concatenate([[5e4, P_REF, 3e5, 4e7], rng.uniform(5e4, 4e7, 12)]):
                rigid = root + BETA * math.log1p(wall * (root - P_REF) / geometric)
                out.append((geometric, rigid, wall, float(root)))
    return out


STATES = states()


@pytest.mark.parametrize("geometric,rigid,wall,root", STATES)
def test_inverted_pressure_meets_the_tolerance_and_matches_the_iteration_evaluating_every_step(
        geometric, rigid, wall, root):
    p = C._invert_wall_node(geometric, rigid, wall, P_REF, BETA, TOL, PRESSURE_INVERSION_MAX_ITERATIONS)
    assert abs(residual(p, geometric, rigid, wall)) < TOL
    volume = geometric + wall * (root - P_REF)
    assert abs(p - root) <= 2.0 * BETA * TOL / (1.0 + wall * BETA / volume) + 4.0 * math.ulp(root)
    assert p == evaluated_every_step(geometric, rigid, wall)

