"""Cost of logging and of start-up, as ratios measured in one run.

Logging: the excavator dig cycle (default 20 s, the whole scenario) in MuJoCo mode at 1 kHz with the
implicit and the Rosenbrock coupling, and in PBD mode (a shorter stretch, ``--pbd-seconds``: a PBD
step costs some twenty MuJoCo steps, so logging weighs less there); per plant four configurations,
repeated and interleaved:

``no log``        load the scene, build the plant (the fast block plant), check its load-time guards,
                  advance it in blocks of ``sim.run.runner.block_steps(dt)`` steps (the runner's
                  block size) with a finiteness check per block (``plant.end_finite``, from the
                  compiled loop, as ``run()`` checks it): everything ``run()`` does except logging;
``1 Hz``          ``sim.run.runner.run()`` logging one sample a second: what a run adds whatever it logs (the
                  log's set-up and close, the run loop's per-block checks: plausibility monitor, snapshots);
``100 Hz``        ``run()`` at the scenario's log rate (100 Hz): the same plus the recorder, the MCAP writer
                  and the per-sample checks (energy growth, monitor);
``every step``    ``run()`` logging all 1000 samples per second, recorded by the plant inside its
                  compiled loop (``advance(n, record, every)``).

Overhead = the median over pairs of (logged run / the no-log run just before it) − 1, with the
quartiles of the pairs: each pair shares the machine's state of the moment, and on a shared machine
the run-to-run spread (±15 %) is larger than the logging's cost.  Wall time is the target's measure
(the log's writer thread overlaps the stepping on a second core); the CPU time of the process (all
threads) is given beside it, in brackets.  Targets: 100 Hz ≤ 5 %, every step ≤ 25 % (paired wall
median), on the MuJoCo-mode dig.

Where the cost lands: the CPU time of the run's own thread (the stepping, the checks, the recorder's
``derive`` and ``push``; paired median over the no-log run's) and that of the other threads (the
log's writer thread: fields, encoding, merge, compression, writes; µs per step).  With a second core
free for the writer, the wall-time overhead tends to the run's thread's share; on a machine whose
cores are busy with other jobs it tends to the process's.  The writer can only overlap the stepping
if the block releases Python's GIL while it steps (``mj_step`` of the bindings does, and the control
callback is a numba ``cfunc`` that never takes it): ``GIL while stepping`` gives the rate of a
Python thread counting while the plant advances blocks of ``block_steps(dt)`` steps, relative to its
rate while the main thread sleeps (0 % if the block held the GIL; below 100 % when the two threads
share a core with other jobs).

Fixed cost of a log: opening it (run metadata, attachments), registering the run's channels and the
scene, and closing it (last batch, summary), timed alone on a one-sample log.

Per sample (logging every step, batches of the recorder's ring): in the run's thread ``derive`` (what
the checks need: node volumes, stored oil energy, energy residual) and ``push`` (the ring handed to the
log); on the writer's thread ``fill`` (the other logged fields and the cylinder scene), ``encode`` (the
MCAP Message records, a compiled pass), ``merge`` (log-time order, chunk records and message indexes)
and ``compress`` (zstd, CRC-32 and the file writes); plus ``record``, the plant's copy of a sample
inside its compiled loop (the difference of blocks with and without recording: noisy).

Start-up: ``hydroplant run`` of the dig scenario for one step in a fresh interpreter
(import, scene load, plant with its compiled callback, first step, log closed), twice:
the first may compile numba kernels into the disk cache, the second shows the cached
cost; wall and CPU time (user + system) of the process, since other jobs on a shared
machine stretch the wall time.  Target: under 2 s.

Run: ``.venv/bin/python bench/bench_logging.py [--seconds 20] [--reps 11]``.
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


PLANTS = {  # label: scenario overrides
    "MuJoCo implicit": {"coupling": "implicit"},
    "MuJoCo rosenbrock": {"coupling": "rosenbrock"},
    "PBD": {"mode": "pbd"},
}
RATES = {"1 Hz": 1.0, "100 Hz": 100.0, "every step": 1000.0}  # log rates of the dig at 1 kHz
TARGETS = {"100 Hz": 0.05, "every step": 0.25}  # on the MuJoCo-mode plants


def scenario(seconds: float, plant: dict, **overrides):
    from sim.io.scenario import load_scenario

    return load_scenario(DIG).with_overrides(duration=seconds, **plant, **overrides)


def no_log(seconds: float, plant: dict) -> tuple[float, float, float]:
    """Wall, process CPU and this thread's CPU time of everything run() does except logging (see module
    docstring) [s]."""
    from sim.run.guards import check_plant
    from sim.run.runner import block_steps, make_plant
    from sim.io.scene import load_scene

    t, c, m = time.perf_counter(), time.process_time(), time.thread_time()
    run_scenario = scenario(seconds, plant)
    plant = make_plant(load_scene(run_scenario))
    check_plant(plant)  # run() checks the load-time guards whether it logs or not
    assert plant.fast
    steps, block = run_scenario.step_count, block_steps(run_scenario.dt)
    while plant.step_index < steps:
        report = plant.advance(min(block, steps - plant.step_index))
        if not (report.success and plant.end_finite):
            raise RuntimeError(report.message)
    return time.perf_counter() - t, time.process_time() - c, time.thread_time() - m


def with_log(seconds: float, plant: dict, rate_hz: float, out: Path) -> tuple[float, float, float]:
    """Wall, process CPU and this thread's CPU time of ``run()`` logging at ``rate_hz`` [s]."""
    from sim.run.runner import run

    t, c, m = time.perf_counter(), time.process_time(), time.thread_time()
    result = run(scenario(seconds, plant, log_rate_hz=rate_hz), out=out)
    elapsed = time.perf_counter() - t, time.process_time() - c, time.thread_time() - m
    assert result.status == "complete", result.message
    out.unlink()
    return elapsed


