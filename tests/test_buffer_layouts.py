"""Flat buffers between Python and the compiled kernels are described once (:mod:`hydraulics.layout`).

* The sources hold no hand-counted table: no tuple unpacked from ``range(<int literal>)``, no chain of calls that
  thread an offset through a buffer (``x, o = take(W, o, n)``), no size function that sums its own terms.
* Every described buffer (:class:`hydraulics.layout.Layout` in the kernel modules): its fields' offsets run
  contiguously from 0 to its size, the generated views cover each entry exactly once with the described shapes, and
  the generated carver and sizer agree with them.
* The sizes the kernels and plants use are the layouts' sizes: ``_compiled.work_size`` of a packed network, the fast
  MuJoCo plant's scratch and pointer table, the PBD buffers, the recorded row's width; the Python ``record_row``
  writes each field where the layout puts it.
* The modules that pass buffers by address or as flattened tables (the fast MuJoCo plant, the PBD block, the coupling
  tables) hold no hand-laid view or table (:func:`hand_laid`); the fast plant's generated pointer-table views are the
  arrays it registers (address, shape, item size); the coupling tables round-trip through their layouts.
"""

from __future__ import annotations

import ast
import itertools
from pathlib import Path

import numpy as np
import pytest

from conftest import MODELS

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("hydraulics", "sim", "bench")


def _sources():
    for folder in SCANNED:
        yield from sorted((ROOT / folder).rglob("*.py"))


def _is_int_literal(node) -> bool:
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        node = node.operand
    return isinstance(node, ast.Constant) and type(node.value) is int


def _terms(node) -> int:
    """Number of terms of a chain of + and - (1 for anything else)."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub)):
        return _terms(node.left) + _terms(node.right)
    return 1


def hand_counted(source: str) -> list[tuple[int, str]]:
    """(line, what) of every hand-counted table in ``source``: a tuple unpacked from ``range`` of integer literals,
    an assignment ``(..., o) = f(W, o, count, ...)`` threading an offset ``o`` through a buffer ``W``, and a function named
    ``*size*``/``*width*`` returning a sum of three or more terms."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], (ast.Tuple, ast.List)):
            target, value = node.targets[0], node.value
            if (isinstance(value, ast.Call) and isinstance(value.func, ast.Name) and value.func.id == "range"
                    and value.args and all(_is_int_literal(a) for a in value.args)):
                found.append((node.lineno, f"{len(target.elts)} names unpacked from range(<int literal>)"))
            if isinstance(value, ast.Call) and target.elts and isinstance(target.elts[-1], ast.Name):
                offset = target.elts[-1].id  # take(buffer, offset, count, ...): the offset is the second argument
                if len(value.args) >= 3 and isinstance(value.args[1], ast.Name) and value.args[1].id == offset:
                    found.append((node.lineno, f"offset {offset!r} threaded through a call"))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and ("size" in node.name or "width" in node.name):
            for inner in ast.walk(node):
                if isinstance(inner, ast.Return) and inner.value is not None and _terms(inner.value) >= 3:
                    found.append((inner.lineno, f"{node.name} returns a hand-written sum"))
    return found


def test_the_checker_finds_hand_counted_tables():
    """The checker itself: each kind of hand-counted table is found, the generated forms are not."""
    bad = """
(A, B, C) = range(3)
(I_X, I_Y) = range(6, 8)
def carve(W, n):
    o = 0
    a, o = take(W, o, n)
    b, o = take2(W, o, n, 3)
def scratch_size(n, na, nb):
    return 4 * na + 6 * n + nb
"""
    assert sorted(line for line, _ in hand_counted(bad)) == [2, 3, 6, 7, 9]
    good = """
NAMES = ("a", "b", "c")
A, B, C = range(len(NAMES))
ws, _ = carve(W, 0, n, na)
def scratch_size(n, na, nb):
    return LAYOUT.size(n=n, na=na, nb=nb)
def record_width(self):
    return max(a, b) + 1
"""
    assert hand_counted(good) == []


def test_no_hand_counted_table_in_the_sources():
    """No source of the packages or the benches lays a buffer or a table out by hand (see :func:`hand_counted`)."""
    found = [f"{path.relative_to(ROOT)}:{line}: {what}" for path in _sources()
             for line, what in hand_counted(path.read_text(encoding="utf-8"))]
    assert not found, "hand-counted tables (describe them with hydraulics.layout):\n" + "\n".join(found)


