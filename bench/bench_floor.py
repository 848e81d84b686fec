"""The floor of an implicit coupled step: the network's building blocks against bare ``mj_step``, in one run.

Any implicit coupling of the hydraulics with MuJoCo (``implicit``, ``implicit-linear``,
``rosenbrock``) does, per step, at least: one evaluation of the network at the
step's end (every node's pressure from its oil content, every branch law's flow
and slopes, the nodes' net inflows), one factorisation of the Newton matrix
I − h·∂Q/∂m with its solve for the coupling's right-hand sides (the oil increment
and its sensitivity to each actuator's velocity).  This bench times those pieces of the
compiled kernels (``hydraulics._compiled``) in a compiled loop, with no Python
and no MuJoCo between calls, at the network states of the scene's own scenario
every ``--every`` seconds of its first ``--window`` seconds at 1 kHz (their mean),
and in the same run a bare ``mj_step`` loop over that window on the scene's MJCF
at the constant controls of ``bench_fast.py``'s ``bare`` (the effort law of the
plant's first step held), in alternation, ``--reps``
times (medians).

It prints each piece in µs and as a fraction of the bare step, and the floor
ratio (bare + evaluation + factorisation) / bare: what the coupled step would
cost if everything else (moments, M⁻¹·Jᵀ, effort law, energy ledger, Newton
iterations beyond the first) were free and the end-of-step pressures were the
next step's start evaluation; and the same with the end pressures inverted
separately, as the implicit couplings do (their next step starts at MuJoCo's
integrated positions, not at the linearisation's; ``rosenbrock`` ends its step there).
A second line times the pieces of a ``rosenbrock`` step in the same way: its one-step
linearisation (``_compiled._linearize_one_step_core``: start evaluation, gradients,
one elimination, effort gradient), the same with the start evaluation known (MuJoCo
mode, where the previous step's end evaluation is it), the same again keeping the previous step's end flows
of the branches whose arguments did not change (``known`` 2, as MuJoCo mode runs it: the valve commands of the plant's
last step, the valve areas at the step before's end spools, which are this step's start), its linear finish (end
pressures and flows) and the energy ledger.  Run: ``.venv/bin/python bench/bench_floor.py``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco
import numba
import numpy as np

import hydraulics._compiled as C
from sim.plants.mujoco_fast import MujocoPlantFast
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene

from hydraulics.fluid import POTENTIAL_QUADRATURE_POINTS

from bench_fast import DT, SCENES, bare_start  # the same scenes, step and bare loop as bench_fast.py

PIECES = ("pressures", "flows", "evaluation", "factorisation")
PRESSURES, FLOWS, EVALUATION, FACTORISATION = range(len(PIECES))
# the pieces of a rosenbrock step (hydraulics.coupling): its one-step linearisation, the same at a known start
# evaluation (MuJoCo mode: the previous step's end), its linear finish and the energy ledger
STEP_PIECES = ("one-step", "one-step known", "one-step kept", "linear finish", "ledger")
ONE_STEP, ONE_STEP_KNOWN, ONE_STEP_KEPT, LINEAR_FINISH, LEDGER = range(len(PIECES), len(PIECES) + len(STEP_PIECES))


@numba.njit(cache=True)
def _time_piece(F, I, oil, x, v, spool, speed, cmd, piece, reps):
    """Run one building block ``reps`` times on the packed network (F, I) at (oil, x, v, spool, speed); returns a
    checksum of its outputs (so that nothing is optimised away).  ``cmd``: valve commands (the kept one-step
    linearisation's; the other pieces hold the spools)."""
    net = C._unpack(F, I)
    pnet = C._ref(net)
    n, nb, nf, na = net.ic[C.IC_N], net.ic[C.IC_NB], net.ic[C.IC_NF], x.size
    area = np.empty(net.ic[C.IC_O1] - net.ic[C.IC_O0])
    geo, p, dpdm, inflow = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    flow, dflow = np.empty(nb), np.empty((nb, C._W_BR))  # flow derivatives: branches × terminals
    residual = np.empty(nf)
    jac = np.empty((nf, nf))
    lu, saved = np.empty(net.ic[C.IC_NLU]), np.empty(net.ic[C.IC_NLU])
    rhs = np.empty((nf, 1 + na))
    C._valve_areas(pnet, spool, area)
    C._evaluate(pnet, oil, oil, x, v, (area, spool), speed, DT, geo, p, dpdm, flow, dflow, inflow, residual)
    W = np.empty(C._linearize_work_size(net.ic))
    start = C.StepStart(oil, spool, spool, speed, x, v)
    out = C.LinearizationOut(np.empty(n), np.empty(n), np.empty(spool.size), np.empty(na), np.empty(nb),
                             np.zeros(6, np.int64), np.empty(na), np.empty((na, na)), p.copy(), np.empty((n, na)))
    ledger, quad, mu = np.zeros(8), np.zeros(2 * POTENTIAL_QUADRATURE_POINTS), np.empty(n)
    # the kept linearisation's step before: its valve areas at its end spools (this step's start), its law pieces
    # and end flows at the start pressures
    ic = net.ic
    one, _ = C._one_step_scratch(W, 0, n, na, nb, nf, C._area_count(ic), ic[C.IC_NJQ], ic[C.IC_NLU])
    flow_before, dflow_before = np.empty(nb), np.empty((nb, C._W_BR))
    C._valve_areas(pnet, spool, one.area)
    C._law_pieces(pnet, p, spool, DT, one.pieces)
    C._branch_flows(pnet, p, one.area, speed, v, flow_before, dflow_before, spool, DT)
    kept = C.StepStart(oil, spool, cmd, speed, x, v)
    check = 0.0
    for r in range(reps):
        if piece == ONE_STEP:
            C._linearize_one_step_core(pnet, W, start, DT, out)
            check += out.pressure[n - 1]
        elif piece == ONE_STEP_KNOWN:
            C._linearize_one_step_from(pnet, W, start, DT, out, 1, geo, dpdm, (flow, dflow, speed))
            check += out.pressure[n - 1]
        elif piece == ONE_STEP_KEPT:
            C._valve_areas(pnet, spool, one.area)  # (the step before's finish left them; the linearisation moves them)
            C._linearize_one_step_from(pnet, W, kept, DT, out, 2, geo, dpdm, (flow_before, dflow_before, speed))
            check += out.pressure[n - 1]
        elif piece == LINEAR_FINISH:
            C._linear_finish(pnet, W, oil, spool, x, v, speed, p, flow, dflow, DT)
            check += p[n - 1]
        elif piece == LEDGER:
            C._account(pnet, ledger, 2, DT, p, x, flow, v, quad, mu, geo, dpdm)
            check += ledger[4]
        elif piece == PRESSURES:
            C._pressure(pnet, oil, x, geo, p, dpdm)
            check += p[n - 1]
        elif piece == FLOWS:
            C._branch_flows(pnet, p, area, speed, v, flow, dflow, spool, DT)
            C._net_inflow(pnet, flow, inflow)
            check += inflow[n - 1]
        elif piece == EVALUATION:
            C._evaluate(pnet, oil, oil, x, v, (area, spool), speed, DT, geo, p, dpdm, flow, dflow, inflow, residual)
            check += residual[nf - 1] if nf else 0.0
        else:
            C._newton_values(pnet, dflow, dpdm, DT, lu)
            for i in range(nf):
                for j in range(1 + na):
                    rhs[i, j] = residual[i] * (1.0 + j)
            C._newton_solve(pnet, lu, saved, jac, rhs)
            check += rhs[nf - 1, 0] if nf else 0.0
    return check


def bench(name, path, reps, window, every, calls):
    scenario = load_scenario(path).with_overrides(dt=DT)
    plant = MujocoPlantFast(load_scene(scenario))
    assert plant.fast
    m = plant.model
    start = bare_start(plant)
    states = []  # the network's state every ``every`` seconds of the window
    stride = int(round(every / DT))
    while plant.step_index + stride <= int(round(window / DT)):
        report = plant.advance(stride)
        assert report.success, report.message
        states.append((plant._F, plant._I, plant._oil.copy(), plant._x.copy(), plant._v.copy(), plant._spool.copy(),
                       plant._speed[stride - 1].copy(), plant._cmd[stride - 1].copy()))
    for args in states[:1]:
        for piece in range(len(PIECES) + len(STEP_PIECES)):
            _time_piece(*args, piece, 10)  # compiled (or loaded) before timing
    steps = int(round(window / DT))
    times = {key: [] for key in ("bare", *PIECES, *STEP_PIECES)}
    for _ in range(reps):
        bare = mujoco.MjData(m)
        mujoco.mj_copyData(bare, m, start)
        t = time.perf_counter()
        mujoco.mj_step(m, bare, nstep=steps)
        times["bare"].append((time.perf_counter() - t) / steps)
        for piece, key in enumerate(PIECES + STEP_PIECES):
            t = time.perf_counter()
            for args in states:
                _time_piece(*args, piece, calls)
            times[key].append((time.perf_counter() - t) / (calls * len(states)))
    med = {k: statistics.median(v) * 1e6 for k, v in times.items()}
    floor = med["evaluation"] + med["factorisation"]
    n, nf = plant.network.node_count, len(plant.network.free_nodes)
    cells = "  ".join(f"{k} {med[k]:6.3f} µs ({med[k] / med['bare']:4.2f})" for k in PIECES)
    print(f"{name:10s} {n:2d} nodes ({nf} free), {len(plant.network.branch_names):2d} branches, first {window:.1f} s "
          f"({len(states)} states):  bare mj_step {med['bare']:6.3f} µs  {cells}  "
          f"floor {(med['bare'] + floor) / med['bare']:4.2f}× bare "
          f"({(med['bare'] + floor + med['pressures']) / med['bare']:4.2f}× with separate end pressures)", flush=True)
    cells = "  ".join(f"{k} {med[k]:6.3f} µs ({med[k] / med['bare']:4.2f})" for k in STEP_PIECES)
    print(f"{'':10s} rosenbrock's pieces: {cells}", flush=True)
    return med


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=7)
    parser.add_argument("--window", type=float, default=6.0, help="simulated seconds from the scenario's start [s]")
    parser.add_argument("--every", type=float, default=0.5, help="interval of the network states timed [s]")
    parser.add_argument("--calls", type=int, default=2000, help="calls of each piece per state and repetition")
    args = parser.parse_args()
    for name, path in SCENES.items():
        bench(name, path, args.reps, args.window, args.every, args.calls)


if __name__ == "__main__":
    main()