def fixed_cost(out: Path, reps: int = 7) -> dict:
    """ms to open a run's log, register its channels and scene, and close it (one sample), medians of ``reps``."""
    from sim.io.mcap_log import LogWriter
    from sim.run.recorder import RunRecorder
    from sim.run.runner import input_files, make_plant, run_metadata
    from sim.io.scene import load_scene

    run_scenario = scenario(1.0, {})
    scene = load_scene(run_scenario)
    plant = make_plant(scene)
    times: dict[str, list[float]] = {"open": [], "channels": [], "close": []}
    for i in range(reps + 1):
        path = out / f"fixed{i}.mcap"
        t0 = time.perf_counter()
        attachments = [(name, media, data) for name, media, _, data in input_files(scene)]
        log = LogWriter(path, dt=run_scenario.dt, run_metadata=run_metadata(run_scenario, plant), attachments=attachments)
        t1 = time.perf_counter()
        recorder = RunRecorder(log, plant, tf_every=run_scenario.tf_every)
        recorder.capture(plant.step_index)
        t2 = time.perf_counter()
        log.close()
        t3 = time.perf_counter()
        path.unlink()
        if i:  # (the first warms the caches)
            for name, a, b in (("open", t0, t1), ("channels", t1, t2), ("close", t2, t3)):
                times[name].append((b - a) * 1e3)
    return {name: statistics.median(v) for name, v in times.items()}