def _layouts():
    from hydraulics import _compiled, _compiled_rigid
    from hydraulics.layout import Layout
    from sim.io import record_row
    from sim.plants import mujoco_fast, pbd_hydraulics

    out, seen = {}, set()
    for module in (_compiled, _compiled_rigid, mujoco_fast, pbd_hydraulics, record_row):
        for name, value in vars(module).items():
            if isinstance(value, Layout) and id(value) not in seen:  # (a layout imported elsewhere counted once)
                seen.add(id(value))
                out[f"{module.__name__}.{name}"] = value
    return out


def test_every_kernel_buffer_is_described():
    """The buffers the kernels carve are all found as layouts (a module that stops describing one fails here)."""
    assert sorted(k.rsplit(".", 1)[1] for k in _layouts()) == sorted([
        "SOLVE_SCRATCH", "STEP_SCRATCH", "LINEARIZE_SCRATCH", "ONE_STEP_SCRATCH", "LINEAR_FINISH_SCRATCH",
        "EXPLICIT_SCRATCH", "MIXED_LAW_SCRATCH", "EXPLICIT_LAW_SCRATCH", "RIGID_LAW_SCRATCH", "RIGID_FINISH_SCRATCH",
        "PLANT_SCRATCH", "KEEP", "RECORD_ROW", "INCOMPRESSIBLE_FLOATS", "INCOMPRESSIBLE_INTS", "RIGID_FLOATS",
        "RIGID_INTS"])


@pytest.mark.parametrize("name", sorted(_layouts()))
def test_layout_offsets_are_contiguous_and_views_cover_the_buffer(name):
    """For several dimensions (zeros included): offsets contiguous from 0 to the size, every entry in exactly one
    view of the described shape, the generated carver's views and end offset and the generated sizer the same."""
    layout = _layouts()[name]
    rng = np.random.default_rng(7)
    choices = [{d: 0 for d in layout.dims}, {d: 1 for d in layout.dims}]
    choices += [{d: int(rng.integers(0, 9)) for d in layout.dims} for _ in range(6)]
    for dims in choices:
        size = layout.size(**dims)
        offsets = layout.offsets(**dims)
        assert list(offsets) == list(layout.names)
        stops = [0] + [stop for _, stop in offsets.values()]
        assert [start for start, _ in offsets.values()] == stops[:-1], f"{name}: offsets not contiguous for {dims}"
        assert stops[-1] == size
        assert layout.sizer()(*(dims[d] for d in layout.dims)) == size
        shapes = layout.shapes(**dims)
        head = 5  # the buffer starts at an offset, as a nested layout does
        buffer = np.full(head + size + 3, -1.0)
        views = layout.views(buffer, head, **dims)
        for i, (field, view) in enumerate(zip(layout.names, views)):
            assert view.shape == shapes[field]
            assert np.all(view == -1.0), f"{name}.{field} overlaps another field for {dims}"
            view[...] = i
        assert np.all(buffer[:head] == -1.0) and np.all(buffer[head + size:] == -1.0)
        assert np.all(buffer[head:head + size] >= 0.0)
        carved, end = layout.carver(lambda a, r, c: a.reshape((r, c)))(buffer, head, *(dims[d] for d in layout.dims))
        assert end == head + size
        for field, a, b in zip(layout.names, carved, views):
            assert a.shape == b.shape and a.ctypes.data == b.ctypes.data and np.array_equal(a, b), f"{name}.{field}"


def test_layout_rejects_ambiguous_descriptions():
    """A field named twice, a field named like a dimension or like the carver's own variables is refused."""
    from hydraulics.layout import Layout

    for dims, fields in ((("n",), (("a", "n"), ("a", "n"))), (("n",), (("n", "n"),)), (("n",), (("o", "n"),)),
                         (("n",), (("W", "n"),))):
        with pytest.raises(ValueError):
            Layout("bad", dims, fields)


def _plant_dims(net):
    return dict(n=net.node_count, na=net.actuator_count, nb=len(net.branch_names), nvalve=net.component_state_count)


