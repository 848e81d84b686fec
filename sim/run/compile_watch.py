"""The first run's kernel compilation: announced on stderr, shown while it lasts, kept out of the run's timing.

The compiled kernels (numba, ``cache=True``) are compiled ahead of any run by ``hydroplant compile`` (``make`` runs
it at install) into the content-keyed cache folder of :mod:`hydraulics.kernel_cache`, and a run only loads them.
When that cache is missing or does not fit (other sources, another toolchain, or kernel files touched since it
was built), numba compiles the kernels at their first call: minutes of CPU before the run's first step.  :class:`CompileWatch` listens to numba's public
event API (``numba.core.event``, event kind ``"numba:compile"``, which numba broadcasts only when it compiles a
function, never when it loads one from the disk cache) and

* prints one line on stderr before the first compilation::

      hydroplant: compiling kernels for excavator/dig (pbd), first run only; later runs load them from the cache
      hydroplant: no prebuilt kernel cache in FOLDER; `hydroplant compile` builds every mode's kernels ahead of a run

* while it compiles, on a terminal (``stream.isatty()``), rewrites a progress line every second: the kernels
  compiled so far, the one being compiled and the elapsed time; on a pipe or a file only the first line and a
  closing line (``hydroplant: kernels compiled in 212 s``) are written;
* counts the kernels compiled (:attr:`count`).

:func:`sim.run.runner.run` builds the plant and runs a short throwaway copy of the run (its first few log
intervals, into a temporary log) inside a watch before it starts the clock, so every kernel the run calls is
compiled (or loaded) before the timed loop: the run's wall time and real-time factor, and the costs ``compare``
and ``tradeoff`` take from them, exclude compilation (``RunResult.compile_time`` holds it).

Example
-------
>>> import io
>>> from sim.run.compile_watch import CompileWatch
>>> out = io.StringIO()
>>> with CompileWatch("boom/lift", "mujoco", stream=out) as watch:
...     pass  # build and warm the plant here
>>> watch.count, out.getvalue()
(0, '')
"""

from __future__ import annotations

import sys
import threading
import time

try:  # pragma: no branch
    from numba.core import config as _numba_config
    from numba.core import event as _event
except ImportError:  # pragma: no cover - numba missing: nothing is compiled
    _event = None

PROGRESS_INTERVAL = 1.0  # s between two progress lines on a terminal


def _name(event) -> str:
    """The compiled function's qualified name (``module.function``), from the event's dispatcher."""
    dispatcher = (event.data or {}).get("dispatcher")
    function = getattr(dispatcher, "py_func", None)
    if function is None:
        return "kernel"
    module = getattr(function, "__module__", "") or ""
    return f"{module.rsplit('.', 1)[-1]}.{function.__qualname__.replace('.<locals>', '')}"


class CompileWatch:
    """Context manager: announce and show numba compilations that happen inside it (see the module docstring).

    Parameters
    ----------
    scene : str
        What is compiled for, as the line names it (``excavator/dig``).
    mode : str
        The run's mode (``mujoco``, ``pbd``).
    stream : text stream
        Where the lines go (default ``sys.stderr``); progress lines only when ``stream.isatty()``.
    show : bool
        False: count and time the compilations silently.
    """

    def __init__(self, scene: str, mode: str, *, stream=None, show: bool = True):
        self.scene, self.mode, self.show = scene, mode, show
        self.stream = sys.stderr if stream is None else stream
        self.count = 0  # functions compiled (every dispatcher's compilation, callees included)
        self.current = ""  # the function whose compilation started last
        self.start = None  # perf_counter at the first compilation
        self.seconds = 0.0  # wall time inside compilations so far [s] (the outermost ones: callees are inside them)
        self._outer = 0.0  # perf_counter at the start of the current outermost compilation
        self._depth = 0
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._ticker = None
        self._width = 0

    # ------------------------------------------------------------ numba's compile events
    def on_start(self, event) -> None:
        with self._lock:
            self.count += 1
            self._depth += 1
            self.current = _name(event)
            if self._depth == 1:
                self._outer = time.perf_counter()
            if self.start is None:
                self.start = time.perf_counter()
                self._announce()

    def on_end(self, event) -> None:
        with self._lock:
            self._depth -= 1
            if self._depth == 0:
                self.seconds += time.perf_counter() - self._outer

    # ------------------------------------------------------------ lines
    @property
    def tty(self) -> bool:
        isatty = getattr(self.stream, "isatty", None)
        return bool(self.show and isatty is not None and isatty())

    def _announce(self) -> None:
        if not self.show:
            return
        from hydraulics import kernel_cache

        print(f"hydroplant: compiling kernels for {self.scene} ({self.mode}), first run only; "
              "later runs load them from the cache", file=self.stream, flush=True)
        print(f"hydroplant: {kernel_cache.describe(kernel_cache.CURRENT)}; `hydroplant compile` builds every mode's "
              "kernels ahead of a run", file=self.stream, flush=True)
        if self.tty:
            self._ticker = threading.Thread(target=self._tick, name="hydroplant-compile-progress", daemon=True)
            self._ticker.start()

    def _tick(self) -> None:
        while not self._done.wait(PROGRESS_INTERVAL):
            with self._lock:
                text = f"  compiling: {self.count} functions, {time.perf_counter() - self.start:.0f} s ({self.current})"
            self._width = max(self._width, len(text))
            print("\r" + text.ljust(self._width), end="", file=self.stream, flush=True)

    @property
    def elapsed(self) -> float:
        """Wall time since the first compilation [s] (0 when nothing was compiled)."""
        return 0.0 if self.start is None else time.perf_counter() - self.start

    # ------------------------------------------------------------ context
    def __enter__(self) -> "CompileWatch":
        if _event is not None and not _numba_config.DISABLE_JIT:
            self._listening = _event.install_listener("numba:compile", _Forward(self))
            self._listening.__enter__()
        else:
            self._listening = None
        return self

    def __exit__(self, *exc) -> None:
        if self._listening is not None:
            self._listening.__exit__(*exc)
        self._done.set()
        if self._ticker is not None:
            self._ticker.join()
            print("\r" + " " * self._width + "\r", end="", file=self.stream, flush=True)
        if self.show and self.start is not None and exc[0] is None:
            print(f"hydroplant: {self.count} functions compiled in {self.elapsed:.0f} s", file=self.stream, flush=True)


if _event is not None:
    class _Forward(_event.Listener):
        """numba's listener (an instance of its ``Listener``) passing the events on to a :class:`CompileWatch`."""

        def __init__(self, watch: CompileWatch):
            self.watch = watch

        def on_start(self, event):
            self.watch.on_start(event)

        def on_end(self, event):
            self.watch.on_end(event)
