"""MuJoCo mode cost per step against a bare ``mujoco.mj_step`` loop on the same MJCF, same run.

For each scene and coupling: µs per coupled step (hydraulics + MuJoCo, no
logging), µs per bare ``mj_step`` with the same actuators held at constant
controls, their ratio, and the real-time factor.  Timings alternate between the
two loops in blocks so that machine noise hits both alike.

    python bench/bench_mujoco.py [--steps N]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import mujoco
import numpy as np

from sim.plants.mujoco import MujocoPlant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = {
    "seed_cylinder": ROOT / "models/seed_cylinder/closed.scenario.toml",
    "boom": ROOT / "models/boom/lift.scenario.toml",
    "excavator": ROOT / "models/excavator/dig.scenario.toml",
}
BLOCKS = 5  # alternating timing blocks per measurement


def bare_step_us(model, data, steps):
    start = time.perf_counter()
    mujoco.mj_step(model, data, nstep=steps)
    return (time.perf_counter() - start) / steps * 1e6


def plant_step_us(plant, steps):
    start = time.perf_counter()
    for _ in range(steps):
        plant.step()
    return (time.perf_counter() - start) / steps * 1e6


def measure(name, path, coupling, steps):
    scenario = load_scenario(path).with_overrides(coupling=coupling, dt=1e-3 if name != "seed_cylinder" else None)
    plant = MujocoPlant(load_scene(scenario))
    bare_model = load_scene(scenario).mjmodel
    bare_data = mujoco.MjData(bare_model)
    bare_data.qpos[:] = plant.data.qpos
    mujoco.mj_forward(bare_model, bare_data)
    bare_data.ctrl[:] = plant.effort  # the holding efforts, held constant
    ours, bare = [], []
    for _ in range(BLOCKS):
        ours.append(plant_step_us(plant, steps))
        bare.append(bare_step_us(bare_model, bare_data, steps))
    ours_us, bare_us = float(np.median(ours)), float(np.median(bare))
    return ours_us, bare_us, ours_us / bare_us, scenario.dt / (ours_us * 1e-6)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="steps per timing block")
    args = parser.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, {platform.python_implementation()} {platform.python_version()}, "
          f"mujoco {mujoco.__version__}, numpy {np.__version__}")
    print(f"{'scene':<14} {'coupling':<9} {'ours [us/step]':>15} {'bare mj_step [us]':>18} {'ratio':>8} {'real-time factor':>17}")
    for name, path in SCENARIOS.items():
        for coupling in ("implicit", "explicit"):
            ours, bare, ratio, rtf = measure(name, path, coupling, args.steps)
            print(f"{name:<14} {coupling:<9} {ours:15.1f} {bare:18.2f} {ratio:8.1f} {rtf:17.2f}")


if __name__ == "__main__":
    main()
