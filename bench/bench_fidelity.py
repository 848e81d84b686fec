"""Excavator dig cycle at each fidelity level against the ``lines`` level: error and cost per level.

    python bench/bench_fidelity.py [--duration S] [--reference-dt S]

The reference is the ``lines`` level (hoses as π-lines) in MuJoCo mode with
implicit coupling at ``--reference-dt``.  Errors are max over the run of joint
angles [rad], cylinder strokes [m] and chamber pressures [bar] (interpolated
onto the reference's 100 Hz log times); cost is wall time per simulated second.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
from pathlib import Path

import numpy as np

from sim.io.mcap_log import read_log
from sim.run.runner import run

DIG = Path(__file__).resolve().parents[1] / "models/excavator/dig.scenario.toml"
CYLINDERS = ("boom_cyl", "stick_cyl", "bucket_cyl")
JOINTS = ("swing", "boom", "stick", "bucket")


RIGID_FRONT = {"stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"}
SETTINGS = (  # (label, run overrides)
    ("incompressible", {"fidelity": "incompressible", "dt": 1 / 30}),
    ("incompressible", {"fidelity": "incompressible", "dt": 1e-3}),
    ("compressible boom, rigid front", {"actuator_fidelity": RIGID_FRONT, "dt": 1e-3}),
    ("compressible boom, rigid front", {"actuator_fidelity": RIGID_FRONT, "dt": 2e-3}),
    ("… PBD 1/30 s × 20 substeps", {"actuator_fidelity": RIGID_FRONT, "dt": 1 / 30, "mode": "pbd", "pbd_substeps": 20,
                                     "pbd_iterations": 4}),
    ("compressible", {"fidelity": "compressible", "dt": 1e-3}),
    ("lines", {"fidelity": "lines", "dt": 2e-3}),
)
"""Levels and mixes measured; "rigid front": stick, bucket and swing ``incompressible`` (rigid actuators of the
compressible network, :class:`hydraulics.coupling.CouplingMixed`)."""


def signals(path):
    log = read_log(path)
    joints = log.topic("/hydroplant/joint_states")
    out = {"t": joints.t}
    for j in JOINTS:
        out[f"joint/{j}"] = joints[f"position/{j}"]
    for c in CYLINDERS:
        cyl = log.topic(f"/hydroplant/cylinders/{c}")
        out[f"stroke/{c}"] = np.interp(joints.t, cyl.t, cyl["position_m"])
        for side in ("p_cap_pa", "p_rod_pa"):
            out[f"pressure/{c}.{side}"] = np.interp(joints.t, cyl.t, cyl[side])
    return out


def errors(run_signals, reference):
    t = reference["t"]
    worst = {"joint": 0.0, "stroke": 0.0, "pressure": 0.0}
    for key, ref in reference.items():
        if key == "t":
            continue
        value = np.interp(t, run_signals["t"], run_signals[key])
        kind = key.split("/")[0]
        worst[kind] = max(worst[kind], float(np.max(np.abs(value - ref))))
    return worst


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--reference-dt", type=float, default=1e-3)
    args = parser.parse_args(argv)
    out = Path(tempfile.mkdtemp(prefix="fidelity-"))
    print(f"machine: {platform.machine()} {platform.python_version()}; dig cycle {args.duration:g} s; "
          f"reference: lines level, implicit coupling, dt {args.reference_dt:g} s")
    reference_run = run(DIG, out=out / "reference.mcap", overrides={"fidelity": "lines", "dt": args.reference_dt, "duration": args.duration})
    reference = signals(reference_run.log_path)
    print(f"{'level':<34} {'dt [s]':>8} {'status':>9} {'wall/sim':>9} {'joint [rad]':>12} {'stroke [mm]':>12} {'pressure [bar]':>15}")
    for label, overrides in SETTINGS:
        dt = overrides["dt"]
        result = run(DIG, out=out / f"{len(label)}-{dt:g}.mcap", overrides={**overrides, "duration": args.duration})
        e = errors(signals(result.log_path), reference) if result.status == "complete" else {"joint": np.nan, "stroke": np.nan, "pressure": np.nan}
        print(f"{label:<34} {dt:8.4g} {result.status:>9} {result.wall_time / result.simulated_time:9.3f} "
              f"{e['joint']:12.4f} {1e3 * e['stroke']:12.1f} {e['pressure'] / 1e5:15.1f}", flush=True)
    print(f"{'lines (ref)':<34} {args.reference_dt:8.4g} {reference_run.status:>9} {reference_run.wall_time / reference_run.simulated_time:9.3f}")


if __name__ == "__main__":
    main()
