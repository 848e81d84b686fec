"""A long run's memory stays flat: peak RSS after 30 s of simulation is that after 5 s (the log is on disk)."""

import subprocess
import sys

from conftest import MODELS, ROOT

PROBE = """
import resource, sys
from sim.run.runner import run
result = run(sys.argv[1], out=sys.argv[2], overrides={"duration": float(sys.argv[3]), "dt": 2e-3})
assert result.status == "complete", result.message
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def peak_rss_kib(duration, tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", PROBE, str(MODELS / "boom" / "lift.scenario.toml"), str(tmp_path / f"run{duration}.mcap"), str(duration)],
        cwd=ROOT, capture_output=True, text=True, check=True, timeout=300,
    )
    return int(out.stdout.strip().splitlines()[-1])


def test_peak_memory_does_not_grow_with_run_length(tmp_path):
    short = peak_rss_kib(5.0, tmp_path)
    long = peak_rss_kib(30.0, tmp_path)
    print(f"\npeak RSS: 5 s run {short / 1024:.1f} MiB, 30 s run {long / 1024:.1f} MiB")
    assert long - short < 16 * 1024  # KiB: six times the run, less than 16 MiB more (buffers, not history)
