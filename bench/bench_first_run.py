"""The first run on a cold kernel cache: what it costs, and what the run reports.

    python bench/bench_first_run.py [--scenario models/excavator/dig.scenario.toml] [--modes mujoco pbd]
                                    [--inline] [--markdown]

For each mode, ``hydroplant run SCENARIO --mode MODE`` in a fresh process whose numba cache is an empty
temporary folder (``NUMBA_CACHE_DIR``), as on a fresh clone, then once more on the cache it filled (a later run):

* process wall and CPU time (user + system of the child, ``resource.getrusage``), as ``/usr/bin/time`` reports;
* the run's own figures: its reported wall time (the timed loop), real-time factor, the compile time it excluded
  (``RunResult.compile_time``) and the functions numba compiled;
* with ``--inline``: a third, cold process that runs with ``warm=False`` (the kernels compiled at their first
  call, inside the timed loop): the wall time a run reports when compilation is not kept out of it.

A cold run of the excavator takes minutes of CPU per mode (longer on a busy machine: the process wall time
stretches, the CPU time much less).  The runs are deterministic; only their times vary.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import json, sys
from sim.run.runner import run
from sim.io.scenario import load_scenario
scenario = load_scenario(sys.argv[1]).with_overrides(mode=sys.argv[2])
result = run(scenario, out=sys.argv[3], warm=sys.argv[4] == "warm", progress=False)
print(json.dumps({"status": result.status, "wall": result.wall_time, "rtf": result.real_time_factor,
                  "compile": result.compile_time, "compiled": result.kernels_compiled}))
"""


def timed_run(scenario: Path, mode: str, cache: Path, warm: bool) -> dict:
    """One run in a fresh process with numba's cache in ``cache``: the child's figures and its process wall and CPU
    time [s]."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        done = subprocess.run([sys.executable, "-c", CHILD, str(scenario), mode, str(Path(tmp) / "run.mcap"),
                               "warm" if warm else "inline"], cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode:
        raise SystemExit(f"run failed ({mode}):\n{done.stderr[-3000:]}")
    out = json.loads(done.stdout.strip().splitlines()[-1])
    announced = [line for line in done.stderr.splitlines() if line.startswith("hydroplant: compiling kernels")]
    return dict(out, process_wall=wall, cpu=(after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
                announced=bool(announced))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", type=Path, default=ROOT / "models/excavator/dig.scenario.toml")
    parser.add_argument("--modes", nargs="+", default=["mujoco", "pbd"])
    parser.add_argument("--inline", action="store_true", help="also a cold run with warm=False (compiled in the loop)")
    parser.add_argument("--markdown", action="store_true", help="a Markdown table (else plain text)")
    parser.add_argument("--keep-cache", type=Path, metavar="DIR", help="fill DIR/MODE (emptied first) as each mode's "
                        "cache and keep it (default: temporary folders)")
    args = parser.parse_args(argv)
    rows = []
    for mode in args.modes:
        with tempfile.TemporaryDirectory(prefix="hydroplant-numba-cache-") as folder:
            cache = Path(folder) if args.keep_cache is None else args.keep_cache / mode
            if args.keep_cache is not None:
                shutil.rmtree(cache, ignore_errors=True)
                cache.mkdir(parents=True)
            cold = timed_run(args.scenario, mode, cache, warm=True)
            later = timed_run(args.scenario, mode, cache, warm=True)
        rows.append((mode, "first run (empty cache)", cold))
        rows.append((mode, "later run (cache filled)", later))
        if args.inline:
            with tempfile.TemporaryDirectory(prefix="hydroplant-numba-cache-") as folder:
                rows.append((mode, "first run, warm=False", timed_run(args.scenario, mode, Path(folder), warm=False)))
        print(f"  {mode}: done", file=sys.stderr, flush=True)
    name = args.scenario.relative_to(ROOT) if args.scenario.is_relative_to(ROOT) else args.scenario
    print(f"{name}, {os.cpu_count()} cores; process times of `hydroplant run` in a fresh interpreter")
    print()
    head = ("mode", "process", "process wall [s]", "process CPU [s]", "functions compiled", "compile/load excluded [s]",
            "reported wall time [s]", "real-time factor")
    if args.markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "|".join(["---"] * 2 + ["---:"] * (len(head) - 2)) + "|")
    else:
        print("  ".join(f"{h:>14}" for h in head))
    for mode, label, r in rows:
        cells = (mode, label, f"{r['process_wall']:.1f}", f"{r['cpu']:.1f}", str(r["compiled"]), f"{r['compile']:.1f}",
                 f"{r['wall']:.2f}", f"{r['rtf']:.2f}")
        print(("| " + " | ".join(cells) + " |") if args.markdown else "  ".join(f"{c:>14}" for c in cells))
    announced = [f"{mode} {label}" for mode, label, r in rows if r["announced"]]
    print()
    print("compilation announced on stderr by: " + (", ".join(announced) if announced else "none"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
