"""The first run on a fresh clone: before (empty kernel cache) and after the install built it, and what the generic-CPU
kernels cost.

    python bench/bench_first_run.py [--scenario models/excavator/dig.scenario.toml] [--modes mujoco pbd]
                                    [--pairs 5] [--no-cpu-cost] [--markdown] [--keep DIR]

Everything runs in a fresh clone of this repository's ``HEAD`` in a temporary folder (the committed code: edits
not committed are not measured), with its own virtual environment, as a newcomer gets it:

1. ``make .venv/.installed`` in the clone: pip installs the package (pip's own download cache applies), then
   ``hydroplant compile`` builds the kernel cache (``hydraulics/kernel_cache.py``: a folder inside the venv named
   by the kernel sources' content, the kernels compiled for a generic CPU);
2. *after*: the first ``hydroplant run SCENARIO --mode MODE`` of each mode in the clone, on that cache;
3. *before*: the same command with ``NUMBA_CACHE_DIR`` an empty folder (what the first run costs without the
   install-time build: it compiles the kernels its mode calls, announced on stderr), then once more on the cache it
   filled (a later run);
4. unless ``--no-cpu-cost``: the run-time cost of the generic-CPU kernels against kernels compiled for this CPU
   (``NUMBA_CPU_NAME``/``NUMBA_CPU_FEATURES`` set to llvmlite's host CPU name and features, in their own cache
   folder, compiled by a first run): ``--pairs`` pairs of runs per mode in fresh processes, the order alternating
   within pairs; each pair's ratio generic/host of the run's reported wall time (its timed loop, compilation and
   loading excluded) and of the process CPU time; the median and the range of the ratios.

Times are whole-process figures of each command: wall time (``time.perf_counter`` around it) and CPU time
(user + system of the command and its children, ``resource.getrusage``), as ``/usr/bin/time`` reports them.  On a
shared machine the wall time stretches with the load; the CPU time much less.  The clone is removed at the end
(``--keep DIR`` clones into DIR instead and keeps it).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OWN = ("NUMBA_CACHE_DIR", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES", "PYTHONPATH", "VIRTUAL_ENV")


def clean_env(**extra) -> dict:
    """This process's environment without the variables that choose the kernel cache or the Python path, plus
    ``extra``."""
    env = {k: v for k, v in os.environ.items() if k not in OWN}
    env.update(extra)
    return env


def timed(command: list, cwd: Path, env: dict) -> dict:
    """Run ``command``; its process wall and CPU time [s], stdout and stderr.  Exits the benchmark if it fails."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode:
        raise SystemExit(f"{' '.join(map(str, command))} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return {"wall": wall, "cpu": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
            "stdout": done.stdout, "stderr": done.stderr}


def first_run(clone: Path, scenario: str, mode: str, env: dict) -> dict:
    """``hydroplant run SCENARIO --mode MODE --json`` in the clone: process times, the run's reported wall time and
    real-time factor, and the kernels it compiled (from its stderr)."""
    with tempfile.TemporaryDirectory(prefix="hydroplant-bench-log-") as tmp:
        out = timed([str(clone / ".venv/bin/hydroplant"), "run", scenario, "--mode", mode, "--json",
                     "--no-progress", "--out", str(Path(tmp) / "run.mcap")], clone, env)
    document = json.loads(out["stdout"])
    compiled = re.search(r"hydroplant: (\d+) functions compiled in", out["stderr"])
    result = dict(out, status=document["status"], reported=document["wall_time_s"], rtf=document["real_time_factor"],
                  compiled=int(compiled.group(1)) if compiled else 0,
                  announced="hydroplant: compiling kernels" in out["stderr"])
    print(f"  {mode}: process wall {result['wall']:.1f} s, CPU {result['cpu']:.1f} s, {result['compiled']} compiled, "
          f"reported {result['reported']:.2f} s ({env.get('NUMBA_CACHE_DIR', 'install cache')}, "
          f"{env.get('NUMBA_CPU_NAME', 'generic')})", file=sys.stderr, flush=True)
    return result


def host_cpu() -> dict:
    """``NUMBA_CPU_NAME``/``NUMBA_CPU_FEATURES`` of this machine's own CPU (what numba compiles for by default)."""
    import llvmlite.binding as llvm

    return {"NUMBA_CPU_NAME": llvm.get_host_cpu_name(), "NUMBA_CPU_FEATURES": llvm.get_host_cpu_features().flatten()}


def cpu_cost(checkout: Path, scenario: str, modes, count: int, host_cache: Path) -> dict:
    """{mode: {"reported": ratios, "cpu": ratios}}: ``count`` pairs of runs in ``checkout`` (its ``.venv``), the
    install's generic-CPU kernels against kernels compiled for this CPU into ``host_cache`` (compiled by a first run
    of each mode if not there yet), the order alternating within pairs."""
    host = host_cpu()
    host_cache.mkdir(parents=True, exist_ok=True)
    generic_env, host_env = clean_env(), clean_env(NUMBA_CACHE_DIR=str(host_cache), **host)
    out = {}
    for mode in modes:
        first_run(checkout, scenario, mode, host_env)  # compiles the host-CPU kernels (or loads them)
        first_run(checkout, scenario, mode, generic_env)  # the generic ones, from the install's cache
        ratios = {"reported": [], "cpu": []}
        for i in range(count):
            order = (("generic", generic_env), ("host", host_env))
            got = {name: first_run(checkout, scenario, mode, env) for name, env in (order if i % 2 == 0 else order[::-1])}
            for key in ratios:
                ratios[key].append(got["generic"][key] / got["host"][key])
        out[mode] = ratios
        print(f"  {mode}: CPU-target pairs done: " + ", ".join(f"{k} {spread(v)}" for k, v in ratios.items()),
              file=sys.stderr, flush=True)
    return out


