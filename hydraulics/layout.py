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

:func:`table_carver` carves one named tuple from several buffers, each described by a layout (a table of float64 and
int64 columns flattened into one array of each dtype).

:func:`slots` makes the named indices of an int64 table from one tuple of names; a :class:`PointerTable` describes an
int64 table that holds counters, dimensions and the addresses of typed arrays (what a C callback reads instead of
arguments), and generates its slot names, the named tuple of its arrays, the numba-compilable function that views
them, and the check of each registered array against the description.

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
import math
from collections import namedtuple

import numpy as np


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
        lines += self._slices("W")
        lines.append(f"    return _View({', '.join(self.names)}), o")
        return "\n".join(lines) + "\n"

    def _slices(self, buffer: str) -> list[str]:
        """Statements binding each field to its slice of ``buffer`` from offset ``o`` and advancing ``o``."""
        lines = []
        for name, rows, cols in self.fields:
            count = self._term(rows, cols)
            if cols is None:
                lines.append(f"    {name} = {buffer}[o:o + {count}]")
            else:
                lines.append(f"    {name} = _matrix({buffer}[o:o + {count}], {rows}, {cols})")
            lines.append(f"    o = o + {count}")
        return lines

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

    def gather(self, source, dtype, length: int | None = None, fill=0, **dims):
        """A new flat array of ``dtype`` holding the fields of ``source`` (an object with an attribute per field, a
        named tuple) in the layout's order, each checked to have its described number of entries; padded with
        ``fill`` to ``length`` entries when given (at least :meth:`size`).  :meth:`views` or :meth:`carver` (or
        :func:`table_carver` for a table split over several buffers) read it back."""
        out = np.full(self.size(**dims) if length is None else int(length), fill, dtype)
        if out.size < self.size(**dims):
            raise ValueError(f"layout {self.name}: {out.size} entries cannot hold {self.size(**dims)} for {dims}")
        for name, (start, stop) in self.offsets(**dims).items():
            values = np.ravel(getattr(source, name))
            if values.size != stop - start:
                raise ValueError(f"layout {self.name}: field {name} has {values.size} entries, {stop - start} described "
                                 f"for {dims}")
            out[start:stop] = values
        return out

    def __repr__(self):
        return f"Layout({self.name!r}, {self.dims}, {self.names})"


def table_carver(view, parts, dims: tuple[str, ...], matrix):
    """``carve(*buffers, *dims)``: the named tuple ``view`` of the fields of several flat buffers, each described by a
    :class:`Layout` (``parts``: ``(layout, buffer name)`` per buffer, e.g. a float64 and an int64 array holding one
    table), every field of ``view`` found in exactly one layout; ``dims``: the union of the layouts' dimensions, in
    the order the function takes them.  Generated source, compiled like :meth:`Layout.carver` (inline it in a
    kernel); ``matrix`` as there."""
    names = [n for layout, _ in parts for n in layout.names]
    if sorted(names) != sorted(view._fields):
        raise ValueError(f"{view.__name__}: the layouts' fields {names} are not the tuple's {view._fields}")
    buffers = [b for _, b in parts]
    for layout, _ in parts:
        if not set(layout.dims) <= set(dims):
            raise ValueError(f"{view.__name__}: layout {layout.name} takes {layout.dims}, not all in {dims}")
    if set(buffers) & (set(names) | set(dims) | {"o"}) or len(set(buffers)) != len(buffers):
        raise ValueError(f"{view.__name__}: a buffer named twice or like a field or dimension: {buffers}")
    lines = [f"def carve({', '.join(buffers + list(dims))}):"]
    for layout, buffer in parts:
        lines.append("    o = 0")
        lines += layout._slices(buffer)
    lines.append(f"    return _View({', '.join(view._fields)})")
    source = "\n".join(lines) + "\n"
    namespace = {"_View": view, "_matrix": matrix}
    exec(compile(source, f"<hydraulics.layout.{view.__name__}.carve>", "exec"), namespace)
    function = namespace["carve"]
    function.__doc__ = (f"The {view.__name__} held in {', '.join(buffers)} ({', '.join(l.name for l, _ in parts)}) "
                        f"as views.")
    function.source = source
    return function