def test_plant_buffers_have_the_layouts_sizes():
    """The excavator on the fast MuJoCo plant: the Newton kernels' scratch is the larger of the step's and the
    linearisation's layouts, the plant's scratch is PLANT_SCRATCH, its work buffer holds every layout carved from
    it, the pointer table has one entry per named slot, the record width is RECORD_ROW's; on the PBD plant the
    persistent buffer is KEEP and the record width RECORD_ROW's."""
    from hydraulics import _compiled as C
    from hydraulics import _compiled_rigid as K
    from sim.io.record_row import RECORD_ROW
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants import mujoco_fast as F
    from sim.plants import pbd_hydraulics as H
    from sim.plants.pbd import PbdPlant

    scenario = load_scenario(MODELS / "excavator" / "dig.scenario.toml")
    plant = F.MujocoPlantFast(load_scene(scenario))
    assert plant.fast
    net = plant.network
    dims = _plant_dims(net)
    ic = C._unpack(plant._F, plant._I).ic
    nf, narea = int(ic[C.IC_NF]), int(C._area_count(ic))
    njq, nlu = int(ic[C.IC_NJQ]), int(ic[C.IC_NLU])
    n, na, nb = dims["n"], dims["na"], dims["nb"]
    solve = C.SOLVE_SCRATCH.size(n=n, nb=nb, nf=nf, narea=narea, nlu=nlu)
    step = C.STEP_SCRATCH.size(nsolve=solve, n=n)
    linearize = C.LINEARIZE_SCRATCH.size(nsolve=solve, n=n, na=na, nb=nb, nf=nf, narea=narea, njq=njq, nlu=nlu)
    assert C.work_size(plant._F, plant._I) == max(step, linearize)
    assert C.ONE_STEP_SCRATCH.size(n=n, na=na, nb=nb, nf=nf, narea=narea, njq=njq, nlu=nlu) <= linearize
    assert C.LINEAR_FINISH_SCRATCH.size(n=n, narea=narea) <= solve
    assert int(K.explicit_work_size(ic)) == K.EXPLICIT_SCRATCH.size(n=n, narea=narea)
    assert plant._scratch.size == F.PLANT_SCRATCH.size(**dims)
    nr = len(net.rigid_branch_actuator)
    for needed in (step, linearize, K.EXPLICIT_SCRATCH.size(n=n, narea=narea), K.EXPLICIT_LAW_SCRATCH.size(na=na),
                   K.RIGID_LAW_SCRATCH.size(nr=nr, n=n, nmixed=K.MIXED_LAW_SCRATCH.size(na=na)),
                   K.RIGID_FINISH_SCRATCH.size(na=na)):
        assert plant._work.size >= needed
    assert plant._ctx.size == F.NCTX == len(F.POINTERS) and list(F.SLOT) == list(range(F.NCTX))
    assert plant._ctx[F.SLOT.C_NS] == plant._scratch.size and plant._ctx[F.SLOT.P_S] == plant._scratch.ctypes.data
    m = plant.model
    row_dims = dict(n=n, nq=m.nq, nv=m.nv, na=na, nvalve=len(net.valve_names), nstate=dims["nvalve"],
                    npump=len(net.pump_names), nb=nb, nbody=m.nbody, nctl=plant.controller_state.shape[0])
    assert plant.record_width == RECORD_ROW.size(**row_dims)

    pbd = PbdPlant(load_scene(scenario.with_overrides(mode="pbd", dt=1 / 60, pbd_substeps=10)), block=True)
    assert pbd.fast
    buffers = H.NetworkBuffers(pbd)
    pdims = _plant_dims(pbd.network)
    assert buffers._S.size == H.KEEP.size(**pdims)
    offsets, base = H.KEEP.offsets(**pdims), buffers._S.ctypes.data
    for name, view in zip(H.KEEP.names, buffers.buffers.keep):  # the kernels' views tile S at the layout's offsets
        start, stop = offsets[name]
        assert view.ctypes.data == base + start * buffers._S.itemsize and view.size == stop - start
    assert buffers.buffers.istats.size == H.NI == C.NIS + len(H.TOTALS)
    nj = len(pbd.scalar_joints)
    assert pbd.record_width == RECORD_ROW.size(**{**row_dims, "nq": nj, "nv": nj, "nbody": pbd.xmodel.nbody})


