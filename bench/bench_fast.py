"""µs per coupled step at 1 kHz: bare mj_step vs MujocoPlant vs MujocoPlantFast, per scene.

Same process, alternating blocks, medians over repetitions.  "bare" is
``mj_step(m, d, nstep=B)`` on a copy of the fast plant's MjData with no
callback (the mechanical cost alone); the fast plant is timed with blocks of
10 steps (a 100 Hz log at 1 kHz: one ``advance(10)`` per logged sample) and of
1000 steps.  Run: ``.venv/bin/python bench/bench_fast.py [--reps 7]``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import mujoco

from sim.plant_mujoco import MujocoPlant
from sim.plant_mujoco_fast import MujocoPlantFast
from sim.scenario import load_scenario
from sim.scene import load_scene

MODELS = Path(__file__).resolve().parents[1] / "models"
SCENES = {
    "seed": MODELS / "seed_cylinder" / "closed.scenario.toml",
    "boom": MODELS / "boom" / "lift.scenario.toml",
    "excavator": MODELS / "excavator" / "dig.scenario.toml",
}


def bench(name, path, reps, fast_steps=2000, python_steps=200):
    scenario = load_scenario(path).with_overrides(dt=1e-3)
    slow = MujocoPlant(load_scene(scenario))
    fast = MujocoPlantFast(load_scene(scenario))
    assert fast.fast
    fast.advance(10)  # warm (callback compiled, caches hot)
    for _ in range(10):
        slow.step()
    m = fast.model
    bare = mujoco.MjData(m)
    times = {"bare": [], "python": [], "fast/10": [], "fast/1000": []}
    for _ in range(reps):
        mujoco.mj_copyData(bare, m, fast.data)
        t = time.perf_counter()
        mujoco.mj_step(m, bare, nstep=fast_steps)
        times["bare"].append((time.perf_counter() - t) / fast_steps)
        t = time.perf_counter()
        for _ in range(python_steps):
            slow.step()
        times["python"].append((time.perf_counter() - t) / python_steps)
        t = time.perf_counter()
        for _ in range(fast_steps // 10):
            fast.advance(10)
        times["fast/10"].append((time.perf_counter() - t) / fast_steps)
        t = time.perf_counter()
        for _ in range(fast_steps // 1000):
            fast.advance(1000)
        times["fast/1000"].append((time.perf_counter() - t) / fast_steps)
    med = {k: statistics.median(v) * 1e6 for k, v in times.items()}
    ratios = "  ".join(f"{k} {med[k]:8.2f} µs ({med[k] / med['bare']:6.2f}×)" for k in med)
    print(f"{name:10s} t={fast.time:7.2f}s  {ratios}", flush=True)
    return med


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=7)
    args = parser.parse_args()
    for name, path in SCENES.items():
        bench(name, path, args.reps)


if __name__ == "__main__":
    main()
