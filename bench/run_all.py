"""Run the benchmarks and write their figures to ``docs/benchmarks.md`` (``make bench``).

Each benchmark runs in its own process with the arguments listed in :data:`BENCHES`; its
printed output is echoed and becomes the figures of its section in the page: lines of a
Markdown table (``|`` first) stay tables, everything else goes into a text block.  The page's
header names the machine, the library versions, the date and the commit measured.  A section
is delimited by ``<!-- bench: NAME -->`` and ``<!-- /bench -->`` and replaced as soon as its
benchmark has run; the sections of benchmarks not run (``--only``) stay as they are.

    .venv/bin/python bench/run_all.py                       # every benchmark (about an hour on 2 cores)
    .venv/bin/python bench/run_all.py --only bench_fast     # one section
    .venv/bin/python bench/run_all.py --list

Exit status 1 if a benchmark failed (its section then says so, with the end of its error output).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "benchmarks.md"


@dataclass(frozen=True)
class Bench:
    """One benchmark script of ``bench/`` and what its section of the page says about it."""

    name: str
    args: tuple
    title: str
    about: str


BENCHES = (
    Bench("bench_fast", ("--reps", "5", "--markdown"), "Coupled step against bare MuJoCo",
          "µs per step at 1 kHz over the first 6 s of each scene's scenario, its ratio to a bare `mj_step` loop on "
          "the same MJCF with the actuators at constant controls, and the real-time factor; PBD cells are µs per "
          "millisecond of simulated time. Blocks of 2000 / 4000 steps (the runner's 2 s block and twice it) are the "
          "block-stepping `MujocoPlantFast`; the Python-orchestrated plant is the per-step `MujocoPlant`. Last "
          "column: the process's peak RSS. "
          "Target T1: MuJoCo mode within 1.3× bare `mj_step` on the excavator (see the floor below)."),
    Bench("bench_bare_replay", ("--reps", "7", "--markdown"), "Coupled step against bare-replay",
          "The excavator dig (20 s at 1 kHz) per coupling against bare-replay: plain `mj_step` stepping the same "
          "trajectory with the run's own effort laws replayed from a table (its contacts and solver work included; "
          "the replayed `qpos` equals the coupled run's). 7 rounds, the two halves of each pair back to back; the "
          "figure is the median of the paired ratios. Target: the default coupling within 1.6× bare-replay."),
    Bench("bench_floor", (), "The floor of an implicit step",
          "The least any implicit coupling does per step (one network evaluation, one factorisation of the Newton "
          "matrix with its solve), timed in a compiled loop at the scenario's network states, against bare `mj_step` "
          "(see [numerics.md](numerics.md#the-cost-floor-of-an-implicit-step))."),
    Bench("bench_pbd", ("--scenes", "excavator", "--pair-reps", "7"), "PBD mode at matched accuracy",
          "PBD mode across frames and substeps beside MuJoCo mode on the excavator dig; for each MuJoCo-mode row the "
          "fastest PBD setting at least as accurate (whole run; before contact against a converged reference), "
          "timed again in 7 alternating pairs; the paired median ratio is the figure. Target T2: PBD at matched "
          "accuracy at least as fast as MuJoCo mode. After the bucket meets the soil the dig is chaotic: a "
          "whole-run error moves with perturbations far below the step (frame lengths changed by at most 1e-4 of themselves), "
          "so a pick between neighbouring settings lies within that spread; the pre-contact matching (t < 1.5 s) and "
          "the filtered pressures by phase are the stable comparisons."),
    Bench("bench_logging", ("--seconds", "20", "--reps", "11"), "Logging and start-up",
          "The 20 s excavator dig at 1 kHz in MuJoCo mode (implicit and Rosenbrock coupling) and 2 s of it in PBD "
          "mode, 11 interleaved runs per configuration; each logged run against the no-log run just before it "
          "(paired median and quartiles of the wall time; the process's CPU time, all threads, in brackets). The "
          "log's writer thread takes each batch's fields, encoding, compression and writing, so on a second core they "
          "overlap the stepping. Targets T3: logging ≤ 5 % at the default 100 Hz, ≤ 25 % logging every step (MuJoCo "
          "mode); T4: `hydroplant run` of one step in a fresh process < 2 s."),
    Bench("bench_monitor", (), "The plausibility monitor's cost",
          "The excavator dig at 1 kHz with the monitor on and off in alternating pairs, in the fast MuJoCo plant and "
          "the PBD block path: the paired median and spread, and the time inside its checks per step. Target: "
          "≤ 2 % of the step."),
    Bench("bench_play", ("--reps", "3"), "Paced frames: the physics share of a frame",
          "`hydroplant play` of the excavator dig at 60 Hz frames, unpaced so that every frame's work is measured, "
          "per mode and coupling: physics time per frame (the frame's steps with the log's in-loop sampling) in wall "
          "and in CPU time, and the CPU share of the 16.67 ms frame, median and p99 over the 1200 frames (median of "
          "3 interleaved reps); the excavators one core steps in real time, 16.67 ms / CPU p99 (extrapolated, logs "
          "included), and measured: the most plants stepped one after the other in every frame (no logs) whose summed "
          "CPU time per frame keeps its p99 within the frame (see [play.md](play.md)). On a "
          "shared machine the wall-time p99 is the scheduler's time slice: the CPU time is the physics."),
    Bench("bench_control", ("--reps", "15"), "Controllers in compiled blocks",
          "Closed loops against the same machine open loop: the outside arm whose valve command is proportional to "
          "the stroke error every step (scenario `tests/scenes/outside_arm_servo.scenario.toml`) and the excavator dig "
          "with three PI stroke controllers, each against its own commands replayed as schedules (the same physics), "
          "in the runner's blocks over 2 s, 15 alternating pairs of CPU time: µs per step and the paired median ratio; and the controllers' update alone in a compiled loop. Targets: "
          "the arm within 10 % of open loop, the excavator's controllers at most 5 % of the step. Last table: a "
          "Python `controller(t, sensors)` against the compiled PID (see [controllers.md](controllers.md))."),
    Bench("bench_startup", (), "Start-up in fresh processes",
          "Import, scene load with the plant (cached kernels) and first step, in fresh interpreters."),
    Bench("bench_first_run", ("--markdown",), "The first run on a fresh clone",
          "A fresh clone of the commit in a temporary folder with a fresh venv: `make .venv/.installed` (pip, then "
          "`hydroplant compile` builds the content-keyed kernel cache, compiled for a generic CPU), then the first "
          "`hydroplant run` of the excavator dig (20 s) in each mode on it (after); the same first run with an "
          "empty kernel cache (before: it compiles the kernels its mode calls, announced on stderr, before its "
          "clock starts) and a later run on the cache that filled. Whole-process wall and CPU times (children "
          "included); the reported wall time and real-time factor are the run's own timed loop. Last table: the "
          "generic-CPU kernels against kernels compiled for this machine's CPU, paired runs in fresh processes. "
          "Target: each first run after the install within 10 s of wall time on 2 cores."),
    Bench("bench_install", ("--markdown",), "Installed size",
          "The default install and each extra in fresh venvs (site-packages beyond an empty venv; distributions "
          "installed, hydroplant included), against an install with the tools' libraries required."),
    Bench("bench_memory", (), "Memory of long runs",
          "The excavator dig at 1 kHz with default logging for 10 s and 600 s in fresh processes: peak RSS, RSS "
          "over the run, log size. Target T5: memory flat over a 10-minute run."),
    Bench("bench_network", (), "The network alone",
          "One 1 ms step of the excavator circuit called from Python, per stepper (no MuJoCo)."),
    Bench("bench_scaling", ("--reps", "5", "--markdown"), "Scaling in machine size",
          "N independent booms (the shipped boom's mechanics, valve, hoses and cylinder, side by side), N = 1 … 32, "
          "fed by one pump for all (the supply gallery joins every valve: the Newton matrix is an arrowhead) or by a "
          "pump each (N decoupled blocks), in MuJoCo mode (implicit coupling) and PBD mode (1 ms frames × 1 substep), "
          "0.3 s from rest with every valve opening, beside bare `mj_step` with the first step's effort law held "
          "(MuJoCo's own share); 5 rounds, every size once per round. µs per step (median), per "
          "boom in brackets, and the exponent of the cost in N between sizes, median [quartiles] over the rounds' "
          "pairs: 1 is a cost linear in the number of actuators; below 1 at small N, the per-step overheads. Target: at most "
          "1.1 from N = 4 to 32 (see [numerics.md](numerics.md#cost-in-machine-size)). Small N are at the noise floor "
          "of a shared machine: read the exponents from N = 4."),
    Bench("bench_mujoco", (), "MuJoCo mode per step",
          "µs per coupled step of the per-step plant against bare `mj_step`, per scene and coupling."),
    Bench("bench_fidelity", (), "Fidelity levels",
          "The excavator dig (20 s) at each fidelity level against the `lines` level at 1 kHz: cost and max errors "
          "(see [fidelity.md](fidelity.md))."),
    Bench("bench_tradeoff", ("--docs", "--full-dig", "--full"), "Accuracy against cost",
          "The seed cylinder (0.1 s) and the excavator dig (the whole 20 s against a reference on 0.1 s averages; "
          "the full trade-off sweep on its first 1.75 s): converged reference, every mode against it, the trade-off sweep "
          "(see [validation.md](validation.md)). Rewrites the figures, tables and reports of "
          "[figures/](figures/)."),
    Bench("bench_stability", (), "Stability maps",
          "Rewrites the maps, CSVs and summaries of [stability/](stability/README.md)."),
)
"""Every benchmark, in the order of the page."""

HEADER = """# Benchmarks

