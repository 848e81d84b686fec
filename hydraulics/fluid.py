"""Hydraulic fluid: density, bulk modulus, entrained air, cavitation.

The network keeps, for every volume node, its *oil content* m [m³]: the volume
the oil in the node would occupy at the reference pressure (mass divided by the
reference density).  The pressure follows from m and the node volume V through
the fill ratio φ(p) = m/V, which is the density ratio ρ(p)/ρ_ref:

* pure oil of constant bulk modulus β: dρ/ρ = dp/β, so φ(p) = exp((p − p_ref)/β).
  With no flow this gives the seed report's closed-chamber law
  dP/dt = −β·(dV/dt)/V exactly (its integral P = P_0 − β·ln(V/V_0));
* oil with entrained free air (volume fraction a_0 at p_ref, polytropic index n):
  the mixture's specific volume is e^{−(p−p_ref)/β} + a_0·(p_ref/p)^{1/n}, and
  φ(p) = (1 + a_0) / that.  The effective bulk modulus β_eff = φ/φ' softens at
  low pressure.

Because m is the state, oil mass is conserved exactly by any stepper that moves
it only through flows, and the pressure is always consistent with whatever
chamber volume the mechanics reports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Newton iterations when inverting φ(p) for a fluid with entrained air.
FILL_INVERSION_MAX_ITERATIONS = 50  # converges in < 10 from the oil-only guess
FILL_INVERSION_TOLERANCE = 1e-12  # on ln φ, i.e. ≈ β·1e-12 Pa
POTENTIAL_QUADRATURE_POINTS = 24  # Gauss–Legendre points for μ(p) with entrained air


def potential_quadrature() -> np.ndarray:
    """The Gauss–Legendre rule on [−1, 1] of :meth:`Fluid.pressure_potential` with entrained air: its
    ``POTENTIAL_QUADRATURE_POINTS`` nodes, then their weights (one flat array, as the compiled kernels take it)."""
    return np.concatenate(np.polynomial.legendre.leggauss(POTENTIAL_QUADRATURE_POINTS))


@dataclass(frozen=True, kw_only=True)
class Fluid:
    """Hydraulic oil properties (SI)."""

    density: float = 870.0
    """Reference density ρ_ref [kg/m³] at ``reference_pressure``."""
    bulk_modulus: float = 1.5e9
    """Bulk modulus β of the pure liquid [Pa]."""
    kinematic_viscosity: float = 4.6e-5
    """Kinematic viscosity ν [m²/s] (ISO VG 46 at 40 °C)."""
    reference_pressure: float = 1.01325e5
    """Absolute pressure p_ref [Pa] at which the oil content is measured (ambient)."""
    cavitation_pressure: float | None = 3.0e3
    """Absolute pressure [Pa] below which the oil cavitates; None = no floor (idealised)."""
    air_fraction: float = 0.0
    """Free-air volume fraction a_0 [-] at ``reference_pressure``; 0 = pure oil."""
    polytropic_index: float = 1.0
    """Polytropic index n [-] of the entrained air (1 = isothermal)."""

    def __post_init__(self):
        for name in ("density", "bulk_modulus", "kinematic_viscosity", "polytropic_index"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"`{name}` must be positive and finite, got {value!r}")
        if not (math.isfinite(self.reference_pressure) and self.reference_pressure >= 0):
            raise ValueError(f"`reference_pressure` must be >= 0 Pa and finite, got {self.reference_pressure!r}")
        if not (0.0 <= self.air_fraction < 1.0):
            raise ValueError(f"`air_fraction` must be in [0, 1), got {self.air_fraction!r}")
        if self.air_fraction > 0 and self.reference_pressure <= 0:
            raise ValueError("`air_fraction` > 0 needs `reference_pressure` > 0 Pa")
        if self.cavitation_pressure is not None:
            if not (math.isfinite(self.cavitation_pressure) and self.cavitation_pressure > 0):
                raise ValueError(f"`cavitation_pressure` must be > 0 Pa absolute, got {self.cavitation_pressure!r}")

    @property
    def pressure_floor(self) -> float:
        """Lowest admissible absolute pressure [Pa] (−inf when cavitation is off)."""
        return -math.inf if self.cavitation_pressure is None else self.cavitation_pressure

    # ------------------------------------------------------------------
    def fill_ratio(self, pressure):
        """φ(p) = ρ(p)/ρ_ref [-] and dφ/dp [1/Pa] (see module docstring)."""
        p = np.asarray(pressure, dtype=float)
        liquid = np.exp(-(p - self.reference_pressure) / self.bulk_modulus)
        if self.air_fraction == 0.0:
            phi = 1.0 / liquid
            return phi, phi / self.bulk_modulus
        pp = np.maximum(p, 1.0)
        air = self.air_fraction * (self.reference_pressure / pp) ** (1.0 / self.polytropic_index)
        specific = liquid + air
        dspecific = -liquid / self.bulk_modulus - air / (self.polytropic_index * pp)
        phi = (1.0 + self.air_fraction) / specific
        return phi, -phi * dspecific / specific

    def effective_bulk_modulus(self, pressure):
        """β_eff(p) = φ/φ' [Pa]: equals β for pure oil, softer with entrained air."""
        phi, dphi = self.fill_ratio(pressure)
        return phi / dphi

    def pressure_from_fill_ratio(self, ratio):
        """Invert φ: absolute pressure [Pa] whose fill ratio is ``ratio`` (no floor applied)."""
        r = np.asarray(ratio, dtype=float)
        p = self.reference_pressure + self.bulk_modulus * np.log(r)
        if self.air_fraction == 0.0:
            return p
        target = np.log(r)
        p = np.maximum(p, self.reference_pressure * 1e-3)
        for _ in range(FILL_INVERSION_MAX_ITERATIONS):
            phi, dphi = self.fill_ratio(p)
            residual = np.log(phi) - target
            p = np.maximum(p - residual * phi / dphi, 0.5 * p)
            if np.all(np.abs(residual) < FILL_INVERSION_TOLERANCE):
                break
        return p

    def pressure_potential(self, pressure):
        """μ(p) = ∫_{p_ref}^{p} dp'/φ(p') [Pa]: flow work per unit oil content (enthalpy × ρ_ref).

        A flow Q of oil content between pressures p₁ and p₂ exchanges the power
        Q·(μ(p₁) − μ(p₂)) [W]; for pure oil μ = β·(1 − exp(−(p − p_ref)/β)),
        which is p − p_ref to first order.
        """
        p = np.asarray(pressure, dtype=float)
        if self.air_fraction == 0.0:
            return self.bulk_modulus * -np.expm1(-(p - self.reference_pressure) / self.bulk_modulus)
        nodes, weights = np.split(potential_quadrature(), 2)
        half = 0.5 * (p - self.reference_pressure)
        mid = 0.5 * (p + self.reference_pressure)
        samples = mid[..., None] + half[..., None] * nodes
        return half * np.sum(weights / self.fill_ratio(samples)[0], axis=-1)
