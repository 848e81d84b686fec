"""Progress of long work on stderr: ``done/total`` and an estimate of the time left, redrawn in place on a terminal.

On a terminal (``stream.isatty()``) each update rewrites one line with ``\\r``: ``compare: 2/5 runs, 12 s,
ETA 18 s``.  Into a pipe or a file no ``\\r`` is written: a plain line at every tenth of the work and
at the end, so a log file of the output stays readable.  The estimate is the mean time per finished
item times the items left (items of unequal cost make it a rough guide).

Example::

    progress = Progress(len(points), "tradeoff", "settings")
    for done, point in enumerate(points, 1):
        ...
        progress(done, total)
"""

from __future__ import annotations

import sys
import time


def duration_text(seconds: float) -> str:
    """``42 s``, ``3 min 20 s``, ``1 h 05 min``."""
    seconds = max(0.0, seconds)
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"


class Progress:
    """``progress(done, total)`` callable (as :func:`sim.tools.sweep.run_sweep` takes it) printing on ``stream``."""

    def __init__(self, total: int, label: str, unit: str = "runs", stream=None, clock=time.perf_counter):
        self.total, self.label, self.unit = total, label, unit
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.clock = clock
        self.start = clock()
        self.first_done = None  # items already done at the first update (cached): not counted in the rate
        self.rate_start = self.start
        self.step = max(1, total // 10)

    def text(self, done: int, total: int, note: str = "") -> str:
        now = self.clock()
        if self.first_done is None:  # items reported at once (read from a cache) do not count in the rate
            quick = now - self.start < 0.5 and done < total
            self.first_done, self.rate_start = (done, now) if quick else (0, self.start)
        elapsed = now - self.start
        fresh = done - self.first_done
        eta = "" if done >= total or fresh <= 0 else f", ETA {duration_text((now - self.rate_start) / fresh * (total - done))}"
        return f"{self.label}: {done}/{total} {self.unit}, {duration_text(elapsed)}{eta}" + (f" ({note})" if note else "")

    def __call__(self, done: int, total: int | None = None, note: str = "") -> None:
        total = self.total if total is None else total
        line = self.text(done, total, note)
        if self.tty:
            print("\r\033[K" + line, end="\n" if done >= total else "", file=self.stream, flush=True)
        elif done >= total or done % self.step == 0 or note:
            print(line, file=self.stream, flush=True)