class PointerTable:
    """An int64 table of named integers and of the addresses of typed arrays, described once.

    A compiled callback that cannot take arguments (a C callback) reads its arrays through such a table: their
    addresses and the dimensions that size them.  ``scalars``: the names of the table's plain integer entries
    (counters, flags), in table order; ``dims``: the arrays' dimensions, each held in the entry ``C_<DIM>`` (upper
    case) after the scalars; ``arrays``: ``(name, dtype, rows)`` for a vector, ``(name, dtype, rows, cols)`` for a
    C-contiguous matrix, ``dtype`` a numpy dtype name, ``rows``/``cols`` an ``int`` or a Python expression in
    ``dims``, the address in the entry ``P_<NAME>`` after the dimensions.  Generated from it:

    * :attr:`SLOT`: every entry's index (:func:`slots`), :attr:`names` the entries' names, ``len`` the table's length;
    * :attr:`View`: the named tuple of the arrays; :meth:`viewer` (source :meth:`viewer_source`): ``views(ctx)``, every
      array as a view of the memory the table points to (``carray`` of the address cast to a pointer of its dtype,
      numba-compilable; inline it where the views are used);
    * :meth:`register`: writes dimensions and addresses into a table after checking each array's dtype, contiguity
      and size against the description; :meth:`shapes`.

    Example
    -------
    >>> import numpy as np
    >>> T = PointerTable("demo", ("C_STEP",), ("n",), (("oil", "float64", "n"), ("table", "int64", "n", 2)))
    >>> T.names, T.SLOT.P_OIL
    (('C_STEP', 'C_N', 'P_OIL', 'P_TABLE'), 2)
    >>> ctx, oil = np.zeros(len(T), np.int64), np.zeros(3)
    >>> T.register(ctx, {"oil": oil, "table": np.zeros((3, 2), np.int64)}, n=3)
    >>> int(ctx[T.SLOT.C_N]), int(ctx[T.SLOT.P_OIL]) == oil.ctypes.data
    (3, True)
    """

    def __init__(self, name: str, scalars: tuple[str, ...], dims: tuple[str, ...], arrays: tuple[tuple, ...]):
        self.name = name
        self.dims = tuple(dims)
        self.arrays = tuple((a[0], str(a[1]), tuple(a[2:])) for a in arrays)
        fields = [a[0] for a in self.arrays]
        for n in fields + list(self.dims):
            if not n.isidentifier() or keyword.iskeyword(n) or n.startswith("_") or n == "ctx":
                raise ValueError(f"pointer table {name}: {n!r} is not a plain identifier (or is the table's ctx)")
        if set(fields) & set(self.dims):
            raise ValueError(f"pointer table {name}: an array named like a dimension: {fields}, {self.dims}")
        for field, _, shape in self.arrays:
            if len(shape) not in (1, 2):
                raise ValueError(f"pointer table {name}: {field} has {len(shape)} dimensions (1 or 2 described)")
        self.names = tuple(scalars) + tuple(f"C_{d.upper()}" for d in self.dims) + tuple(f"P_{f.upper()}" for f in fields)
        self.SLOT = slots(self.names)  # (refuses a name twice, e.g. arrays J and j)
        self._dim_slots = tuple(getattr(self.SLOT, f"C_{d.upper()}") for d in self.dims)
        self._pointer_slots = tuple(getattr(self.SLOT, f"P_{f.upper()}") for f in fields)
        self._index = {f: i for i, f in enumerate(fields)}
        self._dtypes = tuple(np.dtype(dtype) for _, dtype, _ in self.arrays)
        self.View = namedtuple(f"{name.title().replace('_', '')}Views", fields)
        self.View.__doc__ = f"Views of the arrays of the {name} pointer table ({', '.join(fields)})."
        # each array's shape as a function of the dimensions (generated once: a registration calls those of the
        # arrays it registers, no eval per array)
        extents = ["(" + "".join(f"({e}), " for e in shape) + ")" for _, _, shape in self.arrays]
        source = "".join(f"def shape_{i}({', '.join(self.dims)}):\n    return {extent}\n" for i, extent in
                         enumerate(extents))
        namespace = {"__builtins__": {}}
        exec(compile(source, f"<hydraulics.layout.{name}.shapes>", "exec"), namespace)
        self._shape_of = tuple(namespace[f"shape_{i}"] for i in range(len(self.arrays)))
        self.shapes(**{d: 1 for d in self.dims})  # every expression in the dimensions

    def __len__(self):
        return len(self.names)

    def shapes(self, **dims) -> dict[str, tuple[int, ...]]:
        """Each array's shape for the dimensions ``dims`` (every name of :attr:`dims`)."""
        if set(dims) != set(self.dims):
            raise TypeError(f"pointer table {self.name} takes the dimensions {self.dims}, got {sorted(dims)}")
        values = tuple(int(dims[d]) for d in self.dims)
        return {field: shape(*values) for field, shape in zip(self.View._fields, self._shape_of)}

    def viewer_source(self) -> str:
        """Source of ``views(ctx)``: the dimensions read from the table, then each array through
        ``_carray(_cast_<dtype>(address), shape)``, returned as a :attr:`View`."""
        lines = ["def views(ctx):"]
        lines += [f"    {d} = ctx[{getattr(self.SLOT, f'C_{d.upper()}')}]" for d in self.dims]
        for field, dtype, shape in self.arrays:
            extent = ", ".join(f"({e})" for e in shape)
            lines.append(f"    {field} = _carray(_cast_{dtype}(ctx[{getattr(self.SLOT, f'P_{field.upper()}')}]), "
                         f"({extent},))")
        lines.append(f"    return _View({', '.join(self.View._fields)})")
        return "\n".join(lines) + "\n"

    def viewer(self, carray, casts: dict):
        """The Python function of :meth:`viewer_source`; ``carray(pointer, shape)`` makes a view of foreign memory
        (``numba.carray``), ``casts[dtype](address)`` the typed pointer of an address."""
        namespace = {"_View": self.View, "_carray": carray, **{f"_cast_{k}": v for k, v in casts.items()}}
        exec(compile(self.viewer_source(), f"<hydraulics.layout.{self.name}.views>", "exec"), namespace)
        function = namespace["views"]
        function.__doc__ = f"The arrays of the {self.name} pointer table as views ({', '.join(self.View._fields)})."
        return function

    def register(self, ctx, arrays: dict, **dims) -> None:
        """Write ``dims`` (some of :attr:`dims`) and the addresses of ``arrays`` (name → numpy array, some of the
        described ones) into the table ``ctx`` (int64, ``len(self)`` entries).  Each array must have its described
        dtype, be C-contiguous and hold as many entries as its described shape for the table's dimensions (those
        given here, the others as ``ctx`` holds them); a ``ValueError`` says which does not.  The caller keeps the
        arrays alive as long as the table is read."""
        unknown = (set(dims) - set(self.dims)) | (set(arrays) - set(self.View._fields))
        if unknown:
            raise TypeError(f"pointer table {self.name}: unknown dimensions or arrays {sorted(unknown)}")
        for d, value in dims.items():
            ctx[getattr(self.SLOT, f"C_{d.upper()}")] = int(value)
        dims = tuple(int(ctx[s]) for s in self._dim_slots)
        for field, array in arrays.items():
            index = self._index[field]
            dtype, shape = self._dtypes[index], self._shape_of[index](*dims)
            size = math.prod(shape)
            if not (isinstance(array, np.ndarray) and array.dtype == dtype and array.flags.c_contiguous
                    and array.size == size):
                raise ValueError(f"pointer table {self.name}: {field} must be a C-contiguous {dtype} array of {size} "
                                 f"entries {shape}, got {getattr(array, 'dtype', type(array))} "
                                 f"{getattr(array, 'shape', '')}")
            ctx[self._pointer_slots[index]] = array.ctypes.data

    def __repr__(self):
        return f"PointerTable({self.name!r}, {self.dims}, {self.View._fields})"


def slots(names: tuple[str, ...]):
    """Named indices 0, 1, ... of the entries of an int64 table, as a named tuple of ints (``slots(NAMES).X`` is the
    index of ``X``); numba reads a global named tuple of ints as constants.  ``len(names)`` is the table's length."""
    if len(set(names)) != len(names):
        raise ValueError(f"a slot name appears twice in {names}")
    return namedtuple("Slots", names)(*range(len(names)))
