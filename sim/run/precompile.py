"""``hydroplant compile``: build numba's disk cache of every compiled kernel, several processes at a time.

The compiled paths (the MuJoCo coupled step, the PBD block/frame/substep kernels, the compiled
hydraulic stepper, the log record filling) are compiled on first use and cached on disk
(``cache=True``); a cold cache costs minutes of single-threaded compilation, which a run, a
benchmark or the test suite would otherwise pay one kernel after another.  This module compiles
them in independent groups, each in its own process (``jobs`` at a time), by taking a few real
steps of the shipped scenes down each path, so the cache holds exactly the signatures the runs
use.  With a warm cache each group only loads its kernels (about a second).

The kernels go to the content-keyed folder :mod:`hydraulics.kernel_cache` chose, compiled for a generic CPU of
the architecture.  Once every group is done the command records the build there (``hydroplant-kernels.json``);
run again while that record covers the requested groups and the kernel sources still have the time stamps numba
checks, it compiles nothing and starts no process.  After a build it removes the folders it had built for
earlier sources of the same installation (no run of it can load them any more).  ``make`` runs it after pip
installs the package, so a first run loads its kernels instead of compiling them.

Groups (each group's kernels depend on each other, so one group is one process):

``mujoco``
    :class:`~sim.plants.mujoco_fast.MujocoPlantFast` on the excavator (the control callback; the
    same kernel serves the implicit, implicit-linear and rosenbrock couplings), a logged run
    (``log_writer._fill_records``), and the per-step :class:`~sim.plants.mujoco.MujocoPlant` with the
    compiled stepper (``_compiled._step_kernel``, ``_linearize_kernel``).
``pbd``
    :class:`~sim.plants.pbd.PbdPlant` on the excavator: the compiled block (``plants/pbd_block``, with
    the frame and the XPBD substep inside), then its variant that carries the articulated responses
    through the substeps (``SolverXPBD.transport_response``: in the same process it reuses the compiled
    callees, a few seconds), and the compiled observations: the longest group (one chain of callers and
    callees), so it is started first.
``xpbd``
    the XPBD solver stepped from Python (``SolverXPBD.step``: the compiled substep on its own) and the PBD plant's
    articulated response (``PbdPlant.articulated``).
``hydraulics``
    the entries Python calls one at a time: every :class:`~hydraulics.network.NetworkModel` evaluation
    (``_compiled.evaluation_entries``) on a network with and without rigid actuators, and the per-step
    :class:`~sim.plants.mujoco.MujocoPlant` with each coupling (the implicit couplings' rules, the explicit
    step, the incompressible and rigid-actuator laws of ``_compiled_rigid``).

    hydroplant compile [--jobs N] [--groups pbd mujoco xpbd]
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from sim.io.examples import example_path

EXCAVATOR = example_path("excavator/dig")


def _mujoco() -> None:
    from sim.plants.mujoco import MujocoPlant
    from sim.plants.mujoco_fast import MujocoPlantFast
    from sim.run.runner import run
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene

    with tempfile.TemporaryDirectory() as tmp, _without_run_announcement():
        run(EXCAVATOR, out=Path(tmp) / "compile.mcap", overrides={"duration": 0.02})  # fast plant + log records
    scene = load_scene(load_scenario(EXCAVATOR))
    MujocoPlantFast(scene).advance(2)
    MujocoPlant(scene).step()  # the compiled stepper's own kernels


@contextlib.contextmanager
def _without_run_announcement():
    """Inside ``hydroplant compile``, the run's own announcement of a first-run compilation (and its advice to run
    ``hydroplant compile``) is noise: its lines are dropped, any other line on stderr is passed on."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            yield
    finally:
        for line in captured.getvalue().splitlines():
            if not line.startswith(("hydroplant: ", "\r", "  compiling: ")) and line.strip():
                print(line, file=sys.stderr)


def _pbd_plant(**options):
    """A PBD plant on the excavator, 60 Hz × 2 substeps (``options``: PbdPlant's path switches)."""
    from sim.plants.pbd import PbdPlant
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene

    scenario = load_scenario(EXCAVATOR).with_overrides(mode="pbd", dt=1 / 60, pbd_substeps=2)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        return PbdPlant(load_scene(scenario), **options)


