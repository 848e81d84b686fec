"""Start-up time of MuJoCo mode: import, scene load (+ plant construction) and first step, in fresh processes.

Runs ``--runs`` fresh interpreters one after the other on the excavator dig
scene; the first may compile (cold numba cache after a change of the source),
the others load the compiled kernels and the control callback from numba's
disk cache.  ``--cold`` points the first process at an empty cache directory
(``NUMBA_CACHE_DIR``) to measure the one-off compilation, and the later ones
at the same directory.  Run: ``.venv/bin/python bench/bench_startup.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "models" / "excavator" / "dig.scenario.toml"

PROBE = """
import json, sys, time
t0 = time.perf_counter()
from sim.plants.mujoco_fast import MujocoPlantFast, callback
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
t1 = time.perf_counter()
plant = MujocoPlantFast(load_scene(load_scenario(sys.argv[1])))
t2 = time.perf_counter()
report = plant.advance(1)
t3 = time.perf_counter()
assert plant.fast and report.success
print(json.dumps({"import": t1 - t0, "load": t2 - t1, "first_step": t3 - t2, "total": t3 - t0,
                  "callback_cache_hits": callback().cache_hits}))
"""


def run_once(env):
    out = subprocess.run([sys.executable, "-c", PROBE, str(SCENARIO)], cwd=ROOT, env=env, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--cold", action="store_true", help="start from an empty numba cache directory")
    args = parser.parse_args()
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as cache:
        if args.cold:
            env["NUMBA_CACHE_DIR"] = cache
        for i in range(args.runs):
            r = run_once(env)
            print(f"process {i + 1}: import {r['import']:.2f} s  scene load + plant {r['load']:.2f} s  "
                  f"first step {r['first_step']:.3f} s  total {r['total']:.2f} s  "
                  f"(callback from cache: {'yes' if r['callback_cache_hits'] else 'no'})", flush=True)


if __name__ == "__main__":
    main()
