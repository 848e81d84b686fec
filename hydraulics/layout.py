"""Flat buffers described once: an ordered list of named fields whose sizes are expressions in a buffer's dimensions.

The compiled kernels take their scratch and their persistent state as flat float64 arrays (no allocation in a step).
A :class:`Layout` describes such an array once: its dimensions (``n`` nodes, ``na`` actuators, ...) and its fields in
order, each a vector of ``rows`` entries or a C-contiguous ``rows`` × ``cols`` matrix, ``rows`` and ``cols`` being
Python expressions in the dimensions (or integers).  Everything else is generated from it:

* :meth:`Layout.size` / :meth:`Layout.sizer`: the length Σ rows·cols, as Python and as a function of the dimensions
  (``def size(n, na): return (n) + (n) * (na)``) that a kernel compiles;
* :meth:`Layout.offsets`: each field's ``[start, stop)`` in the array, contiguous from 0 to the size;
* :meth:`Layout.carver`: a function ``carve(W, o, *dims)`` returning a :meth:`Layout.View` named tuple of views of
  ``W`` from offset ``o`` (plain slices, ``matrix(W[a:b], rows, cols)`` for the matrices) and the offset after them,
  generated as source and ``exec``-ed, so that numba compiles straight-line slicing (inline it: ``inline="always"``)
  and sees no Python object in a kernel.

A layout nested in another is a field whose size is a dimension of the outer one (the outer buffer reserves it, the
inner kernel carves it from its own start), or its fields are spliced into the outer list
(``Layout(..., INNER.fields + (...))``): either way each field is written once.

:func:`slots` makes the named indices of an int64 table (a pointer table) from one tuple of names.

Example
-------
>>> import numpy as np
>>> L = Layout("demo", ("n", "na"), (("oil", "n"), ("gradient", "n", "na"), ("flag", 1)))
>>> L.size(n=3, na=2), L.offsets(n=3, na=2)["gradient"]
(10, (3, 9))
>>> views, end = L.carver(lambda a, r, c: a.reshape((r, c)))(np.arange(10.0), 0, 3, 2)
>>> views.gradient.shape, float(views.flag[0]), end
((3, 2), 9.0, 10)
>>> slots(("C_NA", "P_F")).P_F
1
"""

from __future__ import annotations

import keyword
from collections import namedtuple