Written by `make bench` (`bench/run_all.py`) from the benchmarks' printed figures; regenerate one section
with `.venv/bin/python bench/run_all.py --only NAME`. Speed is measured as ratios within one run: shared
machines move by ±15–20 % from one run to the next, so read ±10 % into any one figure. No figure includes
numba's compilation of the kernels: a run compiles (or loads) them before its clock starts
(`RunResult.compile_time`) and the benchmarks run on a filled cache; the cold first run is measured on its own
below. How the figures are produced is in each script's docstring; what they mean in
[numerics.md](numerics.md), [pbd.md](pbd.md) and [validation.md](validation.md).
"""

_SECTION = re.compile(r"<!-- bench: (?P<name>\S+) -->\n.*?<!-- /bench -->\n", re.S)


def machine() -> str:
    """One line naming the CPU, the core count and the versions measured with."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    versions = [f"CPython {platform.python_version()}"]
    for module in ("mujoco", "numba", "numpy"):
        try:
            versions.append(f"{module} {__import__(module).__version__}")
        except ImportError:
            pass
    return f"{cpu}, {os.cpu_count()} cores, {', '.join(versions)}"


def commit() -> str:
    """The checkout's commit (with ``+`` if files differ from it), or ``unknown``."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+" if dirty else "")


def figures(output: str) -> str:
    """A benchmark's printed output as Markdown: its table lines as tables, the rest as text blocks."""
    blocks, kind, lines = [], None, []
    for line in output.rstrip().splitlines():
        this = "table" if line.lstrip().startswith("|") else "text"
        if this != kind and lines:
            blocks.append((kind, lines))
            lines = []
        kind = this
        lines.append(line.strip() if this == "table" else line)
    if lines:
        blocks.append((kind, lines))
    parts = []
    for kind, lines in blocks:
        if kind == "text":
            while lines and not lines[-1].strip():
                lines.pop()
            while lines and not lines[0].strip():
                lines.pop(0)
            if lines:
                parts.append("```text\n" + "\n".join(lines) + "\n```")
        else:
            parts.append("\n".join(lines))
    return "\n\n".join(parts)


