"""µs per coupled step at 1 kHz: bare ``mj_step`` vs MujocoPlantFast (and MujocoPlant), per scene, in one run.

For each scene every variant simulates the same window from the scene's
initial state (the excavator: the first ``--window`` seconds of the dig cycle,
approach and digging included), repeated ``--reps`` times in alternation; the
median is reported:

* ``bare``: ``mj_step(m, d, nstep=B)`` on the fast plant's MJCF (same model,
  same actuators and integrator) from the same initial state, with constant
  controls (the effort law of the plant's first step held), no callback: the
  mechanical cost alone;
* ``fast/2000``: ``MujocoPlantFast.advance(2000)`` — the runner's block at 1 kHz
  (``sim.run.runner.block_steps``: 2 s, two hundred samples of the default 100 Hz log per block);
* ``fast/4000``: ``advance(4000)``;
* ``linear/2000``, ``linear/4000``: the same with coupling ``implicit-linear``
  (linearly implicit finish, no second Newton solve; plant constructor
  argument ``coupling``);
* ``rosen/2000``, ``rosen/4000``: coupling ``rosenbrock`` (also the linearisation is
  one Newton step: no nonlinear solve unless a step leaves the trust region);
* ``python``: the Python-orchestrated :class:`MujocoPlant` (first 0.2 s only);
* ``pbd-θ 1ms×1``, ``pbd-rb-θ 60Hz×18``, ``pbd-rb-θ 100Hz×11``: PBD mode
  (:class:`sim.plants.pbd.PbdPlant` on the runner's block path, ``advance`` in the runner's blocks,
  ``block_steps(dt)`` frames) at MuJoCo mode's step (1 ms frames × 1 substep, θ-rule) and at the two
  settings ``bench_pbd.py`` finds at least as accurate as MuJoCo mode at 1 ms on the excavator
  (rosenbrock, θ-rule): 60 Hz × 18 substeps on the strokes before contact, 100 Hz × 11 on those and on
  every phase's pressures too.  Their µs are per millisecond of simulated time, so the ratio compares
  them with 1 kHz of bare ``mj_step``.

Prints µs/step, the ratio to bare, the real-time factor (simulated/wall time)
and the process's peak RSS; ``--markdown`` also prints these as the table of docs/benchmarks.md
(one row per scene).  Run: ``.venv/bin/python bench/bench_fast.py [--markdown]``.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time
from pathlib import Path

import mujoco

from sim.plants.mujoco import MujocoPlant
from sim.plants.mujoco_fast import MujocoPlantFast
from sim.run.runner import block_steps, make_plant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene

MODELS = Path(__file__).resolve().parents[1] / "models"
SCENES = {
    "seed": MODELS / "seed_cylinder" / "closed.scenario.toml",
    "boom": MODELS / "boom" / "lift.scenario.toml",
    "excavator": MODELS / "excavator" / "dig.scenario.toml",
}
DT = 1e-3  # s
LONGEST_BLOCK = 4000  # steps: the long-block variants (fast/4000 etc.) advance this many steps per call
RUNNER_BLOCK = block_steps(DT)  # steps: the runner's block at 1 kHz
# MuJoCo mode's variants: (steps per advance, label, coupling)
MUJOCO_VARIANTS = tuple((block, f"{label}/{block}", coupling)
                        for label, coupling in (("fast", "implicit"), ("linear", "implicit-linear"), ("rosen", "rosenbrock"))
                        for block in (RUNNER_BLOCK, LONGEST_BLOCK))
# PBD mode's rows: label -> scenario overrides
PBD_VARIANTS = {
    "pbd-θ 1ms×1": dict(mode="pbd", dt=1e-3, pbd_substeps=1, pbd_blend=True),
    "pbd-rb-θ 60Hz×18": dict(mode="pbd", dt=1 / 60, pbd_substeps=18, coupling="rosenbrock", pbd_blend=True),
    "pbd-rb-θ 100Hz×11": dict(mode="pbd", dt=1 / 100, pbd_substeps=11, coupling="rosenbrock", pbd_blend=True),
}


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bare_start(plant: MujocoPlantFast) -> mujoco.MjData:
    """The bare loop's start: ``plant``'s initial state with the effort law of its first step held as constant
    controls (``plant`` is left reset, at that state; biasprm, in the model, keeps the first law)."""
    plant.advance(1)  # callback loaded/compiled; ctrl and biasprm hold the first step's effort law
    held = plant.data.ctrl.copy()
    plant.reset()
    start = mujoco.MjData(plant.model)
    mujoco.mj_copyData(start, plant.model, plant.data)
    start.ctrl[:] = held
    return start


def bench(name, path, reps, window, python_window=0.2):
    scenario = load_scenario(path).with_overrides(dt=DT)
    steps = int(round(window / DT))
    python_steps = int(round(python_window / DT))
    scene = load_scene(scenario)
    probe = MujocoPlantFast(scene)
    assert probe.fast
    m = probe.model
    start = bare_start(probe)
    b = RUNNER_BLOCK
    variants = MUJOCO_VARIANTS
    times = {"bare": [], **{key: [] for _, key, _ in variants}, "python": [], **{key: [] for key in PBD_VARIANTS}}
    pbd_scenarios = {key: scenario.with_overrides(**overrides) for key, overrides in PBD_VARIANTS.items()}
    for key, pbd_scenario in pbd_scenarios.items():  # kernels loaded before timing
        make_plant(load_scene(pbd_scenario)).advance(2)
    newton = {coupling: 0 for _, _, coupling in variants}
    for _ in range(reps):
        bare = mujoco.MjData(m)
        mujoco.mj_copyData(bare, m, start)
        t = time.perf_counter()
        mujoco.mj_step(m, bare, nstep=steps)
        times["bare"].append((time.perf_counter() - t) / steps)
        for block, key, coupling in variants:
            fast = MujocoPlantFast(load_scene(scenario), coupling=coupling)
            assert fast.fast
            blocks = steps // block
            t = time.perf_counter()
            for _ in range(blocks):
                report = fast.advance(block)
                if block == b:
                    newton[coupling] += report.newton_iterations
            times[key].append((time.perf_counter() - t) / (blocks * block))
            assert report.success, report.message
        slow = MujocoPlant(load_scene(scenario))
        t = time.perf_counter()
        for _ in range(python_steps):
            slow.step()
        times["python"].append((time.perf_counter() - t) / python_steps)
        for key, pbd_scenario in pbd_scenarios.items():
            pbd = make_plant(load_scene(pbd_scenario))
            frames = int(round(window / pbd_scenario.dt))
            t = time.perf_counter()
            while pbd.step_index < frames:
                report = pbd.advance(min(block_steps(pbd_scenario.dt), frames - pbd.step_index))
                assert report is not None and report.success, key
            times[key].append((time.perf_counter() - t) / (frames * pbd_scenario.dt / DT))  # per 1 ms simulated
    med = {k: statistics.median(v) * 1e6 for k, v in times.items()}
    cells = "  ".join(f"{k} {med[k]:7.2f} µs {med[k] / med['bare']:5.2f}× RTF {DT * 1e6 / med[k]:6.1f}" for k in med)
    # Newton iterations of the finish, sampled at the last step of each runner-sized block
    sampled = ", ".join(f"{k} {v / (reps * (steps // b)):.2f}" for k, v in newton.items())
    print(f"{name:10s} {window:4.1f} s  {cells}  peak RSS {peak_rss_mib():.0f} MiB  finish Newton it/step "
          f"(sampled) {sampled}", flush=True)
    return med, peak_rss_mib()


# The table of docs/benchmarks.md: column heading -> the bench's variant keys in that cell (MuJoCo mode: the runner's block, then the
# longest)
TABLE_COLUMNS = {
    **{f"{coupling}, blocks of {RUNNER_BLOCK} / {LONGEST_BLOCK}": tuple(key for _, key, c in MUJOCO_VARIANTS if c == coupling)
       for coupling in dict.fromkeys(c for _, _, c in MUJOCO_VARIANTS)},
    "Python-orchestrated plant": ("python",),
    **{f"PBD {key[4:]}": (key,) for key in PBD_VARIANTS},
}


def markdown_table(results: dict) -> str:
    """The table of docs/benchmarks.md from ``{scene: (medians [µs per 1 ms simulated], peak RSS [MiB])}``: each cell µs, ratio to
    bare and real-time factor; the bare column µs and RTF; the process's peak RSS after the scene."""
    us = lambda x: f"{x:.0f}" if x >= 100 else f"{x:.1f}" if x >= 10 else f"{x:.2f}"  # noqa: E731 - µs, ~3 figures
    ratio = lambda x: f"{x:.0f}" if x >= 10 else f"{x:.2f}"  # noqa: E731
    head = ["scene", "bare `mj_step`", *TABLE_COLUMNS, "peak RSS"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, (med, rss) in results.items():
        bare = med["bare"]
        cells = [name, f"{us(bare)} µs (RTF {DT * 1e6 / bare:.0f})"]
        for keys in TABLE_COLUMNS.values():
            cells.append(" / ".join(f"{us(med[k])} µs {ratio(med[k] / bare)}×" for k in keys)
                         + f" (RTF {DT * 1e6 / med[keys[0]]:.0f})")
        cells.append(f"{rss:.0f} MiB")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--window", type=float, default=6.0, help="simulated seconds per variant and repetition")
    parser.add_argument("--markdown", action="store_true", help="also print the table of docs/benchmarks.md")
    args = parser.parse_args()
    if args.window < LONGEST_BLOCK * DT:  # every variant must time at least one whole block
        parser.error(f"--window {args.window} s: must be at least {LONGEST_BLOCK * DT:g} s "
                     f"(one block of {LONGEST_BLOCK} steps at {DT * 1e3:g} ms)")
    results = {name: bench(name, path, args.reps, args.window) for name, path in SCENES.items()}
    if args.markdown:
        print(markdown_table(results))


if __name__ == "__main__":
    main()
