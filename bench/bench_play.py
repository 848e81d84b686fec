"""The physics share of a paced frame (``hydroplant play``) on the excavator dig, per mode and coupling, and the
number of excavators one core steps in real time.

Per configuration, ``play`` of the 20 s dig unpaced (``pace = 0``: no sleeping, every frame's work measured) at
60 Hz frames with the scripted operator and the default log (100 Hz, snapshots at 1 Hz), ``--reps`` times
interleaved over the configurations; per frame the physics time (the frame's steps with the log's in-loop
sampling, as the paced loop measures it) in wall time and in the process's CPU time (``time.process_time``,
which leaves out the time the process was preempted: on a shared machine the wall-time p99 is the scheduler's
time slice, not the physics).  Printed per configuration: the median over the reps of each rep's median and p99
[ms], the CPU-time shares of the 16.67 ms frame, and the frames whose wall time exceeded the period.

Excavators per core in real time: N = floor(16.67 ms / CPU p99) from one excavator's CPU time per frame (an
extrapolation: N excavators stepped one after the other cost N times one, with the log of each), and measured:
the largest N plants of the configuration stepped one after the other in every frame for ``--check-seconds`` of
simulated time without logs (the same blocks, ``plant.advance`` per frame) whose summed CPU time per frame has its
p99 within the frame, found by doubling from the extrapolated N and bisecting, with that of N + 1 beside it.

Usage::

    python bench/bench_play.py [--reps 3] [--check-seconds 5]
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from sim.io.examples import example_path
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.run.play import PlayOptions, ScheduleSource, play
from sim.run.runner import make_plant

FRAME_MS = 1e3 / 60.0
CONFIGS = (  # label, scenario overrides
    ("mujoco implicit 1 ms", {"mode": "mujoco", "coupling": "implicit"}),
    ("mujoco implicit-linear 1 ms", {"mode": "mujoco", "coupling": "implicit-linear"}),
    ("mujoco rosenbrock 1 ms", {"mode": "mujoco", "coupling": "rosenbrock"}),
    ("pbd implicit 1 ms × 20", {"mode": "pbd", "coupling": "implicit"}),
    ("pbd rosenbrock 1 ms × 20", {"mode": "pbd", "coupling": "rosenbrock"}),
    ("pbd rosenbrock-θ 16.67 ms × 18", {"mode": "pbd", "coupling": "rosenbrock", "dt": 1 / 60, "pbd_substeps": 18,
                                        "pbd_blend": True}),
)


def one_play(overrides: dict, folder: Path):
    """Physics wall and CPU time per frame [ms] of one unpaced play of the dig."""
    scenario = load_scenario(example_path("excavator/dig")).with_overrides(**overrides)
    result = play(scenario, source=ScheduleSource(scenario.inputs), options=PlayOptions(pace=0.0),
                  out=folder / f"play-{time.perf_counter_ns()}.mcap")
    if result.run.status != "complete":
        raise RuntimeError(f"{overrides}: {result.run.status} {result.run.message}")
    return result.frames.physics_ms, result.frames.cpu_ms


def frames_of_many(overrides: dict, count: int, seconds: float) -> np.ndarray:
    """Summed CPU time [ms] per 60 Hz frame of ``count`` plants stepped one after the other (no logs)."""
    scenario = load_scenario(example_path("excavator/dig")).with_overrides(duration=seconds, **overrides)
    plants = [make_plant(load_scene(scenario)) for _ in range(count)]
    steps = scenario.step_count
    per_frame = 1.0 / (60.0 * scenario.dt)
    out = []
    k = 0
    while plants[0].step_index < steps:
        end = min(int(round((k + 1) * per_frame)), steps)
        tic = time.process_time()
        for plant in plants:
            plant.advance(end - plant.step_index)
        out.append(1e3 * (time.process_time() - tic))
        k += 1
    return np.array(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--check-seconds", type=float, default=5.0)
    args = parser.parse_args(argv)
    figures = {label: [] for label, _ in CONFIGS}
    with tempfile.TemporaryDirectory() as tmp:
        for label, overrides in CONFIGS:  # warm-up: kernels loaded or compiled, not timed
            frames_of_many(overrides, 1, 0.1)
        for _ in range(args.reps):
            for label, overrides in CONFIGS:
                wall, cpu = one_play(overrides, Path(tmp))
                figures[label].append((np.median(wall), np.percentile(wall, 99), np.median(cpu), np.percentile(cpu, 99),
                                       np.count_nonzero(wall > FRAME_MS), len(wall)))
    print(f"excavator dig, 20 s, 60 Hz frames ({FRAME_MS:.2f} ms), unpaced, default log; median over {args.reps} reps")
    print()
    print("| mode, coupling, step | wall median [ms] | wall p99 [ms] | CPU median [ms] | CPU p99 [ms] | CPU share of "
          "the frame, median / p99 | frames over 16.67 ms (wall) | excavators per core (16.67 ms / CPU p99) |")
    print("|---|---|---|---|---|---|---|---|")
    counts = {}
    for label, _ in CONFIGS:
        rows = np.array(figures[label])
        wall_med, wall_p99, cpu_med, cpu_p99, over = (statistics.median(rows[:, i]) for i in range(5))
        n = int(math.floor(FRAME_MS / cpu_p99))
        counts[label] = n
        print(f"| {label} | {wall_med:.3f} | {wall_p99:.2f} | {cpu_med:.3f} | {cpu_p99:.3f} | "
              f"{100 * cpu_med / FRAME_MS:.1f} % / {100 * cpu_p99 / FRAME_MS:.1f} % | {over:.0f} of {int(rows[0, 5])} | {n} |")
    print()
    print(f"| measured: N plants stepped one after the other per frame, {args.check_seconds:g} s, no log | largest N "
          "whose summed CPU p99 fits the frame | its summed CPU median / p99 [ms] | N + 1: summed CPU p99 [ms] |")
    print("|---|---|---|---|")
    for label, overrides in CONFIGS:
        fits = {}

        def p99_of(n):
            if n not in fits:
                ms = frames_of_many(overrides, n, args.check_seconds)
                fits[n] = (float(np.median(ms)), float(np.percentile(ms, 99)))
            return fits[n][1]

        low, high = 0, max(1, counts[label])  # p99_of(low) fits (0: nothing to step), p99_of(high) is tried first
        while p99_of(high) <= FRAME_MS:  # grow until one does not fit
            low, high = high, 2 * high
        while high - low > 1:  # bisect: low fits, high does not
            middle = (low + high) // 2
            low, high = (middle, high) if p99_of(middle) <= FRAME_MS else (low, middle)
        n = low
        p99_of(n + 1)
        median, p99 = fits[n] if n else (math.nan, math.nan)
        print(f"| {label} | {n} | {median:.2f} / {p99:.2f} | {fits[n + 1][1]:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