def section(bench: Bench, body: str, stamp: str) -> str:
    """The delimited section of one benchmark."""
    command = " ".join(["python", f"bench/{bench.name}.py", *bench.args])
    return (f"<!-- bench: {bench.name} -->\n## {bench.title}\n\n{bench.about}\n\n`{command}`, {stamp}:\n\n"
            f"{body}\n<!-- /bench -->\n")


def run_bench(bench: Bench) -> tuple[bool, str]:
    """Run one benchmark, echoing its output; (succeeded, Markdown of its figures)."""
    print(f"\n=== {bench.name} {' '.join(bench.args)}", flush=True)
    process = subprocess.Popen([sys.executable, str(ROOT / "bench" / f"{bench.name}.py"), *bench.args], cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    output = []
    for line in process.stdout:
        print(line, end="", flush=True)
        output.append(line)
    error = process.stderr.read()
    status = process.wait()
    if status:
        print(error, file=sys.stderr)
        tail = "\n".join(error.rstrip().splitlines()[-15:])
        return False, f"**Failed** with exit status {status}:\n\n```text\n{tail}\n```"
    return True, figures("".join(output))


def page(sections: dict[str, str]) -> str:
    """The whole page: header, then the sections in the order of :data:`BENCHES`."""
    body = "".join(sections[b.name] + "\n" for b in BENCHES if b.name in sections)
    return f"{HEADER}\n{body}".rstrip() + "\n"


def main(argv=None) -> int:
    names = [b.name for b in BENCHES]
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", choices=names, metavar="NAME", help="run these; keep the page's other sections")
    parser.add_argument("--out", type=Path, default=PAGE, help="the page to write (default docs/benchmarks.md)")
    parser.add_argument("--list", action="store_true", help="list the benchmarks and their arguments")
    args = parser.parse_args(argv)
    if args.list:
        for b in BENCHES:
            print(f"{b.name:16} {' '.join(b.args)}")
        return 0
    chosen = [b for b in BENCHES if args.only is None or b.name in args.only]
    sections = {}
    if args.out.is_file():
        sections = {m["name"]: m.group(0) for m in _SECTION.finditer(args.out.read_text(encoding="utf-8"))}
    where = f"commit {commit()}, {machine()}"
    failed = []
    for bench in chosen:
        ok, body = run_bench(bench)
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        sections[bench.name] = section(bench, body, f"{stamp}, {where}")
        if not ok:
            failed.append(bench.name)
        args.out.write_text(page(sections), encoding="utf-8")  # after each benchmark, so a later failure keeps it
    print(f"\nwrote {args.out}" + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
