"""µs per coupled step against bare-replay: the same run's controls replayed into plain ``mj_step``, in one process.

Bare-replay is the least MuJoCo mode can cost: MuJoCo stepping the very trajectory the coupled run
took (its contacts, constraint islands and solver iterations included) with the hydraulics replaced
by a table.  For each coupling the scene's scenario (default: the excavator dig, its whole 20 s, at
1 kHz) is first run once step by step with :class:`sim.plants.mujoco_fast.MujocoPlantFast`, keeping
the effort law every step wrote to MuJoCo (``ctrl`` and ``actuator_biasprm[:, 2]``, the affine
actuator's constant and velocity slope).  The bare-replay loop is then ``mj_step(m, d, nstep=N)``
from the plant's initial state with a compiled control callback that only copies step k's row of
that table into ``ctrl`` and ``biasprm`` (MuJoCo calls it where the coupled step's callback runs,
so the actuator forces, and hence the trajectory, are bit for bit the coupled run's: the bench
prints the largest ``qpos`` difference at the end as a check).

Timing: ``--reps`` rounds; in each, for every coupling, its bare-replay and its coupled run
(``advance`` in the runner's blocks, ``block_steps(dt)``, from a new plant) are timed back to back, the order of
the two alternating from round to round.  Printed per coupling: the median µs per step of each,
and the median and quartiles of the per-round ratio coupled / bare-replay (the paired figure to
read: both halves of a pair see the same machine load).  ``--markdown`` adds the table of
docs/benchmarks.md.

    .venv/bin/python bench/bench_bare_replay.py [--reps 7] [--seconds 20] [--couplings implicit rosenbrock]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import mujoco
import numba
import numpy as np
from numba import carray, types

from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.methods import COUPLINGS, DEFAULT_COUPLING
from sim.plants.mujoco_fast import MujocoPlantFast, _pf64, _pi64
from sim.run.runner import block_steps

SCENARIO = Path(__file__).resolve().parents[1] / "models" / "excavator" / "dig.scenario.toml"
DT = 1e-3  # s
IMPLICIT_COUPLINGS = tuple(c for c in COUPLINGS if c != "explicit")  # those that are stable on the excavator at 1 kHz
# the replay callback's table (int64): step, rows, actuators, biasprm width, addresses of ctrl, biasprm, the rows, ids
REPLAY_TABLE = ("step", "rows", "actuators", "bias_width", "ctrl", "biasprm", "table", "ids")
R_K, R_ROWS, R_NA, R_NBIAS, R_CTRL, R_BIAS, R_TABLE, R_ACT = range(len(REPLAY_TABLE))


def replay_callback(table_address: int):
    """A compiled MuJoCo control callback that writes row k of the float64 table (k: the step counter in the int64
    table at ``table_address``, layout ``R_*``) into ``ctrl[act]`` (first na columns) and ``biasprm[act, 2]`` (next
    na), then advances k (the last row is held).  The address is compiled in: one callback per table."""

    @numba.cfunc(types.void(types.voidptr, types.voidptr), error_model="numpy")
    def replay(m, d):
        head = carray(_pi64(table_address), (R_ACT,))
        na, nbias, rows = head[R_NA], head[R_NBIAS], head[R_ROWS]
        act = carray(_pi64(table_address + 8 * R_ACT), (na,))
        k = min(head[R_K], rows - 1)
        row = carray(_pf64(head[R_TABLE] + 8 * 2 * na * k), (2 * na,))
        ctrl, bias = _pf64(head[R_CTRL]), _pf64(head[R_BIAS])
        for i in range(na):
            ctrl[act[i]] = row[i]
            bias[act[i] * nbias + 2] = row[na + i]
        head[R_K] = head[R_K] + 1

    return replay


def record_laws(scenario, coupling, steps):
    """The effort law of every step of ``coupling``'s run (rows: ctrl of the actuators, then their biasprm slope), and
    the final qpos of that run stepped in the runner's blocks (the replay's check)."""
    plant = MujocoPlantFast(load_scene(scenario), coupling=coupling)
    assert plant.fast
    act = np.asarray(plant.binding.actuator_id)
    rows = np.empty((steps, 2 * act.size))
    for k in range(steps):
        report = plant.advance(1)
        assert report.success, report.message
        rows[k, :act.size] = plant.data.ctrl[act]
        rows[k, act.size:] = plant.model.actuator_biasprm[act, 2]
    blocked = MujocoPlantFast(load_scene(scenario), coupling=coupling)
    block = block_steps(DT)
    while blocked.step_index < steps:
        blocked.advance(min(block, steps - blocked.step_index))
    return rows, act, blocked.data.qpos.copy()


class Replay:
    """Bare-replay of one recorded run: ``time(steps)`` steps plain ``mj_step`` from the plant's initial state with the
    recorded laws; returns the seconds it took and leaves the end state in ``data``."""

    def __init__(self, scenario, rows, act):
        self.plant = MujocoPlantFast(load_scene(scenario))  # its model and initial state (never stepped)
        self.model = self.plant.model
        self.start = mujoco.MjData(self.model)
        mujoco.mj_copyData(self.start, self.model, self.plant.data)
        self.rows = np.ascontiguousarray(rows)
        self.head = np.zeros(R_ACT + act.size, np.int64)
        self.data = mujoco.MjData(self.model)
        self.head[R_ROWS], self.head[R_NA], self.head[R_NBIAS] = rows.shape[0], act.size, self.model.actuator_biasprm.shape[1]
        self.head[R_CTRL], self.head[R_BIAS] = self.data.ctrl.ctypes.data, self.model.actuator_biasprm.ctypes.data
        self.head[R_TABLE] = self.rows.ctypes.data
        self.head[R_ACT:] = act
        self.callback = replay_callback(int(self.head.ctypes.data))

    def time(self, steps):
        mujoco.mj_copyData(self.data, self.model, self.start)
        self.head[R_K] = 0
        previous = mujoco.get_mjcb_control()
        mujoco.set_mjcb_control(self.callback.ctypes)
        try:
            t = time.perf_counter()
            mujoco.mj_step(self.model, self.data, nstep=steps)
            return time.perf_counter() - t
        finally:
            mujoco.set_mjcb_control(previous)


def time_coupled(scenario, coupling, steps):
    """Seconds of ``steps`` coupled steps of a new plant, advanced in the runner's blocks."""
    plant = MujocoPlantFast(load_scene(scenario), coupling=coupling)
    block = block_steps(DT)
    t = time.perf_counter()
    while plant.step_index < steps:
        report = plant.advance(min(block, steps - plant.step_index))
    elapsed = time.perf_counter() - t
    assert report.success, report.message
    return elapsed