def _pbd() -> None:
    plant = _pbd_plant()
    plant.advance(2)  # the compiled block
    plant.solver.transport_response = True  # and its variant that carries the responses through the substeps
    plant.advance(2)


def _xpbd() -> None:
    plant = _pbd_plant()
    plant.articulated()
    plant.solver.step(plant.xmodel.state_from_qpos(plant.model.qpos0, np.zeros(plant.model.nv)), plant.dt)


def _evaluations(model) -> None:
    """Every evaluation method of ``model`` once, at its start state."""
    state, control = model.state(), model.control()
    x, p = state.actuator_position, state.node_pressure
    volumes = model.node_volume_at(x, p)
    model.extra_volume(p), model.accumulator_liquid_volume(p[model.accumulator_node]), model.chamber_volumes(x)
    model.volume_position_gradient(x), model.oil_from_pressure(p, x), model.pressure(state.node_oil, x)
    model.effective_bulk_modulus(p, x, volumes), model.chamber_stiffness(p, x, volumes)
    area = model.valve_areas(control.valve_command)
    model.rigid_direction(control.valve_command), model.law_pieces(p)
    flows = model.branch_flows(p, area, control.pump_speed, state.actuator_velocity)
    model.flow_jacobian(flows), model.flow_velocity_gradient(area)
    model.actuator_effort(p, state.actuator_velocity), model.effort_pressure_gradient()


def _hydraulics() -> None:
    from sim.plants.mujoco import MujocoPlant
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene

    scenario = load_scenario(EXCAVATOR)
    for fidelity in ({}, {"actuator_fidelity": {"boom_cyl": "incompressible"}}):
        for coupling in ("implicit", "implicit-linear", "rosenbrock", "explicit"):
            plant = MujocoPlant(load_scene(scenario.with_overrides(coupling=coupling, **fidelity)))
            plant.step()
        _evaluations(plant.network)
    MujocoPlant(load_scene(scenario.with_overrides(fidelity="incompressible"))).step()


GROUPS = {"pbd": _pbd, "mujoco": _mujoco, "xpbd": _xpbd, "hydraulics": _hydraulics}  # in the order they are started


def _compile_group(name: str) -> float:
    """Run one group's workload in this process; its wall time [s]."""
    start = time.perf_counter()
    GROUPS[name]()
    return time.perf_counter() - start


def precompile(groups=tuple(GROUPS), jobs: int | None = None) -> dict[str, float]:
    """Compile (or load) the kernels of ``groups``, ``jobs`` processes at a time (default: one per group, at most
    the CPU count); returns {group: wall time [s]}.  Each group runs in a fresh process (``spawn``), so the
    kernels end up in numba's disk cache, not only in this process."""
    unknown = sorted(set(groups) - set(GROUPS))
    if unknown:
        raise ValueError(f"unknown kernel groups {unknown}; allowed: {sorted(GROUPS)}")
    jobs = max(1, min(len(groups), jobs or os.cpu_count() or 1))
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
        futures = {name: pool.submit(_compile_group, name) for name in groups}
        return {name: future.result() for name, future in futures.items()}


def add_parser(subparsers) -> None:
    """Register ``hydroplant compile`` (declared in :func:`sim.commands.add_compile`)."""
    from sim.commands import add_compile

    add_compile(subparsers)


def main(args) -> int:
    from hydraulics import kernel_cache

    cache = kernel_cache.CURRENT
    where = cache.folder or "numba's default cache"
    if kernel_cache.fits(cache, args.groups):
        print(f"kernels ready: {', '.join(args.groups)} (built for these sources in {where}; nothing to compile)")
        return 0
    start = time.perf_counter()
    times = precompile(args.groups, args.jobs)
    kernel_cache.write_manifest(cache, args.groups)
    for folder in kernel_cache.superseded(cache):  # built by this command for older sources of this installation
        shutil.rmtree(folder, ignore_errors=True)
        print(f"removed the kernel cache of earlier sources {folder}")
    print("kernels ready: " + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in times.items())
          + f" (wall {time.perf_counter() - start:.1f} s, {cache.cpu} CPU, in {where})")
    return 0