def spread(values) -> str:
    values = sorted(values)
    return f"{statistics.median(values):.3f} ({values[0]:.3f}–{values[-1]:.3f})"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="models/excavator/dig.scenario.toml",
                        help="scenario, relative to the repository")
    parser.add_argument("--modes", nargs="+", default=["mujoco", "pbd"])
    parser.add_argument("--pairs", type=int, default=5, help="paired runs per mode for the CPU-target cost")
    parser.add_argument("--no-cpu-cost", action="store_true", help="skip the generic-against-host CPU pairs")
    parser.add_argument("--markdown", action="store_true", help="Markdown tables (else plain text)")
    parser.add_argument("--keep", type=Path, metavar="DIR", help="clone into DIR (which must not exist) and keep it")
    parser.add_argument("--cpu-cost-only", type=Path, metavar="HOST_CACHE",
                        help="only the CPU-target pairs, in this checkout (its .venv and its built kernel cache), with "
                             "the host-CPU kernels in HOST_CACHE (kept, reused when there)")
    args = parser.parse_args(argv)
    if args.cpu_cost_only is not None:
        pairs = cpu_cost(ROOT, args.scenario, args.modes, args.pairs, args.cpu_cost_only)
        print_pairs(pairs, args)
        return 0

    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    work = Path(tempfile.mkdtemp(prefix="hydroplant-first-run-")) if args.keep is None else args.keep
    clone = work / "hydroplant" if args.keep is None else work
    rows, pairs = [], {}
    load = [os.getloadavg()[0]]
    try:
        subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
        install = timed(["make", ".venv/.installed"], clone, clean_env())
        ready = re.search(r"kernels ready: .*\(wall ([\d.]+) s", install["stdout"])
        rows.append(("install", "`make .venv/.installed` (pip, then `hydroplant compile`)", install,
                     f"compile {ready.group(1)} s wall" if ready else ""))
        print(f"  install: wall {install['wall']:.1f} s, CPU {install['cpu']:.1f} s, {ready.group(0) if ready else ''}",
              file=sys.stderr, flush=True)
        for mode in args.modes:  # after: the install's cache
            rows.append((mode, "first run after the install", first_run(clone, args.scenario, mode, clean_env()), ""))
        for mode in args.modes:  # before: an empty cache
            empty = work / f"empty-cache-{mode}"
            empty.mkdir()
            env = clean_env(NUMBA_CACHE_DIR=str(empty))
            rows.append((mode, "first run, empty cache", first_run(clone, args.scenario, mode, env), ""))
            rows.append((mode, "later run on that cache", first_run(clone, args.scenario, mode, env), ""))
            print(f"  {mode}: done", file=sys.stderr, flush=True)
        if not args.no_cpu_cost:
            pairs = cpu_cost(clone, args.scenario, args.modes, args.pairs, work / "host-cache")
        load.append(os.getloadavg()[0])
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)

    scenario = args.scenario
    print(f"{scenario}, fresh clone of commit {head} with a fresh venv, {os.cpu_count()} cores (load average "
          f"{load[0]:.1f} at the start, {load[-1]:.1f} at the end); whole-process times")
    print()
    head_row = ("mode", "command", "process wall [s]", "process CPU [s]", "functions compiled",
                "reported wall time [s]", "real-time factor", "note")
    if args.markdown:
        print("| " + " | ".join(head_row) + " |")
        print("|" + "|".join(["---"] * 2 + ["---:"] * (len(head_row) - 3) + ["---"]) + "|")
    else:
        print("  ".join(f"{h:>14}" for h in head_row))
    for mode, label, r, note in rows:
        run = "reported" in r
        cells = (mode, label, f"{r['wall']:.1f}", f"{r['cpu']:.1f}", str(r["compiled"]) if run else "",
                 f"{r['reported']:.2f}" if run else "", f"{r['rtf']:.2f}" if run else "",
                 note or ("compilation announced" if run and r["announced"] else ""))
        print(("| " + " | ".join(cells) + " |") if args.markdown else "  ".join(f"{c:>14}" for c in cells))
    print_pairs(pairs, args)
    return 0


def print_pairs(pairs: dict, args) -> None:
    """The CPU-target table."""
    if pairs:
        print()
        print(f"Kernels compiled for a generic CPU against kernels compiled for this CPU ({host_cpu()['NUMBA_CPU_NAME']}), "
              f"{args.pairs} pairs per mode, ratio generic/host, median (range):")
        print()
        if args.markdown:
            print("| mode | reported wall time (timed loop) | process CPU time |")
            print("|---|---:|---:|")
        for mode, ratios in pairs.items():
            cells = (mode, spread(ratios["reported"]), spread(ratios["cpu"]))
            print(("| " + " | ".join(cells) + " |") if args.markdown else "  ".join(f"{c:>22}" for c in cells))


if __name__ == "__main__":
    raise SystemExit(main())
