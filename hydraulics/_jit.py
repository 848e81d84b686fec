"""numba plumbing shared by every compiled kernel of the package: decorators, intrinsics, element-wise helpers.

* :func:`kernel`, :func:`jit`, :func:`inline`: ``numba.njit`` with numpy's floating-point error model (x/0 →
  inf/nan, no exception), without (``kernel``, ``inline``) or with (``jit``) numba's reference counting.  They
  do not cache: a cached function is keyed by its own file only, so a kernel cached on its own would keep
  stale copies of the laws it calls from other files.  Only the entry points called from Python are cached, each
  carrying :data:`FINGERPRINT` (the digest of every file compiled into them, :data:`SOURCES`) as a closure
  variable, which is part of numba's cache key (``hydraulics._compiled`` and the compiled plants of ``sim.plants``).
* :func:`borrowed`, :func:`matrix`, :func:`ref`, :func:`deref`: intrinsics that remove reference-counting
  and copying costs in the hot loops (see each docstring).
* Under ``NUMBA_DISABLE_JIT=1`` (:data:`JIT_ENABLED` False) the decorators return the Python functions and the
  intrinsics are replaced by Python functions with the same results: every kernel then runs as plain Python,
  for debugging (``tests/test_disable_jit.py`` compares such a run with the compiled one).

This module imports nothing from the package (the component modules and :mod:`hydraulics._compiled` import it).

Example
-------
>>> from hydraulics._jit import kernel, clip
>>> @kernel
... def opening(z):
...     return clip(z, 0.0, 1.0)
>>> opening(1.5)
1.0
"""

from __future__ import annotations

import glob
import math
import os

try:  # pragma: no branch
    import numba as _numba

    _NUMBA = True
except ImportError:  # pragma: no cover - the pure stepper is used instead
    _numba = None
    _NUMBA = False

JIT_ENABLED = _NUMBA and not _numba.config.DISABLE_JIT
"""False when numba is missing or ``NUMBA_DISABLE_JIT=1``: the kernels then run as plain Python (for debugging) and
the numba intrinsics below are replaced by Python functions with the same results."""


def compiled_available() -> bool:
    """True when numba imports (the compiled kernels can be used)."""
    return _NUMBA


def source_sha256(*paths) -> str:
    """sha256 of the source files ``paths`` and of numba's version.

    numba keys a cached function by its own file only, so an entry point that compiles in functions of other files
    carries this digest as a closure variable (part of numba's cache key).  The modules take it when they are
    imported: a process that imported one version of the sources keeps that version's key even if a file changes on
    disk before its first compilation (a key read at compile time would file the old code under the new sources).
    A file that cannot be read makes the digest unique to this process (never reuse a cache entry across versions).
    """
    import hashlib

    digest = hashlib.sha256()
    for path in paths:
        try:
            with open(path, "rb") as f:
                digest.update(f.read())
        except OSError:  # pragma: no cover
            digest.update(repr((path, os.getpid())).encode())
    digest.update(_numba.__version__.encode() if _NUMBA else b"")
    return digest.hexdigest()


_PACKAGE = os.path.dirname(os.path.abspath(__file__))
SOURCES = tuple([os.path.join(_PACKAGE, "_jit.py"), os.path.join(_PACKAGE, "_compiled.py"),
                os.path.join(_PACKAGE, "_compiled_rigid.py"), os.path.join(_PACKAGE, "layout.py")]
                + sorted(glob.glob(os.path.join(_PACKAGE, "components", "*.py"))))
"""The files whose functions the hydraulic kernels compile in: this module, :mod:`hydraulics._compiled`,
:mod:`hydraulics._compiled_rigid`, :mod:`hydraulics.layout` (the generated scratch views) and every component
module (their laws).  A cached entry point carries :data:`FINGERPRINT`, their digest."""
FINGERPRINT = source_sha256(*SOURCES)
"""sha256 of :data:`SOURCES` and numba's version, taken at import (see :func:`source_sha256`)."""


def jit(function):
    """``numba.njit`` with numpy's floating-point error model (x/0 → inf/nan, no exception); not cached on its own
    (see the module docstring)."""
    if not _NUMBA:  # pragma: no cover
        return function
    return _numba.njit(error_model="numpy", nogil=True)(function)


def kernel(function):
    """:func:`jit` without numba's reference counting (``_nrt=False``), for every function below that allocates
    nothing and returns no array to a reference-counted caller.

    Reading a field of the packed network ``net`` (a tuple of 22 arrays) in a
    reference-counted function costs an ``NRT_incref``/``NRT_decref`` call pair;
    in the Newton loops these calls cost more than the arithmetic.  Arrays are
    borrowed from the (reference-counted) entry point that owns them.
    """
    if not _NUMBA:  # pragma: no cover
        return function
    return _numba.njit(error_model="numpy", nogil=True, _nrt=False)(function)


