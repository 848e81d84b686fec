"""Exact steps of the linear lags that component states follow (a valve's spool, a poppet), shared by their
modules.

A state y driven towards a target u held over a step of h (zero-order hold) moves exactly as

* first order, τ·ẏ = u − y:  y⁺ = u + e^(−h/τ)·(y − u);
* second order, ÿ + 2ζω·ẏ + ω²·y = ω²·u:  (y⁺ − u, ẏ⁺) = Φ(h)·(y − u, ẏ) with

      Φ = e^(−ζωh)·[[C + ζω·S, S], [−ω²·S, C − ζω·S]],  C = cosh(δh), S = sinh(δh)/δ,  δ² = ω²(ζ² − 1)

  (cos(|δ|h) and sin(|δ|h)/|δ| when δ² < 0; a series near critical damping), the matrix exponential of
  [[0, 1], [−ω², −2ζω]]·h in closed form.

Either step is unconditionally stable and exact for the lag's own motion whatever h·ω; what the target does
within the step is the caller's approximation.

Example
-------
>>> f11, f12, f21, f22 = second_order_transition(100.0, 1.0, 0.01)
>>> round(f11, 6), round(f12, 6)  # critically damped: e^(−1)·(1 + 1), e^(−1)·0.01
(0.735759, 0.003679)
"""

from __future__ import annotations

import math

from .._jit import kernel


@kernel
def first_order_transition(tau, h):
    """e^(−h/τ) [-] of a first-order lag with time constant ``tau`` [s] over ``h`` [s] (0 for τ = 0: no lag)."""
    return math.exp(-h / tau) if tau > 0.0 else 0.0


@kernel
def second_order_transition(omega, zeta, h):
    """Φ(h) = (Φ₁₁, Φ₁₂ [s], Φ₂₁ [1/s], Φ₂₂) of ÿ + 2ζω·ẏ + ω²·y = 0 over ``h`` [s]; natural frequency ``omega``
    [rad/s], damping ratio ``zeta`` [-]."""
    a = zeta * omega
    d2 = omega * omega * (zeta * zeta - 1.0)
    x2 = d2 * h * h
    if abs(x2) < 1e-6:  # series of cosh(√x2) and sinh(√x2)/√x2: cancellation-free near critical damping
        cosine = 1.0 + x2 / 2.0 + x2 * x2 / 24.0
        sine = h * (1.0 + x2 / 6.0 + x2 * x2 / 120.0)
    elif d2 > 0.0:
        d = math.sqrt(d2)
        cosine, sine = math.cosh(d * h), math.sinh(d * h) / d
    else:
        d = math.sqrt(-d2)
        cosine, sine = math.cos(d * h), math.sin(d * h) / d
    decay = math.exp(-a * h)
    return decay * (cosine + a * sine), decay * sine, -decay * omega * omega * sine, decay * (cosine - a * sine)
