"""The XPBD package's scalar laws and algebra against the independent formulations of ``tests/reference``.

Property tests (hypothesis) on random inputs:

* MuJoCo's soft-constraint law: the compiled ``compiled._impedance``, ``_contact_law`` and ``_soft_limit_target``
  against ``xpbd_laws.mujoco_impedance``, ``mujoco_contact_law`` and ``soft_limit_target`` (both formats of
  solref, both cones, condim 1/3/4/6, inside and beyond the limit), to 1e-12 relative;
* the quaternion algebra of ``sim.xpbd.quat`` (row-wise numpy) against the tuple kernels of ``xpbd_kernels``,
  to 1e-15 of the vectors' size.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.xpbd import compiled as XC
from sim.xpbd.quat import np_cross, np_quat_conj, np_quat_mul, np_quat_rotate, np_quat_rotate_inv
from reference import xpbd_kernels as K
from reference.xpbd_laws import mujoco_contact_law, mujoco_impedance, soft_limit_target

PROPERTY = settings(max_examples=200, deadline=None, database=None)
finite = dict(allow_nan=False, allow_infinity=False)


def _close(a, b, rel=1e-12):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = max(1e-300, float(np.max(np.abs(b), initial=0.0)))
    assert float(np.max(np.abs(a - b), initial=0.0)) <= rel * scale, (a, b)


solimps = st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.0, 0.1), st.floats(0.0, 1.0),
                    st.floats(0.5, 6.0))
solrefs = st.one_of(st.tuples(st.floats(1e-4, 0.2), st.floats(0.05, 3.0)),  # (timeconst, dampratio)
                    st.tuples(st.floats(-1e6, -1.0), st.floats(-1e4, 0.0)))  # direct (−stiffness, −damping)


@PROPERTY
@given(solimp=solimps, pos=st.floats(-0.2, 0.2, **finite))
def test_impedance_is_the_oracles(solimp, pos):
    assert XC._impedance(np.array(solimp), pos) == mujoco_impedance(solimp, pos)


@PROPERTY
@given(solref=solrefs, solimp=solimps, condim=st.sampled_from([1, 3, 4, 6]), tran=st.floats(1e-4, 10.0),
       mu=st.floats(0.0, 2.0), pos=st.floats(-0.05, 0.0), cone=st.sampled_from([0, 1]),
       impratio=st.floats(0.5, 100.0), timestep=st.floats(0.0, 0.01))
def test_contact_law_is_the_oracles(solref, solimp, condim, tran, mu, pos, cone, impratio, timestep):
    got = XC._contact_law(np.array(solref), np.array(solimp), condim, tran, mu, pos, cone, impratio, timestep)
    ref = mujoco_contact_law(solref, solimp, condim, tran, mu, pos, cone=cone, impratio=impratio, timestep=timestep)
    for a, b in zip(got, ref):
        _close(a, b)


@PROPERTY
@given(solref=solrefs, solimp=solimps, invweight=st.floats(1e-3, 100.0), value=st.floats(-1.0, 1.0),
       rate=st.floats(-5.0, 5.0), h=st.floats(1e-5, 1e-2))
def test_soft_limit_target_is_the_oracles(solref, solimp, invweight, value, rate, h):
    lo, hi = -0.3, 0.4
    params = np.zeros(9)
    params[1:3], params[3:8], params[8] = solref, solimp, invweight
    out = np.full(3, np.nan)
    XC._soft_limit_target(params, value, rate, lo, hi, h, out)
    ref = soft_limit_target(value, rate, lo, hi, solref, solimp, invweight, h)
    if ref is None:
        assert np.all(np.isnan(out))  # inside the range: no row
    else:
        _close(out, ref)


vectors = st.lists(st.floats(-10.0, 10.0, **finite), min_size=3, max_size=3)
quaternions = st.lists(st.floats(-1.0, 1.0, **finite), min_size=4, max_size=4).filter(
    lambda q: math.fsum(c * c for c in q) > 1e-3).map(lambda q: [c / math.sqrt(math.fsum(d * d for d in q)) for c in q])


@PROPERTY
@given(a=quaternions, b=quaternions, u=vectors, v=vectors)
def test_quaternion_algebra_is_the_oracles(a, b, u, v):
    qa, qb, uu, vv = (np.array(x) for x in (a, b, u, v))
    size = max(1.0, float(np.max(np.abs(uu))), float(np.max(np.abs(vv))))
    tol = 1e-15 * size * size
    assert np.max(np.abs(np_cross(uu, vv) - K.cross(u, v))) <= tol
    assert np.max(np.abs(np_quat_mul(qa, qb) - K.quat_mul(a, b))) <= 1e-15
    assert np.max(np.abs(np_quat_conj(qa) - K.quat_conj(a))) == 0.0
    assert np.max(np.abs(np_quat_rotate(qa, vv) - K.quat_rotate(a, v))) <= tol
    assert np.max(np.abs(np_quat_rotate_inv(qa, vv) - K.quat_rotate_inv(a, v))) <= tol
    rows = np.stack([qa, qb]), np.stack([uu, vv])  # row-wise: each row as the single-vector call
    np.testing.assert_array_equal(np_quat_rotate(*rows), np.stack([np_quat_rotate(qa, uu), np_quat_rotate(qb, vv)]))
