"""Cost of logging and of start-up, as ratios measured in one run.

Logging: the excavator dig cycle at 1 kHz for a few simulated seconds (default 3 s,
from t = 0, the approach and the start of the dig), each configuration repeated and
interleaved, medians reported:

``no log``        load the scene, build :class:`MujocoPlantFast`, check its load-time guards,
                  advance it in blocks of ``sim.run.runner.block_steps(dt)`` steps (the runner's
                  block size at the default 100 Hz log rate) with a finiteness check per block
                  (``plant.end_finite``, from the compiled loop, as ``run()`` checks it):
                  everything ``run()`` does except logging;
``default log``   ``sim.run.runner.run()`` at the scenario's log rate (100 Hz), the same work
                  plus the recorder, the MCAP writer and the divergence/energy checks;
``every step``    ``run()`` logging all 1000 samples per second: blocks as long as at the default
                  rate (``sim.run.runner.block_steps``), the samples inside a block copied by the
                  plant from its compiled loop (``MujocoPlantFast.advance(n, record, every)``);
``per-step path`` for reference, ``run(..., fast=False)`` at 100 Hz: :class:`MujocoPlant`, one
                  Python-orchestrated step at a time (``run()``'s per-step path).

Overhead = (time / no-log time) − 1 of the medians (wall and CPU), and the median and quartiles of
the paired overheads (each logged run against the no-log run just before it, which shares the
machine's state of the moment: on a shared machine the run-to-run spread, ±15 %, is larger than the
logging's cost).  Targets: default ≤ 10 %, every step ≤ 50 %, judged on the paired median.
The per-sample cost is split into the recorder's stages (``capture`` of the raw state per
sample from Python at a block's end, or ``record`` of a sample inside a block by the plant's
compiled loop; ``derive`` and ``push`` per batch), CDR encoding (the MCAP Message records of
a sample, filled in a compiled pass) and MCAP writing, by timing those parts alone on the same
plant.

Start-up: ``hydroplant run`` of the dig scenario for one step in a fresh interpreter
(import, scene load, plant with its compiled callback, first step, log closed), twice:
the first may compile numba kernels into the disk cache, the second shows the cached
cost; wall and CPU time (user + system) of the process, since other jobs on a shared
machine stretch the wall time.  Target: under 2 s.

Run: ``.venv/bin/python bench/bench_logging.py [--seconds 3] [--reps 3]``.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DIG = ROOT / "models" / "excavator" / "dig.scenario.toml"

STARTUP_SCRIPT = r"""
import json, sys, time
t0 = time.perf_counter()
from sim.run.runner import run, make_plant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
t_import = time.perf_counter()
scenario = load_scenario(sys.argv[1]).with_overrides(duration=float(sys.argv[3]))
scene = load_scene(scenario)
t_scene = time.perf_counter()
plant = make_plant(scene)
t_plant = time.perf_counter()
plant.step()
t_step = time.perf_counter()
result = run(scenario, out=sys.argv[2])
t_run = time.perf_counter()
print(json.dumps({"import": t_import - t0, "scene": t_scene - t_import, "plant": t_plant - t_scene,
                  "first_step": t_step - t_plant, "run_again": t_run - t_step, "fast": bool(getattr(plant, "fast", False))}))