def sample_parts(samples: int, out: Path) -> dict:
    """µs per sample of the logging stages (see the module docstring), logging every step of the dig from its start.

    The log is written without its chunk thread, each stage timed alone in CPU time: the run's
    thread (derive, push) and the writer's (fill, encode, merge, compress); ``record`` in wall time.
    """
    import dataclasses

    import numpy as np

    from sim.io.log_writer import _merge_blocks
    from sim.io.mcap_log import LogWriter
    from sim.run.recorder import RunRecorder
    from sim.run.runner import make_plant
    from sim.io.scene import load_scene

    run_scenario = scenario(1.0, {})
    plant = make_plant(load_scene(run_scenario))
    plant.advance(10)
    clock = time.thread_time  # CPU time: the stages run in this thread (no chunk thread), other jobs do not count
    stages = dict.fromkeys(("derive", "push", "fill", "encode", "merge", "compress"), 0.0)
    messages = size = 0
    # batches of the recorder's ring, as in a run; the chunks' compression and writing timed apart from the merge
    with LogWriter(out / "parts.mcap", dt=run_scenario.dt, flush_interval=float("inf"), chunk_thread=False) as log:
        write_chunk = log._writer._write_chunk

        def timed_write_chunk(*args):
            t = clock()
            write_chunk(*args)
            stages["compress"] += clock() - t
        log._writer._write_chunk = timed_write_chunk
        # consecutive steps, as run() logs every step: /tf on the steps at multiples of the scenario's tf_every
        recorder = RunRecorder(log, plant, tf_every=run_scenario.with_overrides(log_rate_hz=1.0 / run_scenario.dt).tf_every)
        done = 0
        while done < samples:
            rows = min(recorder.room - 1, samples - done)
            first = plant.step_index + 1
            plant.advance(rows + 1, recorder.record_target(rows), 1)
            recorder.commit_recorded(first, 1, plant.recorded)
            recorder.capture(plant.step_index)
            done += plant.recorded + 1
            t = clock()
            recorder.derive()
            t1 = clock()
            recorder.push()
            t2 = clock()
            jobs = recorder.frame._take_jobs()
            t3 = clock()
            for job in jobs:
                for first_row, fill, lo, hi in job.fills:
                    fill(job.buffer[first_row:first_row + hi - lo], lo, hi)
            t4 = clock()
            blocks = [dataclasses.replace(job, fills=()).block() for job in jobs]
            compressing = stages["compress"]
            t5 = clock()
            log._writer.add_records(_merge_blocks(blocks))
            t6 = clock()
            for name, a, b in (("derive", t, t1), ("push", t1, t3), ("fill", t3, t4), ("encode", t4, t5),
                               ("merge", t5, t6)):
                stages[name] += b - a
            stages["merge"] -= stages["compress"] - compressing  # (chunks that filled up were written in add_records)
            messages += sum(len(b.log_times) * len(b.offsets) for b in blocks)
            size += sum(b.rows.size for b in blocks)
        log._writer.flush()
    messages, size = messages / done, size / done
    # record: the plant's in-block copy of a sample, per recorded row (blocks of 10 steps, 9 rows recorded), as
    # the difference of alternating blocks with and without recording
    clock = time.perf_counter
    rows = np.empty((9, plant.record_width))
    with_record, without = [], []
    for i in range(400):
        t = clock()
        if i % 2:
            plant.advance(10, rows, 1)
            with_record.append(clock() - t)
        else:
            plant.advance(10)
            without.append(clock() - t)
    record = (statistics.median(with_record) - statistics.median(without)) / 9
    parts = {name: value / done * 1e6 for name, value in stages.items()}
    return {**parts, "record": record * 1e6, "messages": messages, "bytes": size, "ring": recorder.room}


def gil_while_stepping(plant_overrides: dict, blocks: int = 20) -> tuple[float, int]:
    """Rate of a Python thread counting while the main thread advances the plant in blocks of the runner's size,
    over its rate while the main thread sleeps for as long (see the module docstring), and that block size [steps]."""
    import threading

    from sim.io.scene import load_scene
    from sim.run.runner import block_steps, make_plant

    run_scenario = scenario(30.0, plant_overrides)
    plant = make_plant(load_scene(run_scenario))
    block = block_steps(run_scenario.dt)
    plant.advance(block)  # (warm)
    count, done = [0], threading.Event()

    def counter() -> None:
        n = 0
        while not done.is_set():
            n += 1
            count[0] = n

    thread = threading.Thread(target=counter, daemon=True)
    thread.start()
    try:
        time.sleep(0.05)
        c0, t0 = count[0], time.perf_counter()
        for _ in range(blocks):
            plant.advance(block)
        stepping, seconds = count[0] - c0, time.perf_counter() - t0
        c0, t0 = count[0], time.perf_counter()
        time.sleep(seconds)
        alone = (count[0] - c0) / (time.perf_counter() - t0)
    finally:
        done.set()
        thread.join()
    return stepping / seconds / alone, block


