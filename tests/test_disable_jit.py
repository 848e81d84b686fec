"""The compiled kernels run as plain Python under ``NUMBA_DISABLE_JIT=1`` and agree with the compiled run.

A subprocess with ``NUMBA_DISABLE_JIT=1`` steps the seed cylinder, the boom lift and the excavator dig (valve
ramps, as ``tests/test_fast_plant.py``) on the fast MuJoCo plant (coupled steps inside ``mj_step``, the control
callback as a Python function) and on the PBD plant's block path (``PbdPlant.advance``); this process steps the
same scenes compiled.  Same code, same operations in the same order: the end states (joint positions, node
pressures, actuator positions and efforts, energy ledger) agree to round-off, 1e-12 of each quantity's largest
magnitude (measured: bit-identical on x86-64 with numba 0.68).  Likewise the per-step MuJoCo plant on the boom
lift with each implicit coupling: :class:`hydraulics.steppers.StepperImplicitEuler` and the couplings' compiled
entries called from Python.

Run by hand: ``NUMBA_DISABLE_JIT=1 python tests/test_disable_jit.py out.npz [per-step]``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from conftest import MODELS  # noqa: E402

RTOL = 1e-12  # of each quantity's largest magnitude: round-off of a few hundred steps


def _ramp(t0, t1, value):
    from sim.io.scenario import Schedule

    return Schedule(np.array([0.0, t0, t1]), np.array([0.0, 0.0, value]))


def _scenes():
    """name → (scenario path, valve schedules, PBD overrides); the valves move within the first 0.1 s."""
    coarse = dict(dt=1 / 60, pbd_substeps=10)
    return {
        "seed": (MODELS / "seed_cylinder" / "closed.scenario.toml", {}, {}),
        "boom": (MODELS / "boom" / "lift.scenario.toml", {"boom_valve": _ramp(0.02, 0.08, 1.0)}, coarse),
        "excavator": (MODELS / "excavator" / "dig.scenario.toml",
                      {"boom_valve": _ramp(0.02, 0.08, -0.35), "stick_valve": _ramp(0.03, 0.1, 0.8),
                       "bucket_valve": _ramp(0.05, 0.12, 0.5), "swing_valve": _ramp(0.02, 0.1, 1.0)}, coarse),
    }


MUJOCO_STEPS = 300  # at the scenes' dt (1 ms): 0.3 s
PBD_STEPS = 120  # 2 s at dt = 1/60 s, the excavator's teeth in the ground from ≈ 1.6 s (the seed: its own dt)


def run_scenes() -> dict[str, np.ndarray]:
    """End states of every scene in both modes (fast MuJoCo plant, PBD block path), keyed ``scene/mode/quantity``."""
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants.mujoco_fast import MujocoPlantFast
    from sim.plants.pbd import PbdPlant

    out = {}
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        for name, (path, inputs, pbd_overrides) in _scenes().items():
            scenario = load_scenario(path)
            scenario = scenario.with_overrides(inputs={**scenario.inputs, **inputs})
            mujoco_plant = MujocoPlantFast(load_scene(scenario))
            pbd = scenario.with_overrides(mode="pbd", **pbd_overrides)
            pbd_plant = PbdPlant(load_scene(pbd), block=True)
            for mode, plant, steps in (("mujoco", mujoco_plant, MUJOCO_STEPS), ("pbd", pbd_plant, PBD_STEPS)):
                assert plant.fast, f"{name}/{mode}: the compiled path is not in use"
                report = plant.advance(steps)
                assert report.success, report.message
                e = plant.energy
                state = plant.net_state
                out.update({
                    f"{name}/{mode}/joints": np.asarray(plant.joint_state()[0], float),
                    f"{name}/{mode}/pressure": state.node_pressure,
                    f"{name}/{mode}/actuator": np.concatenate((state.actuator_position, state.actuator_velocity)),
                    f"{name}/{mode}/effort": np.asarray(plant.effort, float),
                    f"{name}/{mode}/energy": np.array([e.pump_work, e.dissipated_hydraulic, e.dissipated_friction]),
                })
    return out


def test_disable_jit_run_agrees_with_compiled_run(tmp_path):
    """Python (NUMBA_DISABLE_JIT=1) and compiled runs of the same scenes end in the same states to round-off."""
    target = tmp_path / "python.npz"
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    done = subprocess.run([sys.executable, __file__, str(target)], env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    python = dict(np.load(target))
    from hydraulics._compiled import JIT_ENABLED

    assert JIT_ENABLED
    compiled = run_scenes()
    assert sorted(python) == sorted(compiled)
    moved = 0
    for key, value in compiled.items():
        scale = max(float(np.max(np.abs(value), initial=0.0)), 1e-300)
        error = float(np.max(np.abs(python[key] - value), initial=0.0))
        print(f"{key}: max difference {error:.3e} (scale {scale:.3e})")
        assert error <= RTOL * scale, f"{key}: Python and compiled runs differ by {error:.3e} (scale {scale:.3e})"
        moved += key.endswith("/pressure") and scale > 1e6
    assert moved == 6  # every scene pressurised in both modes


PER_STEP_STEPS = 60  # of the per-step MuJoCo plant (1 ms): the boom's valve opens from 20 ms


def run_per_step() -> dict[str, np.ndarray]:
    """End states of the boom lift on the per-step MuJoCo plant (:class:`hydraulics.coupling.CouplingImplicit` and its
    variants calling the compiled stepper and coupling entries from Python), one per implicit coupling."""
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants.mujoco import MujocoPlant

    path, inputs, _ = _scenes()["boom"]
    out = {}
    for coupling in ("implicit", "implicit-linear", "rosenbrock"):
        scenario = load_scenario(path)
        scenario = scenario.with_overrides(inputs={**scenario.inputs, **inputs}, coupling=coupling)
        plant = MujocoPlant(load_scene(scenario))
        for _ in range(PER_STEP_STEPS):
            report = plant.step()
            assert report.success, report.message
        out[f"boom/{coupling}/joints"] = np.asarray(plant.joint_state()[0], float)
        out[f"boom/{coupling}/pressure"] = plant.net_state.node_pressure
        out[f"boom/{coupling}/effort"] = np.asarray(plant.effort, float)
    return out


def test_disable_jit_per_step_plant_agrees_with_compiled(tmp_path):
    """The backward-Euler stepper and the implicit couplings' entries called from Python (per-step MuJoCo plant) run
    as plain Python under NUMBA_DISABLE_JIT=1 and end where the compiled run ends, to round-off."""
    target = tmp_path / "per_step.npz"
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    done = subprocess.run([sys.executable, __file__, str(target), "per-step"], env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    python = dict(np.load(target))
    compiled = run_per_step()
    assert sorted(python) == sorted(compiled)
    for key, value in compiled.items():
        scale = max(float(np.max(np.abs(value), initial=0.0)), 1e-300)
        error = float(np.max(np.abs(python[key] - value), initial=0.0))
        assert error <= RTOL * scale, f"{key}: Python and compiled runs differ by {error:.3e} (scale {scale:.3e})"
    assert np.max(compiled["boom/implicit/pressure"]) > 1e6  # pressurised


if __name__ == "__main__":
    from hydraulics._compiled import JIT_ENABLED

    import inspect

    from sim.plants import mujoco_fast, pbd_block

    assert not JIT_ENABLED, "run with NUMBA_DISABLE_JIT=1"
    if sys.argv[2:] == ["per-step"]:
        from hydraulics import _compiled

        np.savez(sys.argv[1], **run_per_step())
        assert inspect.isfunction(_compiled.effort_law_kernel) and inspect.isfunction(_compiled._step_kernel)  # plain Python
        sys.exit(0)
    result = run_scenes()
    # the coupled steps ran as Python functions (no compiled entry point was made)
    assert inspect.isfunction(mujoco_fast._CALLBACK) and all(map(inspect.isfunction, pbd_block._BLOCK.values()))
    np.savez(sys.argv[1], **result)
