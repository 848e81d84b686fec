"""The explicit, incompressible and rigid-actuator kernels (hydraulics._compiled_rigid) and the fast MuJoCo plant's
callback for them run as plain Python under ``NUMBA_DISABLE_JIT=1`` and agree with the compiled run.

As ``tests/test_disable_jit.py`` (a subprocess steps the scenes as Python, this process compiled; end states agree
to 1e-12 of each quantity's largest magnitude), for the couplings that test does not step.

Run by hand: ``NUMBA_DISABLE_JIT=1 python tests/test_disable_jit_couplings.py out.npz``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from conftest import MODELS  # noqa: E402

RTOL = 1e-12
RIGID_FRONT = {"stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"}


def _ramp(t0, t1, value):
    from sim.io.scenario import Schedule

    return Schedule(np.array([0.0, t0, t1]), np.array([0.0, 0.0, value]))


def _scenes():
    """name → (scenario path, overrides, valve schedules, coupling, steps)."""
    dig = {"boom_valve": _ramp(0.02, 0.08, -0.35), "stick_valve": _ramp(0.03, 0.1, 0.8),
           "bucket_valve": _ramp(0.05, 0.12, 0.5), "swing_valve": _ramp(0.02, 0.1, 1.0)}
    fast_dig = {"boom_valve": _ramp(0.0, 0.001, -0.35), "stick_valve": _ramp(0.0, 0.001, 0.8),
                "bucket_valve": _ramp(0.0, 0.002, 0.5), "swing_valve": _ramp(0.0, 0.001, 1.0)}
    return {
        "excavator/incompressible": (MODELS / "excavator" / "dig.scenario.toml", {"fidelity": "incompressible"}, dig,
                                     None, 300),
        "push/incompressible": (MODELS / "excavator" / "push.scenario.toml", {"dt": 1e-2}, {}, None, 100),
        "boom/explicit": (MODELS / "boom" / "lift.scenario.toml", {"dt": 2e-5}, {"boom_valve": _ramp(0.0, 0.002, 1.0)},
                          "explicit", 300),
        "excavator/explicit+rigid": (MODELS / "excavator" / "dig.scenario.toml",
                                     {"dt": 2e-5, "actuator_fidelity": RIGID_FRONT}, fast_dig, "explicit", 200),
        "excavator/implicit+rigid": (MODELS / "excavator" / "dig.scenario.toml", {"actuator_fidelity": RIGID_FRONT},
                                     dig, None, 200),
    }


def run_scenes() -> dict[str, np.ndarray]:
    """End states of every scene on the fast MuJoCo plant, keyed ``scene/quantity``."""
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants.mujoco_fast import MujocoPlantFast

    out = {}
    for name, (path, overrides, inputs, coupling, steps) in _scenes().items():
        scenario = load_scenario(path).with_overrides(**overrides)
        if inputs:
            scenario = scenario.with_overrides(inputs={**scenario.inputs, **inputs})
        plant = MujocoPlantFast(load_scene(scenario), coupling=coupling)
        assert plant.fast, f"{name}: the compiled path is not in use"
        report = plant.advance(steps)
        assert report.success, report.message
        e, state = plant.energy, plant.net_state
        out.update({
            f"{name}/joints": np.asarray(plant.joint_state()[0], float),
            f"{name}/pressure": state.node_pressure,
            f"{name}/actuator": np.concatenate((state.actuator_position, state.actuator_velocity)),
            f"{name}/effort": np.asarray(plant.effort, float),
            f"{name}/bounds": np.array(plant.model.actuator_forcerange, float).ravel(),
            f"{name}/energy": np.array([e.pump_work, e.motor_work, e.dissipated_hydraulic, e.dissipated_friction]),
        })
    return out


def test_disable_jit_run_of_the_other_couplings_agrees_with_compiled_run(tmp_path):
    target = tmp_path / "python.npz"
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    done = subprocess.run([sys.executable, __file__, str(target)], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    python = dict(np.load(target))
    from hydraulics._jit import JIT_ENABLED

    assert JIT_ENABLED
    compiled = run_scenes()
    assert sorted(python) == sorted(compiled)
    for key, value in compiled.items():
        scale = max(float(np.max(np.abs(value), initial=0.0)), 1e-300)
        error = float(np.max(np.abs(python[key] - value), initial=0.0))
        print(f"{key}: max difference {error:.3e} (scale {scale:.3e})")
        assert error <= RTOL * scale, f"{key}: Python and compiled runs differ by {error:.3e} (scale {scale:.3e})"
    assert all(np.max(np.abs(compiled[f"{name}/pressure"])) > 1e6 for name in _scenes())


if __name__ == "__main__":
    import inspect

    from hydraulics._jit import JIT_ENABLED
    from sim.plants import mujoco_fast

    assert not JIT_ENABLED, "run with NUMBA_DISABLE_JIT=1"
    result = run_scenes()
    assert inspect.isfunction(mujoco_fast._CALLBACK)  # the coupled steps ran as a Python function
    np.savez(sys.argv[1], **result)