def paired(values: list, base: list) -> tuple[float, float, float]:
    """Median and quartiles of value / base − 1 over the pairs (wall time)."""
    ratios = sorted(v[0] / b[0] - 1.0 for v, b in zip(values, base))
    if len(ratios) == 1:
        return ratios[0], ratios[0], ratios[0]
    q = statistics.quantiles(ratios, n=4)
    return q[1], q[0], q[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per MuJoCo-mode run [s]")
    parser.add_argument("--pbd-seconds", type=float, default=2.0, help="simulated seconds per PBD-mode run [s]")
    parser.add_argument("--reps", type=int, default=11)
    parser.add_argument("--plants", default=",".join(PLANTS), help="comma-separated, of: " + ", ".join(PLANTS))
    parser.add_argument("--no-startup", action="store_true")
    parser.add_argument("--no-parts", action="store_true", help="leave out the fixed cost and the per-sample stages")
    args = parser.parse_args()
    plants = [name.strip() for name in args.plants.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        if not args.no_startup:
            startup(out)
        for label in plants:
            plant = PLANTS[label]
            seconds = args.pbd_seconds if plant.get("mode") == "pbd" else args.seconds
            no_log(0.02, plant)  # warm: callback compiled, kernels loaded, caches hot
            for rate in RATES.values():
                with_log(0.02, plant, rate, out / "warm.mcap")
            times: dict[str, list] = {"no log": [], **{name: [] for name in RATES}}
            for rep in range(args.reps):
                times["no log"].append(no_log(seconds, plant))
                for name, rate in RATES.items():
                    times[name].append(with_log(seconds, plant, rate, out / f"{rep}.mcap"))
            steps = round(seconds / 1e-3)
            base = times["no log"]
            base_wall, base_cpu = (statistics.median(v[k] for v in base) for k in (0, 1))
            print(f"{label}: excavator dig, {seconds:g} s at 1 kHz ({steps} steps), {args.reps} interleaved runs per "
                  f"configuration, medians (wall time; CPU time of the process in brackets):")
            split = []
            for name, values in times.items():
                wall, cpu = (statistics.median(v[k] for v in values) for k in (0, 1))
                line = f"  {name:12s} {wall:7.3f} s [{cpu:7.3f} s]  {wall / steps * 1e6:7.2f} µs/step [{cpu / steps * 1e6:7.2f}]"
                if name != "no log":
                    median, low, high = paired(values, base)
                    cpu_over = statistics.median(v[1] / b[1] - 1.0 for v, b in zip(values, base))
                    line += (f"  overhead: paired median {median:+6.1%} (quartiles {low:+.1%} / {high:+.1%}) "
                             f"[CPU {cpu_over:+6.1%}], {(wall - base_wall) / steps * 1e6:+.2f} µs/step")
                    if plant.get("mode") != "pbd" and name in TARGETS:
                        line += f"; target ≤ {TARGETS[name]:.0%}: {'met' if median <= TARGETS[name] else 'NOT met'}"
                    own = statistics.median(v[2] / b[2] - 1.0 for v, b in zip(values, base))
                    others = statistics.median(((v[1] - v[2]) - (b[1] - b[2])) / steps * 1e6 for v, b in zip(values, base))
                    split.append(f"{name} {own:+.1%}, {others:+.2f} µs/step")
                print(line, flush=True)
            print(f"  CPU time of the run's thread (paired median) and of the other threads: {'; '.join(split)}")
            if plant.get("mode") != "pbd":
                rate, block = gil_while_stepping(plant)
                print(f"  GIL while stepping: a Python thread counts at {rate:.0%} of its rate alone while the plant "
                      f"advances blocks of {block} steps", flush=True)
        if not args.no_parts:
            fixed = fixed_cost(out)
            print(f"fixed cost of a run's log: open {fixed['open']:.2f} ms, channels and scene {fixed['channels']:.2f} ms, "
                  f"close {fixed['close']:.2f} ms (medians of 7)")
            parts = sample_parts(4000, out)
            print(f"one sample logging every step (MuJoCo implicit): {parts['messages']:.1f} messages, {parts['bytes']:.0f} B "
                  f"of Message records; run's thread: derive {parts['derive']:.2f} µs, push {parts['push']:.2f} µs; "
                  f"writer's thread: fill {parts['fill']:.2f} µs, encode {parts['encode']:.2f} µs, merge {parts['merge']:.2f} µs, "
                  f"compress {parts['compress']:.2f} µs; record inside the plant's loop {parts['record']:.2f} µs "
                  f"(median difference, noisy); batches of {parts['ring']}")


if __name__ == "__main__":
    main()