def test_record_row_writes_each_field_where_the_layout_puts_it():
    """The fast MuJoCo plant's Python ``record_row`` after a few steps: each RECORD_ROW field of the row holds the
    quantity the layout names (node pressures, qpos, qvel, actuator positions, spools, body poses, energy terms)."""
    from sim.io.record_row import RECORD_ROW
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants.mujoco_fast import MujocoPlantFast

    plant = MujocoPlantFast(load_scene(load_scenario(MODELS / "boom" / "lift.scenario.toml")))
    assert plant.advance(50).success
    row = np.full(plant.record_width, np.nan)
    plant.record_row(row)
    net, m, d = plant.network, plant.model, plant.data
    r = RECORD_ROW.views(row, n=net.node_count, nq=m.nq, nv=m.nv, na=net.actuator_count, nvalve=len(net.valve_names),
                         nstate=net.component_state_count, npump=len(net.pump_names), nb=len(net.branch_names),
                         nbody=m.nbody, nctl=plant.controller_state.shape[0])
    state = plant.net_state
    assert np.array_equal(r.p, state.node_pressure) and np.array_equal(r.oil, state.node_oil, equal_nan=True)
    assert np.array_equal(r.qpos, d.qpos) and np.array_equal(r.qvel, d.qvel)
    assert np.array_equal(r.x, state.actuator_position) and np.array_equal(r.v, state.actuator_velocity)
    assert np.array_equal(r.spool, state.valve_spool)
    assert np.array_equal(r.xpos, d.xpos) and np.array_equal(r.xquat, d.xquat)
    kinetic, potential = plant.mechanical_energy()
    assert r.energy[0] == kinetic and r.energy[1] == potential and r.energy[2] == plant.energy.pump_work
    assert np.max(np.abs(r.p)) > 1e5 and np.max(np.abs(r.x)) > 0  # pressurised, moved: real values compared


def test_slots_are_named_indices():
    """``slots`` numbers the names in order and refuses a repeated name."""
    from hydraulics.layout import slots

    s = slots(("A", "B", "C"))
    assert (s.A, s.B, s.C) == (0, 1, 2) and len(s) == 3
    with pytest.raises(ValueError):
        slots(("A", "A"))
    assert list(itertools.islice(s, 2)) == [0, 1]


# ---------------------------------------------------------------------------- pointer tables and split tables
HAND_LAID_MODULES = ("sim/plants/mujoco_fast.py", "sim/plants/pbd_block.py", "hydraulics/_compiled_rigid.py")
"""The modules whose buffers cross between Python and the kernels by address or as flattened tables."""


def _names(node) -> set[str]:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}


def _literal_multiple(node) -> bool:
    """``<int literal ≥ 2> * <expression>`` (either order)."""
    return (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult)
            and any(_is_int_literal(side) and abs(side.value) >= 2 for side in (node.left, node.right)))


def _outside_indices(node):
    """``node`` and the nodes below it, not entering an index (``a[...]``)."""
    yield node
    if not isinstance(node, ast.Subscript):
        for child in ast.iter_child_nodes(node):
            yield from _outside_indices(child)


def hand_laid(source: str) -> list[tuple[int, str]]:
    """(line, what) of every hand-laid view or pointer table in ``source``: a named tuple of views written out
    (``namedtuple("...View...", ...)``), a view made by hand from a pointer-table entry (``carray(...ctx[...]...)``), a
    buffer carved by hand (``W[o:o + n]``: start and stop from the same offset), an int64 table of a literal size
    (``np.zeros(<int literal>, np.int64)``), and a size summed by hand from multiples of dimensions
    (``8 * na + 3``, outside an index)."""
    found = []
    tree = ast.parse(source)
    indices = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript):
            indices.update(id(n) for n in ast.walk(node.slice))
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            name = node.func.id if isinstance(node.func, ast.Name) else getattr(node.func, "attr", "")
            if (name == "namedtuple" and node.args and isinstance(node.args[0], ast.Constant)
                    and "View" in str(node.args[0].value)):
                found.append((node.lineno, f"named tuple of views {node.args[0].value!r} written out"))
            if name.endswith("carray") and any(isinstance(n, ast.Subscript) and isinstance(n.value, ast.Name)
                                               and n.value.id == "ctx" for a in node.args for n in ast.walk(a)):
                found.append((node.lineno, "view of a pointer-table entry made by hand"))
            if (name in ("zeros", "empty", "full") and node.args and _is_int_literal(node.args[0])
                    and any("int64" in ast.unparse(a) for a in node.args[1:] + [k.value for k in node.keywords])):
                found.append((node.lineno, "int64 table of a literal size"))
        if isinstance(node, ast.Slice) and node.lower is not None and node.upper is not None:
            if (isinstance(node.upper, ast.BinOp) and isinstance(node.upper.op, ast.Add)
                    and _names(node.lower) & _names(node.upper)):
                found.append((node.lineno, f"slice {ast.unparse(node)} carved by hand"))
        if (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add) and id(node) not in indices
                and any(_literal_multiple(n) for n in _outside_indices(node))):
            found.append((node.lineno, f"size {ast.unparse(node)} summed by hand"))
    return sorted(set(found))


