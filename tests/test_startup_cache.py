"""The fast plant's compiled code is cached on disk: a second process loads the callback instead of compiling it.

No timing here (bench/bench_startup.py measures start-up); the test checks the
mechanism: after a first process has built a MujocoPlantFast and stepped it, a
fresh process finds numba's cache index of the callback on disk and loads the
callback from it (``cache_hits``), and the cached callback couples the same
step as the Python-orchestrated plant (same pressures to round-off).
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import MODELS, ROOT
from hydraulics._compiled import compiled_available

pytestmark = pytest.mark.skipif(not compiled_available(), reason="numba is not installed")

PROBE = """
import json, sys
import numpy as np
from sim.plants import mujoco_fast as fast_module
from sim.plants.mujoco import MujocoPlant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
scenario = load_scenario(sys.argv[1])
fast = fast_module.MujocoPlantFast(load_scene(scenario))
reference = MujocoPlant(load_scene(scenario))
report = fast.advance(5)
for _ in range(5):
    reference.step()
cb = fast_module.callback()
print(json.dumps({
    "fast": fast.fast, "success": report.success, "cache_hits": cb.cache_hits,
    "cache_dir": str(cb._cache._cache_path),
    "pressure_fast": fast.net_state.node_pressure.tolist(),
    "pressure_reference": reference.net_state.node_pressure.tolist(),
}))
"""


def probe():
    out = subprocess.run([sys.executable, "-c", PROBE, str(MODELS / "boom" / "lift.scenario.toml")], cwd=ROOT,
                         capture_output=True, text=True, check=True, timeout=600)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_callback_is_loaded_from_the_disk_cache_by_a_second_process():
    first = probe()  # compiles and writes the cache if it is cold (once per change of the source)
    assert first["fast"] and first["success"]
    index = list(Path(first["cache_dir"]).glob("mujoco_fast._callback_function.locals.coupled_step_c-*.nbi"))
    assert index, f"no cache index of the callback in {first['cache_dir']}"
    second = probe()
    assert second["cache_hits"] >= 1, "the second process compiled the callback instead of loading it"
    for run in (first, second):
        for a, b in zip(run["pressure_fast"], run["pressure_reference"]):
            assert a == pytest.approx(b, rel=1e-9, abs=1e-2)  # Pa



PBD_PROBE = """
import json, sys, warnings
warnings.filterwarnings("ignore")
from sim.plants.pbd import PbdPlant
from sim.plants.pbd_block import block
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
plant = PbdPlant(load_scene(load_scenario(sys.argv[1]).with_overrides(mode="pbd", dt=1 / 60, pbd_substeps=2)))
plant.advance(2)
kernel = block(plant.solver.transport_response, plant.solver.articulated_contacts)
print(json.dumps({"blocks": plant.frame_steps, "hits": sum(kernel.stats.cache_hits.values()),
                  "misses": sum(kernel.stats.cache_misses.values())}))
"""


def test_compile_command_fills_the_cache_for_a_later_process():
    """``hydroplant compile`` (sim.run.precompile) runs its groups in their own processes; a fresh process then loads
    the PBD block kernel from numba's disk cache (a cache hit, no miss: nothing compiled)."""
    from sim.run.precompile import precompile

    with pytest.raises(ValueError, match="unknown kernel groups"):
        precompile(["nope"])
    done = subprocess.run([sys.executable, "-m", "sim.cli", "compile", "--groups", "pbd", "--jobs", "1"], cwd=ROOT,
                          capture_output=True, text=True, timeout=1800)
    assert done.returncode == 0, done.stderr
    assert "kernels ready: pbd" in done.stdout
    probe = subprocess.run([sys.executable, "-c", PBD_PROBE, str(MODELS / "excavator" / "dig.scenario.toml")], cwd=ROOT,
                           capture_output=True, text=True, timeout=1800)
    assert probe.returncode == 0, probe.stderr
    out = json.loads(probe.stdout.strip().splitlines()[-1])
    assert out["blocks"] == 2 and out["hits"] >= 1 and out["misses"] == 0, out
