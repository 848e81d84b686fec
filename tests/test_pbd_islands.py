"""The PBD plant's islands (``sim.xpbd.compiled.islands``): the articulated response and the cylinder rows' block
are solved island by island, so a frame's work grows linearly in the number of independent machines.

* Structure: N booms side by side (``bench/bench_scaling.py``'s scene, one pump for all or a pump each) are N
  islands of one joint, one row and one rigid group each (the shared hydraulics join no mechanics); the entries a
  frame visits in the island-wise kernels (row block Σ kᵢ², mass matrix Σ nⱼᵢ², joint-to-body Jacobians and
  responses Σ nⱼᵢ·(nbᵢ + ngᵢ)) are N times those of one boom.
* Equality: island by island gives the same results as the whole blocks (``single_island``: the mechanism as one
  island, the dense elimination over all joints and rows): the articulated data at a pose, and whole runs of
  the block path (body state, actuator motion, node pressures) compared exactly, on the booms and on the
  excavator (one tree, with motors and ground contact).
"""

from __future__ import annotations

import functools
import importlib.util
import warnings
from pathlib import Path

import numpy as np
import pytest

from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.plants.pbd import PbdPlant
from sim.plants.pbd_frame import Articulated
from sim.xpbd.compiled import islands, single_island
from test_pbd_compiled import DIG

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(autouse=True)
def _quiet_xpbd_notes():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        yield


@functools.lru_cache(maxsize=None)
def _scaling_bench():
    spec = importlib.util.spec_from_file_location("bench_scaling", ROOT / "bench" / "bench_scaling.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _booms(tmp_path, n, layout, tag=""):
    """A PBD plant of ``n`` booms (one pump for all: ``layout`` "shared", or a pump each: "each")."""
    bench = _scaling_bench()
    folder = tmp_path / f"{layout}{n}{tag}"
    folder.mkdir()
    return PbdPlant(load_scene(bench.scenario_of(bench.write_scene(folder, n, layout), "pbd")))


def _whole(plant):
    """``plant`` made to solve its mechanism as one island (the whole blocks)."""
    xm = plant.xmodel
    plant._islands_memo = single_island(xm.nbody, xm.ngroup, xm.njnt, len(plant.cylinders), len(plant.motors))
    for made_once in ("_articulated_ctx", "_frame_ctx", "_block_ctx"):  # rebuilt with the one island
        plant.__dict__.pop(made_once, None)
    return plant


def _visits(isl):
    """Entries the island-wise kernels visit per frame: row block, mass matrix, Jacobians and responses."""
    total = 0
    for i in range(len(isl.joint_ptr) - 1):
        k = isl.row_ptr[i + 1] - isl.row_ptr[i]
        nj = isl.joint_ptr[i + 1] - isl.joint_ptr[i]
        nb = isl.body_ptr[i + 1] - isl.body_ptr[i]
        ng = isl.group_ptr[i + 1] - isl.group_ptr[i]
        total += k * k + nj * nj + nj * (nb + ng) + (k + 1) * ng
    return int(total)


@pytest.mark.parametrize("layout", ["shared", "each"])
def test_booms_are_islands_of_bounded_size(tmp_path, layout):
    one = _booms(tmp_path, 1, layout)._islands()
    for n in (4, 16):
        plant = _booms(tmp_path, n, layout)
        isl = plant._islands()
        assert len(isl.joint_ptr) - 1 == n
        assert np.all(np.diff(isl.joint_ptr) == 1) and np.all(np.diff(isl.row_ptr) == 1)
        assert np.all(np.diff(isl.group_ptr) == 1) and np.all(np.diff(isl.body_ptr) == 2)
        assert _visits(isl) == n * _visits(one)
        # every row's and joint's bodies lie in its island: the dense articulated mobility is zero elsewhere
        plant.articulated()
        mob = plant._mobility
        for i in range(n):
            row = isl.rows[isl.row_ptr[i]]
            groups = isl.groups[isl.group_ptr[i]:isl.group_ptr[i + 1]]
            outside = np.delete(mob[row], groups, axis=0)
            assert not np.any(outside), f"row {row} moves groups outside island {i}"


def test_islands_of_a_chain_with_a_cross_row():
    """Two trees joined by a row are one island; a row on static bodies only is an island of its own."""
    #        world ─ 1 ─ 2       world ─ 3        (bodies 1, 2 in group 1, body 3 in group 2)
    isl = islands([0, 0, 1, 0], [0, 1, 1, 2], [1, 3], [[2, 3], [0, 0]], [1])
    assert isl.joint_ptr.tolist() == [0, 2, 2] and isl.joints.tolist() == [0, 1]
    assert isl.bodies.tolist() == [1, 2, 3] and isl.groups.tolist() == [1, 2]
    assert isl.row_ptr.tolist() == [0, 1, 2] and isl.rows.tolist() == [0, 1]
    assert isl.motors.tolist() == [0] and isl.joint_island.tolist() == [0, 0]


def _articulated_at(plant, x, q):
    ctx = plant._articulated_context()
    out = Articulated(*(np.zeros_like(getattr(ctx["articulated"], f)) for f in Articulated._fields))
    assert ctx["articulated_kernel"](x, q, ctx["articulated_model"], out)
    return out


@pytest.mark.parametrize("layout", ["shared", "each"])
def test_articulated_by_island_equals_whole(tmp_path, layout):
    plant = _booms(tmp_path, 6, layout)
    whole = _whole(_booms(tmp_path, 6, layout, "whole"))
    plant.advance(50)  # a pose off the initial one, the booms lifting
    st = plant.state
    x, q = np.ascontiguousarray(st.x, np.float64), np.ascontiguousarray(st.q, np.float64)
    a, b = _articulated_at(plant, x, q), _articulated_at(whole, x, q)
    for name in Articulated._fields:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def _run_equal(a, b, steps, block):
    for _ in range(steps // block):
        ra, rb = a.advance(block), b.advance(block)
        assert ra.success and rb.success
    for name in ("x", "q", "v", "w"):
        assert np.array_equal(getattr(a.state, name), getattr(b.state, name)), name
    assert np.array_equal(a._x, b._x) and np.array_equal(a._v, b._v)
    assert np.array_equal(a.net_state.node_pressure, b.net_state.node_pressure)


@pytest.mark.parametrize("layout", ["shared", "each"])
def test_booms_run_by_island_equals_whole(tmp_path, layout):
    a = _booms(tmp_path, 6, layout)
    b = _whole(_booms(tmp_path, 6, layout, "whole"))
    _run_equal(a, b, 300, 50)


def test_excavator_run_by_island_equals_whole():
    scenario = load_scenario(DIG).with_overrides(mode="pbd", dt=1 / 60, pbd_substeps=10)
    a = PbdPlant(load_scene(scenario))
    b = _whole(PbdPlant(load_scene(scenario)))
    _run_equal(a, b, 120, 30)  # through the teeth's first ground contact (≈ 1.6 s)
