"""Vector and quaternion algebra on numpy arrays for the XPBD model and plant (scene building, observations).

Quaternions are (w, x, y, z), unit length, and rotate body-frame vectors to the world:
R(q)·v = v + 2w·(u × v) + u × (2·u × v) with u = (x, y, z), and Rᵀ(q)·v is R(q̄)·v with q̄ = (w, −u).
Every function works row-wise on arrays of shape (..., 3) / (..., 4) and on single vectors (shape (3,) / (4,)).
The substep's own algebra is compiled (``compiled.py``: ``_rot``, ``_rotinv``, ``_qmul``, ``_cross``).

Example
-------
>>> import numpy as np
>>> q = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # 90° about z
>>> np.round(np_quat_rotate(q, np.array([1.0, 0.0, 0.0])), 12) + 0.0
array([0., 1., 0.])
"""

from __future__ import annotations

import numpy as np

__all__ = ["np_cross", "np_quat_mul", "np_quat_conj", "np_quat_rotate", "np_quat_rotate_inv"]


def np_cross(a, b):
    """Row-wise cross product (much faster than ``np.cross`` for small arrays)."""
    if np.ndim(a) == 1 and np.ndim(b) == 1:  # one vector pair: scalar arithmetic, one array
        a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
        b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
        return np.array((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    c0 = a1 * b2 - a2 * b1
    out = np.empty(c0.shape + (3,), dtype=np.result_type(c0, float))
    out[..., 0] = c0
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def np_quat_mul(a, b):
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        axis=-1,
    )


def np_quat_conj(q):
    out = np.array(q, dtype=float, copy=True)
    out[..., 1:] *= -1.0
    return out


def np_quat_rotate(q, v):
    u = q[..., 1:]
    t = 2.0 * np_cross(u, v)
    return v + q[..., :1] * t + np_cross(u, t)


def np_quat_rotate_inv(q, v):
    u = -q[..., 1:]
    t = 2.0 * np_cross(u, v)
    return v + q[..., :1] * t + np_cross(u, t)