if JIT_ENABLED:
    from numba.core import cgutils as _cgutils
    from numba.extending import intrinsic as _intrinsic

    @_intrinsic
    def borrowed(typingctx, args):
        """The tuple ``args`` with every array (also in nested tuples) replaced by a view that owns no reference (a
        null meminfo).

        For a reference-counted entry point that passes its (caller-owned) arrays to many compiled callees:
        numba's ``NRT_incref``/``NRT_decref`` return at once on a null meminfo, so the callees' reference
        counting costs a compare per call instead of an atomic add.  Safe while the arrays of ``args`` stay
        alive, i.e. for the duration of the call that received them; a borrowed view must not be returned
        or stored.  Other members of the tuple are passed through unchanged.
        """
        if not isinstance(args, _numba.types.BaseTuple):
            return None

        def borrow(context, builder, member, value):
            if isinstance(member, _numba.types.Array):
                view = context.make_array(member)(context, builder, value=value)
                view.meminfo = _cgutils.get_null_value(view.meminfo.type)
                view.parent = _cgutils.get_null_value(view.parent.type)
                return view._getvalue()
            if isinstance(member, _numba.types.BaseTuple):
                out = value
                for i, inner in enumerate(member.types):
                    out = builder.insert_value(out, borrow(context, builder, inner, builder.extract_value(value, i)), i)
                return out
            return value

        def codegen(context, builder, signature, llargs):
            return borrow(context, builder, args, llargs[0])

        return args(args), codegen

    @_intrinsic
    def matrix(typingctx, a, rows, cols):
        """The 1-D C-contiguous array ``a`` (``rows·cols`` entries) as a C-contiguous ``rows`` × ``cols`` view:
        ``a.reshape((rows, cols))`` without numba's run-time reshape helper and its checks, which cost more than
        the kernels' small loops (``_compiled._unpack`` makes 13 such views per call)."""
        if not (isinstance(a, _numba.types.Array) and a.ndim == 1 and a.layout == "C"
                and isinstance(rows, _numba.types.Integer) and isinstance(cols, _numba.types.Integer)):
            return None
        matrix = a.copy(ndim=2, layout="C")

        def codegen(context, builder, signature, llargs):
            from numba.core.imputils import impl_ret_borrowed

            flat = context.make_array(a)(context, builder, value=llargs[0])
            nrow = context.cast(builder, llargs[1], signature.args[1], _numba.types.intp)
            ncol = context.cast(builder, llargs[2], signature.args[2], _numba.types.intp)
            out = context.make_array(matrix)(context, builder)
            context.populate_array(out, data=flat.data, shape=_cgutils.pack_array(builder, [nrow, ncol]),
                                   strides=_cgutils.pack_array(builder, [builder.mul(ncol, flat.itemsize), flat.itemsize]),
                                   itemsize=flat.itemsize, meminfo=flat.meminfo, parent=flat.parent)
            return impl_ret_borrowed(context, builder, matrix, out._getvalue())

        return matrix(a, rows, cols), codegen

    @_intrinsic
    def ref(typingctx, value):
        """A pointer to ``value`` in the calling function's stack frame (valid until that function returns; never to
        be stored or returned).

        Numba passes a tuple argument by value, field by field: the packed network ``net`` (22 arrays, ~170 machine
        words) would be copied onto the stack at every call of every kernel that takes it, which under ``perf`` is
        the largest single cost of a small network's step.  The kernels take this pointer (``pnet``) instead and read
        the fields they use through :func:`deref`.

        The slot is allocated in the entry block without numba's customary zero fill (``cgutils.alloca_once``
        always stores zeros there): the value is stored before the pointer exists, and the zero fill of a
        ~1.7 kB tuple is a ``memset`` per call that LLVM keeps once the pointer escapes."""
        def codegen(context, builder, signature, llargs):
            with builder.goto_entry_block():
                slot = builder.alloca(llargs[0].type)
            builder.store(llargs[0], slot)
            return slot

        return _numba.types.CPointer(value)(value), codegen

    @_intrinsic
    def deref(typingctx, ref):
        """The value behind a :func:`ref` pointer; any other value passes through unchanged (a kernel called from
        Python with the tuple itself)."""
        from numba.core.imputils import impl_ret_borrowed

        if isinstance(ref, _numba.types.CPointer):
            def load(context, builder, signature, llargs):
                return impl_ret_borrowed(context, builder, signature.return_type, builder.load(llargs[0]))

            return ref.dtype(ref), load

        def same(context, builder, signature, llargs):
            return impl_ret_borrowed(context, builder, signature.return_type, llargs[0])

        return ref(ref), same
else:  # pragma: no cover
    def borrowed(args):
        return args

    def ref(value):
        return value

    def deref(ref):
        return ref

    def matrix(a, rows, cols):
        return a.reshape((rows, cols))


def inline(function):
    """:func:`kernel`, inlined into its callers at numba IR level (small helpers that take ``net``:
    LLVM does not inline them, and each call passes ~170 machine words)."""
    if not _NUMBA:  # pragma: no cover
        return function
    return _numba.njit(error_model="numpy", nogil=True, inline="always", _nrt=False)(function)




# ----------------------------------------------------------------------------
# numpy element-wise semantics (NaN propagates like np.maximum / np.clip)
# ----------------------------------------------------------------------------
@kernel
def maximum(a, b):
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


@kernel
def minimum(a, b):
    if a != a or b != b:
        return math.nan
    return a if a <= b else b


@kernel
def clip(z, lo, hi):
    if z < lo:
        return lo
    if z > hi:
        return hi
    return z