class Layout:
    """An ordered description of a flat float64 buffer (see module docstring).

    ``name``: the buffer's name (also of its view tuple); ``dims``: the dimensions' names, in the order the generated
    functions take them; ``fields``: ``(name, rows)`` for a vector, ``(name, rows, cols)`` for a C-contiguous matrix,
    ``rows``/``cols`` an ``int`` or a Python expression (``str``) in ``dims``.
    """

    def __init__(self, name: str, dims: tuple[str, ...], fields: tuple[tuple, ...]):
        self.name = name
        self.dims = tuple(dims)
        self.fields = tuple((f[0], f[1], f[2] if len(f) > 2 else None) for f in fields)
        names = [f[0] for f in self.fields]
        if len(set(names)) != len(names):
            raise ValueError(f"layout {name}: a field name appears twice in {names}")
        for n in names + list(self.dims):
            if not n.isidentifier() or keyword.iskeyword(n) or n.startswith("_"):
                raise ValueError(f"layout {name}: {n!r} is not a plain identifier")
        if set(names) & (set(self.dims) | {"W", "o"}) or len(set(self.dims)) != len(self.dims):
            raise ValueError(f"layout {name}: a dimension named twice, or a field named like a dimension or like the "
                             f"carver's buffer W and offset o: {self.dims}, {names}")
        self.View = namedtuple(f"{name.title().replace('_', '')}Views", names)
        self.View.__doc__ = f"Views of the {name} buffer's fields ({', '.join(names)})."

    @property
    def names(self) -> tuple[str, ...]:
        """The fields' names in order."""
        return tuple(f[0] for f in self.fields)

    @staticmethod
    def _term(rows, cols) -> str:
        return f"({rows})" if cols is None else f"({rows}) * ({cols})"

    def size_expression(self) -> str:
        """Σ rows·cols as a Python expression in :attr:`dims` (``0`` for no field)."""
        return " + ".join(self._term(r, c) for _, r, c in self.fields) or "0"

    def _environment(self, dims: dict) -> dict:
        missing = set(self.dims) - set(dims)
        extra = set(dims) - set(self.dims)
        if missing or extra:
            raise TypeError(f"layout {self.name} takes the dimensions {self.dims}: missing {sorted(missing)}, "
                            f"unknown {sorted(extra)}")
        return {"__builtins__": {}, **{k: int(v) for k, v in dims.items()}}

    def size(self, **dims) -> int:
        """The buffer's length for the dimensions ``dims`` (every name of :attr:`dims`)."""
        return int(eval(self.size_expression(), self._environment(dims)))

    def offsets(self, **dims) -> dict[str, tuple[int, int]]:
        """Each field's ``(start, stop)`` in the buffer, in order: the first starts at 0, each starts where the one
        before stops, the last stops at :meth:`size`."""
        env = self._environment(dims)
        out, o = {}, 0
        for name, rows, cols in self.fields:
            count = int(eval(self._term(rows, cols), env))
            if count < 0:
                raise ValueError(f"layout {self.name}: field {name} has {count} entries for {dims}")
            out[name] = (o, o + count)
            o += count
        return out

    def shapes(self, **dims) -> dict[str, tuple[int, ...]]:
        """Each field's shape: ``(rows,)`` or ``(rows, cols)``."""
        env = self._environment(dims)
        return {name: (int(eval(f"({rows})", env)),) if cols is None
                else (int(eval(f"({rows})", env)), int(eval(f"({cols})", env))) for name, rows, cols in self.fields}

    def sizer_source(self) -> str:
        """Source of ``size(*dims)``: :meth:`size_expression` as a function of the dimensions in :attr:`dims` order."""
        return f"def size({', '.join(self.dims)}):\n    return {self.size_expression()}\n"

    def carver_source(self) -> str:
        """Source of ``carve(W, o, *dims)``: one slice per field from offset ``o`` (matrices through ``_matrix``),
        returned as a :attr:`View` with the offset after the last field."""
        lines = [f"def carve(W, o, {', '.join(self.dims)}):" if self.dims else "def carve(W, o):"]
        for name, rows, cols in self.fields:
            count = self._term(rows, cols)
            if cols is None:
                lines.append(f"    {name} = W[o:o + {count}]")
            else:
                lines.append(f"    {name} = _matrix(W[o:o + {count}], {rows}, {cols})")
            lines.append(f"    o = o + {count}")
        lines.append(f"    return _View({', '.join(self.names)}), o")
        return "\n".join(lines) + "\n"

    def _generated(self, source: str, namespace: dict, what: str):
        exec(compile(source, f"<hydraulics.layout.{self.name}.{what}>", "exec"), namespace)
        return namespace[what]

    def sizer(self):
        """The Python function of :meth:`sizer_source` (compile it with numba where a kernel needs it)."""
        function = self._generated(self.sizer_source(), {}, "size")
        function.__doc__ = f"Length of the {self.name} buffer: {self.size_expression()}."
        return function

    def carver(self, matrix):
        """The Python function of :meth:`carver_source`; ``matrix(flat, rows, cols)`` makes the 2-D views
        (``hydraulics._jit.matrix`` in a kernel).  Compile it inlined (numba ``inline="always"``): a tuple of
        views returned through a call is a zero-filled stack slot per call."""
        function = self._generated(self.carver_source(), {"_View": self.View, "_matrix": matrix}, "carve")
        function.__doc__ = (f"Views of the {self.name} buffer's fields from offset ``o`` ({', '.join(self.names)}) "
                            f"and the offset after them.")
        return function

    def views(self, buffer, offset: int = 0, **dims):
        """The fields of ``buffer`` (a 1-D numpy array) from ``offset`` as a :attr:`View` of numpy views (Python side)."""
        shapes = self.shapes(**dims)
        out = []
        for name, (start, stop) in self.offsets(**dims).items():
            out.append(buffer[offset + start:offset + stop].reshape(shapes[name]))
        return self.View(*out)

    def __repr__(self):
        return f"Layout({self.name!r}, {self.dims}, {self.names})"


def slots(names: tuple[str, ...]):
    """Named indices 0, 1, ... of the entries of an int64 table, as a named tuple of ints (``slots(NAMES).X`` is the
    index of ``X``); numba reads a global named tuple of ints as constants.  ``len(names)`` is the table's length."""
    if len(set(names)) != len(names):
        raise ValueError(f"a slot name appears twice in {names}")
    return namedtuple("Slots", names)(*range(len(names)))
