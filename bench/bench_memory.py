"""Memory of long runs: a 10-minute excavator run at 1 kHz stays flat.

Runs the excavator dig scenario at 1 kHz with default logging (100 Hz) in fresh
interpreters for ``--durations`` simulated seconds (default 10 s and 600 s; past the
scenario's 20 s cycle the inputs hold their last values).  Each process samples its
resident set size (``/proc/self/statm``) every ``--interval`` seconds of wall time from a
background thread and reports it with the peak RSS (``ru_maxrss``) and the log's size.
Flat means the RSS of the long run, after start-up, stays within a few MiB of the short
run's peak while the log on disk grows with the run.

Run: ``.venv/bin/python bench/bench_memory.py [--durations 10 600] [--interval 0.25]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DIG = ROOT / "models" / "excavator" / "dig.scenario.toml"

PROBE = r"""
import json, os, resource, sys, threading, time
from sim.run.runner import run

page = os.sysconf("SC_PAGE_SIZE")
samples, stop = [], threading.Event()

def rss_mib():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * page / 2**20

def sample(interval):
    while not stop.wait(interval):
        samples.append((time.perf_counter(), rss_mib()))

start = time.perf_counter()
sampler = threading.Thread(target=sample, args=(float(sys.argv[4]),), daemon=True)
sampler.start()
result = run(sys.argv[1], out=sys.argv[2], overrides={"duration": float(sys.argv[3]), "dt": 1e-3})
stop.set()
sampler.join()
end = time.perf_counter()
print(json.dumps({"status": result.status, "wall": end - start, "rtf": result.simulated_time / result.wall_time,
                  "rss": [(t - start, r) for t, r in samples], "peak": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "log_mib": os.path.getsize(result.log_path) / 2**20}))
"""


def measure(duration: float, out: Path, interval: float) -> dict:
    """Peak and sampled RSS [MiB] of one fresh process running ``duration`` s of the dig at 1 kHz."""
    done = subprocess.run([sys.executable, "-c", PROBE, str(DIG), str(out), str(duration), str(interval)], cwd=ROOT,
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(done.stderr)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--durations", nargs="+", type=float, default=[10.0, 600.0], help="simulated seconds per run [s]")
    parser.add_argument("--interval", type=float, default=0.25, help="RSS sampling interval [s of wall time]")
    args = parser.parse_args()
    print("excavator dig at 1 kHz, default logging (100 Hz), fresh process per run:")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for duration in args.durations:
            r = results[duration] = measure(duration, Path(tmp) / f"run{duration:g}.mcap", args.interval)
            rss = [m for _, m in r["rss"]]
            late = [m for t, m in r["rss"] if t >= 0.5 * r["wall"]]  # the second half of the run's wall time
            print(f"  {duration:6g} s simulated: {r['status']}, wall {r['wall']:6.2f} s (RTF {r['rtf']:5.1f}), peak RSS "
                  f"{r['peak']:6.1f} MiB, sampled RSS {min(rss, default=float('nan')):6.1f}–{max(rss, default=float('nan')):6.1f} MiB "
                  f"({len(rss)} samples; second half {min(late, default=float('nan')):.1f}–{max(late, default=float('nan')):.1f}), "
                  f"log {r['log_mib']:6.1f} MiB")
    if len(results) > 1:
        short, long = results[min(results)], results[max(results)]
        print(f"  peak RSS {max(results):g} s − {min(results):g} s: {long['peak'] - short['peak']:+.1f} MiB "
              f"(log {long['log_mib'] / short['log_mib']:.0f}× larger)")


if __name__ == "__main__":
    main()