"""


def startup(out_dir: Path) -> None:
    """Fresh interpreters: ``hydroplant run`` end to end, and its parts."""
    print("start-up of `hydroplant run` (fresh interpreter, dig scenario, 1 step of 1 ms):")
    for attempt in (1, 2):
        t = time.perf_counter()
        cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
        cli = subprocess.run([sys.executable, "-m", "sim.cli", "run", str(DIG), "--duration", "0.001", "--no-progress",
                              "--out", str(out_dir / f"startup{attempt}.mcap")], cwd=ROOT, capture_output=True, text=True)
        total = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - cpu.ru_utime) + (after.ru_stime - cpu.ru_stime)
        if cli.returncode != 0:
            raise SystemExit(cli.stderr)
        t = time.perf_counter()
        parts = subprocess.run([sys.executable, "-c", STARTUP_SCRIPT, str(DIG), str(out_dir / f"parts{attempt}.mcap"), "0.001"],
                               cwd=ROOT, capture_output=True, text=True)
        if parts.returncode != 0:
            raise SystemExit(parts.stderr)
        p = json.loads(parts.stdout.strip().splitlines()[-1])
        print(f"  run {attempt}: hydroplant run {total:5.2f} s wall, {cpu:5.2f} s CPU | python startup+import {p['import']:5.2f} s, scene load "
              f"{p['scene']:5.2f} s, plant (fast={p['fast']}) {p['plant']:5.2f} s, first step {p['first_step'] * 1e3:6.1f} ms, "
              f"a second run() in the same process {p['run_again']:5.2f} s")


def no_log(seconds: float, block: int) -> tuple[float, float]:
    """Wall and CPU time of everything run() does except logging (see module docstring) [s]."""
    from sim.run.guards import check_plant
    from sim.run.runner import make_plant
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene

    t, c = time.perf_counter(), time.process_time()
    scenario = load_scenario(DIG).with_overrides(duration=seconds)
    plant = make_plant(load_scene(scenario))
    check_plant(plant)  # run() checks the load-time guards whether it logs or not
    assert plant.fast
    steps = scenario.step_count
    while plant.step_index < steps:
        report = plant.advance(min(block, steps - plant.step_index))
        if not (report.success and plant.end_finite):
            raise RuntimeError(report.message)
    return time.perf_counter() - t, time.process_time() - c


def with_log(seconds: float, rate_hz: float, out: Path, fast: bool = True) -> tuple[float, float]:
    """Wall and CPU time of ``run()`` at ``rate_hz`` [s] (``fast=False``: the per-step path)."""
    from sim.run.runner import run
    from sim.io.scenario import load_scenario

    t, c = time.perf_counter(), time.process_time()
    result = run(load_scenario(DIG).with_overrides(duration=seconds, log_rate_hz=rate_hz), out=out, fast=fast)
    elapsed = time.perf_counter() - t, time.process_time() - c
    assert result.status == "complete", result.message
    return elapsed


def sample_parts(samples: int, out: Path) -> dict:
    """µs per sample of the recorder's stages, on a plant at the dig's start, logging every step.

    capture (raw state into the ring, per sample), derive (the logged fields of a
    whole ring, vectorised, per sample), push (rows into the log's frame), encode
    (CDR Message records), write (merge, chunks, message indexes, zstd); plus, for comparison, the
    per-sample numpy hydraulic terms computed sample by sample.
    """
    from sim.io.mcap_log import LogWriter
    from sim.run.recorder import RunRecorder
    from sim.run.runner import make_plant
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene

    scenario = load_scenario(DIG)
    plant = make_plant(load_scene(scenario))
    plant.advance(10)
    with LogWriter(out, dt=scenario.dt, overwrite=True, flush_interval=float("inf"), batch_size=samples + 1) as log:
        # consecutive steps, as run() logs every step: /tf on the steps at multiples of the scenario's tf_every
        recorder = RunRecorder(log, plant, tf_every=scenario.with_overrides(log_rate_hz=1.0 / scenario.dt).tf_every)
        first = plant.step_index
        capture = derive = push = 0.0
        for i in range(samples):
            t = time.perf_counter()
            due = recorder.capture(first + i)
            capture += time.perf_counter() - t
            if due or i == samples - 1:
                t = time.perf_counter()
                recorder.derive()
                t2 = time.perf_counter()
                recorder.push()
                derive, push = derive + (t2 - t), push + (time.perf_counter() - t2)
        t1 = time.perf_counter()
        for frame in log._frames:
            frame._encode()
        for channel in log._channels:
            channel._encode_buffer()
        t2 = time.perf_counter()
        blocks = [block for owner in (*log._frames, *log._channels) for block in owner._encoded]
        messages = sum(len(block.log_times) * len(block.offsets) for block in blocks)
        size = sum(block.rows.size for block in blocks)
        t2b = time.perf_counter()
        log._drain_now(end_chunk=True)  # merge in log-time order, MCAP records, compress the chunks, write
        t3 = time.perf_counter() - (t2b - t2)
    # record: the plant's in-block copy of a sample, per recorded row (blocks of 10 steps, 9 rows recorded), as
    # the difference of alternating blocks with and without recording
    import numpy as np

    rows = np.empty((9, plant.record_width))
    with_record, without = [], []
    for i in range(400):
        t = time.perf_counter()
        if i % 2:
            plant.advance(10, rows, 1)
            with_record.append(time.perf_counter() - t)
        else:
            plant.advance(10)
            without.append(time.perf_counter() - t)
    record = (statistics.median(with_record) - statistics.median(without)) / 9
    from hydraulics.energy import stored_energy

    net, state = plant.network, plant.net_state
    t4 = time.perf_counter()
    for _ in range(samples):
        net.chamber_stiffness(state.node_pressure, state.actuator_position)
        stored_energy(net, state)
        net.pressure_effort(state.node_pressure)
    t5 = time.perf_counter()
    for _ in range(samples):
        plant.mechanical_energy()
    t6 = time.perf_counter()
    per = lambda a, b: (b - a) / samples * 1e6  # noqa: E731
    return {"capture": capture / samples * 1e6, "derive": derive / samples * 1e6, "push": push / samples * 1e6,
            "encode": per(t1, t2), "write": per(t2, t3), "messages": messages / samples,
            "bytes": size / samples, "hydraulic_terms": per(t4, t5), "mechanics": per(t5, t6),
            "ring": len(recorder._raw), "record": record * 1e6}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="simulated seconds per run [s]")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--no-startup", action="store_true")
    parser.add_argument("--per-step-reps", type=int, default=1,
                        help="runs of the per-step path (a reference, ≈ 0.4 ms per step), in the first reps")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        if not args.no_startup:
            startup(out)
        from sim.run.runner import block_steps

        block = block_steps(1e-3)
        no_log(0.02, block)  # warm: callback compiled, kernels loaded, caches hot
        with_log(0.02, 100.0, out / "warm.mcap")
        times = {"no log": [], "default log (100 Hz)": [], "every step (1 kHz)": [], "per-step path, 100 Hz": []}
        for rep in range(args.reps):
            times["no log"].append(no_log(args.seconds, block))
            times["default log (100 Hz)"].append(with_log(args.seconds, 100.0, out / f"d{rep}.mcap"))
            times["every step (1 kHz)"].append(with_log(args.seconds, 1000.0, out / f"e{rep}.mcap"))
            if rep < args.per_step_reps:
                times["per-step path, 100 Hz"].append(with_log(args.seconds, 100.0, out / f"p{rep}.mcap", fast=False))
        steps = round(args.seconds / 1e-3)
        base = [statistics.median(v[k] for v in times["no log"]) for k in (0, 1)]
        print(f"excavator dig, {args.seconds:g} s at 1 kHz ({steps} steps), median of {args.reps} interleaved runs "
              f"(wall time; CPU time of the process in brackets):")
        targets = {"default log (100 Hz)": 0.10, "every step (1 kHz)": 0.50}
        for name, values in times.items():
            if not values:
                continue
            wall, cpu = (statistics.median(v[k] for v in values) for k in (0, 1))
            line = f"  {name:22s} {wall:7.3f} s [{cpu:7.3f} s]  {wall / steps * 1e6:7.1f} µs/step [{cpu / steps * 1e6:7.1f}]"
            if name in targets:
                over, over_cpu = wall / base[0] - 1.0, cpu / base[1] - 1.0
                # each run against the no-log run just before it: the pairs share the machine's state of the moment
                paired = sorted(v[0] / n[0] - 1.0 for v, n in zip(values, times["no log"]))
                quartiles = statistics.quantiles(paired, n=4) if len(paired) > 1 else paired * 3
                line += (f"  overhead {over:+7.1%} [{over_cpu:+7.1%}]; paired runs: median {quartiles[1]:+.1%} "
                         f"(quartiles {quartiles[0]:+.1%} / {quartiles[2]:+.1%}; target ≤ {targets[name]:.0%}: "
                         f"{'met' if quartiles[1] <= targets[name] else 'NOT met'})")
            print(line, flush=True)
        parts = sample_parts(2000, out / "parts.mcap")
        print(f"  one sample (every step): {parts['messages']:.1f} messages, {parts['bytes']:.0f} B of Message records (CDR); capture {parts['capture']:.1f} µs "
              f"(of which mechanical energy {parts['mechanics']:.1f} µs) at a block's end, or record {parts['record']:.2f} µs "
              f"inside a block (median difference, noisy), derive {parts['derive']:.1f} µs and push "
              f"{parts['push']:.1f} µs (per sample, in batches of {parts['ring']}), encode {parts['encode']:.1f} µs, "
              f"write {parts['write']:.1f} µs (merge, chunks, message indexes, zstd); for comparison, the per-sample numpy "
              f"hydraulic terms (chamber_stiffness, stored_energy, pressure_effort) cost {parts['hydraulic_terms']:.1f} µs")


if __name__ == "__main__":
    main()