def test_the_checker_finds_hand_laid_views_and_tables():
    """The checker itself: each kind of hand-laid view or table is found, the generated and the indexing forms are
    not."""
    bad = """
_Views = namedtuple("_Views", ("fs", "J"))
V = _Views(_vf(ctx, SLOT.P_FS, 8), carray(_pf64(ctx[SLOT.P_J]), (na, nv)))
T = Table(TF[o:o + na], TF[o + na:o + 2 * na])
ctx = np.zeros(90, np.int64)
nf = max(8 * na + 3, 2 * na + 6 * nr + 3)
"""
    assert sorted({line for line, _ in hand_laid(bad)}) == [2, 3, 4, 5, 6]
    good = """
V = _views(ctx)
ctx = np.zeros(len(POINTERS), np.int64)
force = bias[act[i] * nbias + 2] + frange[2 * a + 1]
rows = cmd[k * substeps:(k + 1) * substeps]
nf, ni = K.table_sizes(na, nr)
row = carray(_pf64(address), (n,))
"""
    assert hand_laid(good) == []


@pytest.mark.parametrize("module", HAND_LAID_MODULES)
def test_no_hand_laid_view_or_pointer_table(module):
    """The fast MuJoCo plant, the PBD block and the coupling tables' module view their buffers only through generated
    layouts (:class:`hydraulics.layout.Layout`, :class:`hydraulics.layout.PointerTable`, see :func:`hand_laid`)."""
    found = [f"{module}:{line}: {what}" for line, what in hand_laid((ROOT / module).read_text(encoding="utf-8"))]
    assert not found, "hand-laid views or tables (describe them with hydraulics.layout):\n" + "\n".join(found)


def _casts():
    import ctypes

    types = {"float64": ctypes.c_double, "int64": ctypes.c_int64, "int32": ctypes.c_int32, "bool": ctypes.c_uint8}
    return {k: (lambda t: lambda address: ctypes.cast(int(address), ctypes.POINTER(t)))(t) for k, t in types.items()}


def _pointer_table_views(plant):
    """The plant's pointer table read back through the generated viewer (run as Python on ctypes pointers)."""
    from numba import carray

    from sim.plants import mujoco_fast as F

    viewer = F.POINTERS.viewer(lambda p, shape: carray(p, shape) if p else None, _casts())
    return viewer(plant._ctx)


@pytest.mark.parametrize("name, overrides, coupling", [
    ("excavator/implicit", {}, None),
    ("excavator/rigid-front", {"actuator_fidelity": {"stick_cyl": "incompressible", "bucket_cyl": "incompressible",
                                                      "swing_motor": "incompressible"}}, None),
    ("excavator/incompressible", {}, "incompressible"),
])
def test_pointer_table_views_are_the_registered_arrays(name, overrides, coupling):
    """The fast MuJoCo plant's pointer table after two blocks: the generated views (:data:`mujoco_fast.POINTERS`) are the
    arrays the plant registered (same address, described shape, same item size), every described array but the
    record is registered, the dimensions are the model's, and a wrong array is refused at registration."""
    from hydraulics import _compiled as C
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants import mujoco_fast as F

    scenario = load_scenario(MODELS / "excavator" / "dig.scenario.toml")
    if overrides:
        scenario = scenario.with_overrides(**overrides)
    plant = F.MujocoPlantFast(load_scene(scenario), coupling=coupling)
    assert plant.fast
    assert plant.advance(3).success and plant.advance(2).success
    ctx, m, d, net = plant._ctx, plant.model, plant.data, plant.network
    dims = {dim: int(ctx[getattr(F.SLOT, f"C_{dim.upper()}")]) for dim in F.POINTERS.dims}
    assert dims["na"] == net.actuator_count and dims["nv"] == m.nv and dims["nu"] == m.nu and dims["n"] == net.node_count
    assert dims["nstate"] == int(C._unpack(plant._F, plant._I).ic[C.IC_NSTATE]) == net.component_state_count
    assert dims["nnz"] == d.actuator_moment.size == d.moment_colind.size and dims["nbody"] == m.nbody
    shapes = F.POINTERS.shapes(**dims)
    registered = {**plant._keep, "cmd": plant._cmd, "speed": plant._speed, "ctl_set": plant._setpoint}
    assert set(registered) == set(F.POINTERS.View._fields) - {"rec"}
    views = _pointer_table_views(plant)
    for field, array in registered.items():
        view = getattr(views, field)
        assert view.shape == shapes[field], field
        assert view.ctypes.data == array.ctypes.data and view.dtype.itemsize == array.dtype.itemsize, field
        assert array.size == view.size and array.flags.c_contiguous, field
        assert np.array_equal(view.view(np.uint8).ravel(), array.view(np.uint8).ravel()), field
    with pytest.raises(ValueError):
        F.POINTERS.register(ctx.copy(), {"oil": np.zeros(net.node_count + 1)})
    with pytest.raises(ValueError):
        F.POINTERS.register(ctx.copy(), {"act": np.zeros(net.actuator_count, np.int32)})


