"""Cost of the plausibility monitor (sim.run.monitor) on the excavator dig at 1 kHz.

Paired runs in one process, alternating monitor on / off (off: a monitor whose checks do nothing, so
the run does no monitoring work at all), on the fast MuJoCo plant (``MujocoPlantFast`` blocks) and on
the PBD block path (``PbdPlant.advance`` in compiled blocks), the default log (100 Hz).  Per pair the
relative cost (wall on / wall off − 1); printed: the median and the spread (min .. max) over the pairs,
and the median wall time per step of each.  On a shared machine the pairs' spread can exceed the
cost itself, so the time spent inside the monitor's checks is also measured directly (every check
method timed with ``perf_counter`` in a monitored run) and printed per step and as a share of the step.

Usage::

    python bench/bench_monitor.py [--pairs 5] [--duration 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import sim.run.runner as runner
from sim.io.examples import example_path
from sim.run.monitor import RunMonitor


class _NoMonitor(RunMonitor):
    """The monitor with every check switched off (the baseline of the pairs)."""

    def check_start(self, plant):
        return None

    def check_state(self, time, pressure, position):
        return None

    def extremes_within(self, plant):
        return True

    def check_batch(self, batch, dt, initial_total):
        return None

    def check_constraints(self, time):
        return None


class _TimedMonitor(RunMonitor):
    """The monitor with the wall time of every check summed in ``spent`` [s] (class attribute)."""

    spent = 0.0


def _timed(name):
    method = getattr(RunMonitor, name)

    def wrapper(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return method(self, *args, **kwargs)
        finally:
            _TimedMonitor.spent += time.perf_counter() - start

    return wrapper


for _name in ("check_start", "check_state", "extremes_within", "check_extremes", "check_batch", "check_constraints", "accept"):
    setattr(_TimedMonitor, _name, _timed(_name))


def _one(mode: str, duration: float, monitored, out: Path) -> float:
    runner.RunMonitor = {True: RunMonitor, False: _NoMonitor}.get(monitored, monitored)
    try:
        start = time.perf_counter()
        result = runner.run(example_path("excavator/dig"), out=out, overwrite=True,
                            overrides={"mode": mode, "duration": duration, "dt": 1e-3})
        wall = time.perf_counter() - start
    finally:
        runner.RunMonitor = RunMonitor
    assert result.status == "complete", result.message
    return wall / result.steps


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=5, help="on/off pairs per mode")
    parser.add_argument("--duration", type=float, default=5.0, help="simulated seconds per run")
    args = parser.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="bench_monitor-"))
    print(f"excavator/dig at 1 kHz, {args.duration:g} s simulated per run, {args.pairs} pairs (on/off alternating)")
    for mode, label in (("mujoco", "MuJoCo fast plant (blocks)"), ("pbd", "PBD block path")):
        _one(mode, min(args.duration, 0.5), True, folder / "warm.mcap")  # compile / load the kernels
        on, off, cost = [], [], []
        for k in range(args.pairs):
            order = (True, False) if k % 2 == 0 else (False, True)
            walls = {flag: _one(mode, args.duration, flag, folder / f"{mode}-{flag}.mcap") for flag in order}
            on.append(walls[True])
            off.append(walls[False])
            cost.append(walls[True] / walls[False] - 1.0)
        _TimedMonitor.spent = 0.0
        step = _one(mode, args.duration, _TimedMonitor, folder / f"{mode}-timed.mcap")
        steps = round(args.duration / 1e-3)
        inside = _TimedMonitor.spent / steps
        print(f"{label:28s} step on {statistics.median(on) * 1e6:7.2f} us, off {statistics.median(off) * 1e6:7.2f} us; "
              f"monitor cost median {statistics.median(cost):+.2%} (spread {min(cost):+.2%} .. {max(cost):+.2%}); "
              f"inside the checks {inside * 1e6:.3f} us per step = {inside / step:.3%} of the step ({step * 1e6:.2f} us)")


if __name__ == "__main__":
    main()
