"""Smooth and clipped ramps shared by the pressure-opened valve laws, with their derivatives.

Compiled scalar functions (:func:`hydraulics._jit.kernel`); the derivative is exact on every piece, so
Newton's method sees the slope of the piece it is on.

Example
-------
>>> smooth_ramp_with_derivative(0.5, 1.0)
(0.125, 0.5)
"""

from __future__ import annotations

from .._jit import clip, kernel


@kernel
def smooth_ramp_with_derivative(z, width):
    """C¹ ramp and its slope: 0 for z ≤ 0, z²/(2w) for 0 < z < w, z − w/2 for z ≥ w (``width`` w > 0, unit of z).

    Used at a relief valve's cracking point so that Newton's method sees a continuous slope.
    """
    if z >= width:
        return z - 0.5 * width, 1.0
    if z > 0.0 and z < width:
        return z * z / (2.0 * width), z / width
    return 0.0, 0.0


@kernel
def ramp_piece(z, width):
    """Which piece of :func:`smooth_ramp_with_derivative` ``z`` lies on: 0 (z ≤ 0), 1 (0 < z < w), 2 (z ≥ w)."""
    if z >= width:
        return 2
    return 1 if z > 0.0 else 0


@kernel
def unit_clip_with_derivative(z):
    """clip(z, 0, 1) and its derivative (1 inside (0, 1), 0 outside)."""
    return clip(z, 0.0, 1.0), (1.0 if (z > 0.0 and z < 1.0) else 0.0)


@kernel
def smooth_step_with_derivative(z):
    """C¹ unit step and its slope: 0 for z ≤ 0, 3z² − 2z³ for 0 < z < 1, 1 for z ≥ 1 (slope 6z(1 − z) inside).

    The opening of a pilot-operated poppet: continuous opening and slope, so Newton's method sees no kink.
    """
    if z >= 1.0:
        return 1.0, 0.0
    if z > 0.0:
        return z * z * (3.0 - 2.0 * z), 6.0 * z * (1.0 - z)
    return 0.0, 0.0