def test_coupling_tables_round_trip_through_their_layouts():
    """The incompressible and rigid tables of the excavator (three rigid actuators): flattened into the padded
    arrays of :func:`table_sizes` (the larger of the two layouts), carved back by the generated carvers field by field
    equal, each flattened field where its layout puts it, and the padding 0 (floats) and −1 (ints)."""
    from hydraulics import _compiled_rigid as K
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants.mujoco import MujocoPlant

    rigid = {"stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"}
    scenario = load_scenario(MODELS / "excavator" / "dig.scenario.toml").with_overrides(actuator_fidelity=rigid)
    net = MujocoPlant(load_scene(scenario)).network
    na, nr = net.actuator_count, len(net.rigid_branch_actuator)
    assert nr > 0
    nf, ni = K.table_sizes(na, nr)
    assert nf == max(K.INCOMPRESSIBLE_FLOATS.size(na=na), K.RIGID_FLOATS.size(na=na, nr=nr))
    assert ni == max(K.INCOMPRESSIBLE_INTS.size(na=na), K.RIGID_INTS.size(na=na, nr=nr))
    for table, flatten, unflatten, layouts, dims in (
            (K.pack_incompressible(net), K.flatten_incompressible, K.unflatten_incompressible,
             (K.INCOMPRESSIBLE_FLOATS, K.INCOMPRESSIBLE_INTS), dict(na=na)),
            (K.pack_rigid(net), K.flatten_rigid, K.unflatten_rigid, (K.RIGID_FLOATS, K.RIGID_INTS), dict(na=na, nr=nr))):
        assert sorted(layouts[0].names + layouts[1].names) == sorted(type(table)._fields)
        TF, TI = flatten(table, (nf, ni))
        assert TF.dtype == np.float64 and TI.dtype == np.int64 and (TF.size, TI.size) == (nf, ni)
        back = unflatten(TF, TI, *dims.values())
        for field in type(table)._fields:
            assert np.array_equal(np.asarray(getattr(back, field)), np.asarray(getattr(table, field))), field
        for layout, flat, pad in zip(layouts, (TF, TI), (0.0, -1)):
            for field, (start, stop) in layout.offsets(**dims).items():
                assert np.array_equal(flat[start:stop], np.ravel(getattr(table, field))), field
            assert np.all(flat[layout.size(**dims):] == pad)
        exact = flatten(table)
        assert (exact[0].size, exact[1].size) == (layouts[0].size(**dims), layouts[1].size(**dims))


def test_pointer_table_rejects_ambiguous_descriptions():
    """An array named like a dimension, twice (slot names equal up to case), or with three dimensions is refused;
    an expression in an unknown dimension fails at description."""
    from hydraulics.layout import PointerTable

    for dims, arrays in ((("n",), (("n", "float64", "n"),)), (("n",), (("a", "float64", "n"), ("A", "int64", "n"))),
                         (("n",), (("a", "float64", "n", "n", "n"),)), (("n",), (("ctx", "float64", "n"),))):
        with pytest.raises(ValueError):
            PointerTable("bad", (), dims, arrays)
    with pytest.raises(NameError):
        PointerTable("bad", (), ("n",), (("a", "float64", "m"),))