def quartiles(values):
    q = statistics.quantiles(values, n=4) if len(values) > 1 else (values[0],) * 3
    return q[0], q[2]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", type=Path, default=SCENARIO)
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per run [s]")
    parser.add_argument("--reps", type=int, default=7)
    parser.add_argument("--couplings", nargs="+", choices=IMPLICIT_COUPLINGS, default=list(IMPLICIT_COUPLINGS))
    parser.add_argument("--markdown", action="store_true", help="also print the table of docs/benchmarks.md")
    args = parser.parse_args()
    if args.seconds <= 0 or args.reps < 1:
        parser.error("--seconds must be > 0 and --reps >= 1")
    scenario = load_scenario(args.scenario).with_overrides(dt=DT)
    steps = int(round(min(args.seconds, scenario.duration) / DT))
    replays = {}
    for coupling in args.couplings:
        rows, act, qpos_blocked = record_laws(scenario, coupling, steps)
        replays[coupling] = replay = Replay(scenario, rows, act)
        replay.time(steps)  # (also compiles the callback)
        time_coupled(scenario, coupling, min(steps, 10))  # kernels loaded
        replays[coupling].deviation = float(np.max(np.abs(replay.data.qpos - qpos_blocked)))
    bare = {c: [] for c in args.couplings}
    coupled = {c: [] for c in args.couplings}
    for r in range(args.reps):
        for coupling in args.couplings:
            pair = [lambda: bare[coupling].append(replays[coupling].time(steps) / steps),
                    lambda: coupled[coupling].append(time_coupled(scenario, coupling, steps) / steps)]
            for timed in (pair if r % 2 == 0 else pair[::-1]):
                timed()
    name = f"{args.scenario.parent.name}/{args.scenario.name.removesuffix('.scenario.toml')}"
    print(f"{name}, {steps * DT:g} s at {1 / DT:g} Hz, {args.reps} paired rounds (coupled in blocks of "
          f"{block_steps(DT)} steps; bare-replay: plain mj_step with the run's own effort laws); default coupling "
          f"{DEFAULT_COUPLING}")
    table = ["| coupling | bare-replay | coupled | ratio, median of pairs (quartiles) | replay check: max abs qpos difference |",
             "|---|---|---|---|---|"]
    for coupling in args.couplings:
        ratios = [c / b for c, b in zip(coupled[coupling], bare[coupling])]
        lo, hi = quartiles(ratios)
        b_us, c_us = statistics.median(bare[coupling]) * 1e6, statistics.median(coupled[coupling]) * 1e6
        print(f"  {coupling:16s} bare-replay {b_us:6.2f} µs  coupled {c_us:6.2f} µs  ratio {statistics.median(ratios):4.2f}× "
              f"(quartiles {lo:4.2f} / {hi:4.2f})  replay check: max |Δqpos| {replays[coupling].deviation:.1e}", flush=True)
        label = f"{coupling} (default)" if coupling == DEFAULT_COUPLING else coupling
        table.append(f"| {label} | {b_us:.2f} µs | {c_us:.2f} µs | {statistics.median(ratios):.2f}× ({lo:.2f} / {hi:.2f}) | "
                     f"{replays[coupling].deviation:.1e} |")
    if args.markdown:
        print("\n".join(table))


if __name__ == "__main__":
    main()
