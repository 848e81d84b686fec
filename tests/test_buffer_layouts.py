"""Flat buffers between Python and the compiled kernels are described once (:mod:`hydraulics.layout`).

* The sources hold no hand-counted table: no tuple unpacked from ``range(<int literal>)``, no chain of calls that
  thread an offset through a buffer (``x, o = take(W, o, n)``), no size function that sums its own terms.
* Every described buffer (:class:`hydraulics.layout.Layout` in the kernel modules): its fields' offsets run
  contiguously from 0 to its size, the generated views cover each entry exactly once with the described shapes, and
  the generated carver and sizer agree with them.
* The sizes the kernels and plants use are the layouts' sizes: ``_compiled.work_size`` of a packed network, the fast
  MuJoCo plant's scratch and pointer table, the PBD buffers, the recorded row's width; the Python ``record_row``
  writes each field where the layout puts it.
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
        "PLANT_SCRATCH", "KEEP", "RECORD_ROW"])


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
    assert plant._ctx.size == F.NCTX == len(F.CTX_SLOTS) and list(F.SLOT) == list(range(F.NCTX))
    assert plant._ctx[F.SLOT.C_NS] == plant._scratch.size and plant._ctx[F.SLOT.P_SCRATCH] == plant._scratch.ctypes.data
    m = plant.model
    row_dims = dict(n=n, nq=m.nq, nv=m.nv, na=na, nvalve=len(net.valve_names), nstate=dims["nvalve"],
                    npump=len(net.pump_names), nb=nb, nbody=m.nbody, nctl=plant.controller_state.shape[0])
    assert plant.record_width == RECORD_ROW.size(**row_dims)

    pbd = PbdPlant(load_scene(scenario.with_overrides(mode="pbd", dt=1 / 60, pbd_substeps=10)), block=True)
    assert pbd.fast
    buffers = H.NetworkBuffers(pbd)
    assert buffers.buffers.S.size == H.KEEP.size(**_plant_dims(pbd.network))
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
