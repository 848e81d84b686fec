"""``hydroplant play``: a scenario stepped paced to the wall clock, driven by an operator, recorded and resumable.

The paced loop is the runner's (:func:`sim.run.runner.run`: the same plant, checks, log and samples) with a frame
driver, :class:`FrameDriver`.  Per frame of period T = 1/``rate_hz`` (default 60 Hz):

1. read the command source (:class:`~sim.live.protocol.CommandSource`), map device axes to valves
   (:mod:`sim.live.mapping`), and hold the result over the frame (:mod:`sim.run.commands`);
2. step the physics through the frame (``loop.blocks(until)``: the runner's blocks, clipped at the frame's end;
   frame k ends at step ``first + round((k + 1)·T/dt)``, so frames of 16 and 17 steps at 1 kHz);
3. publish: the frame's timing on ``/hydroplant/frame``, the state to the frame sinks (a viewer, a live stream);
4. sleep to the frame's deadline, an absolute wall time ``t0 + (simulated time since start)/pace``
   (``time.perf_counter``; never ``sleep(period − elapsed)``, whose errors add up).

Measured per frame: ``physics`` (wall time of step 2, the log's in-loop sampling included), ``lateness`` (how late
the frame started against its scheduled start: sleep overshoot, or the backlog after an overrun), ``cycle`` (from
the frame's start to the later of its deadline and its end) and ``missed`` (the frame's work ended after its
deadline).  An overrun is never dropped: ``overrun = "catch-up"`` (default) keeps the deadlines, so the frames
after it run back to back until the loop is on time again; ``"slow"`` moves every later deadline by the overrun,
so the simulated clock falls behind the wall clock by the sum of the overruns (``slip_s`` in the result).  Unpaced
(``pace = 0``, for tests and replays) never sleeps; a frame then counts as missed when its physics took longer
than the frame period (it would have missed at real time).  The summary (median, p99, max, misses) is printed,
returned (:class:`FrameSummary`) and written to the log's ``hydroplant.result`` record.

Record, replay, resume
----------------------
Every ``play`` run writes the log ``run`` writes, plus

``/hydroplant/commands``   the commands of each frame (its first ``step``, one float64 per valve and pump), the
                           exact values every physics step of the frame used;
``/hydroplant/frame``      the frame timing (:mod:`sim.live.frame_topic`);
``/hydroplant/snapshots``  the plant's full state (:mod:`sim.run.snapshot`) at the first frame boundary at or after
                           every 1/``snapshot_hz`` of simulated time (default 1 Hz), and at the start.

:func:`replay` rebuilds the run from the log alone (its attached input files and run settings) with the recorded
commands as the inputs, and reproduces every logged sample bit for bit: unpaced in the runner's own blocks
(``hydroplant run --replay LOG``), or paced in frames (``hydroplant play --replay LOG``).  :func:`resume` restores
the last snapshot at or before a time T into a freshly built plant and continues: with the recorded commands
(``hydroplant run --resume LOG --at T``) every later sample equals the original's; with a live source
(``hydroplant play --resume LOG --at T``) the operator takes over from that moment.

Example
-------
::

    from sim.run.play import PlayOptions, ScheduleSource, play, replay
    from sim.io.scenario import load_scenario

    scenario = load_scenario("models/excavator/dig.scenario.toml")
    result = play(scenario, source=ScheduleSource(scenario.inputs), options=PlayOptions(pace=1.0))
    print(result.summary_text())                  # frame statistics and the run's summary
    again = replay(result.run.log_path)           # bit for bit the same samples, as fast as it goes
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import tempfile
import time
import tomllib
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hydraulics.components import COMPONENT_TYPES, CircuitError

from sim.commands import PLAY_INPUTS as INPUTS  # the parser's choices, declared with it
from sim.commands import PLAY_OVERRUNS as OVERRUNS
from sim.io.scenario import Scenario, ScenarioError, load_scenario
from sim.live.frame_topic import FRAME_FIELDS, FRAME_STATS, FRAME_TOPIC, frame_row
from sim.live.protocol import FrameStats
from sim.run import snapshot as snap
from sim.run.commands import COMMANDS_TOPIC, CommandTable, commands_schema, table_from_log

RATE_RANGE = (1.0, 1000.0)  # Hz, frame rate
PACE_RANGE = (0.0, 1000.0)  # simulated seconds per wall-clock second; 0 = as fast as possible
SNAPSHOT_RANGE = (0.0, 1000.0)  # Hz of simulated time; 0 = only the start
STATS_WINDOW = 120  # frames of the rolling figures shown live (Vortex, AGX report over the last 120 frames)
_PUMP_SPEED = {f.name: f.metadata for f in dataclasses.fields(COMPONENT_TYPES["pump_fixed"])}["speed"]


@dataclass(frozen=True)
class PlayOptions:
    """How ``play`` paces and records a run."""

    rate_hz: float = 60.0
    """Frame rate [Hz]: commands are read and the state published once per frame, in [1, 1000]."""
    pace: float = 1.0
    """Simulated seconds per wall-clock second: 1 real time, 0 as fast as possible (no sleep), in [0, 1000]."""
    overrun: str = "catch-up"
    """A frame that ends after its deadline: ``"catch-up"`` (later frames run back to back until on time) or
    ``"slow"`` (later deadlines move by the overrun: the simulated clock slows)."""
    snapshot_hz: float = 1.0
    """Full-state snapshots per simulated second [Hz], in [0, 1000] (0: only the one at the start)."""

    def __post_init__(self):
        for name, (low, high) in (("rate_hz", RATE_RANGE), ("pace", PACE_RANGE), ("snapshot_hz", SNAPSHOT_RANGE)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
                raise ScenarioError(f"play option '{name}': {value!r} is not a number in [{low:g}, {high:g}]")
        if self.overrun not in OVERRUNS:
            raise ScenarioError(f"play option 'overrun': {self.overrun!r} is not one of {list(OVERRUNS)}")


# ------------------------------------------------------------------------------------------------- command sources
class ScheduleSource:
    """A program source that plays a scenario's ``inputs`` (schedules, callables or constants) as commands: each poll
    returns every input's value at the polled time (held over the frame by the loop)."""

    def __init__(self, inputs: Mapping):
        self.inputs = dict(inputs)

    def poll(self, t: float) -> dict:
        return {name: float(s(t)) if callable(s) else float(s) for name, s in self.inputs.items()}

    def close(self) -> None:
        pass


class ProgramSource:
    """Commands from a program at a rate: ``program(t)`` (a callable of simulated time [s]) or ``next(program)`` (an
    iterator) gives ``{name: value}`` every 1/``rate_hz`` of simulated time (every poll when ``rate_hz`` is None);
    between calls the last values hold.  Names are axes of the scenario's mapping or the circuit's valves and pumps.
    The same interface a controller uses.
    """

    def __init__(self, program: Callable | Iterable, rate_hz: float | None = None):
        self.program = program
        self.period = None if rate_hz is None else 1.0 / float(rate_hz)
        self.calls = 0
        self.last: dict = {}

    def poll(self, t: float) -> dict:
        if self.period is None or t >= self.calls * self.period - 1e-12:
            if self.period is not None:
                self.calls = int(math.floor(t / self.period + 1e-9)) + 1
            values = self.program(t) if callable(self.program) else next(self.program, None)
            if values is not None:
                self.last = dict(values)
        return self.last

    def close(self) -> None:
        pass


class HoldSource:
    """No operator: the commands stay at the scenario's inputs at the start."""

    def poll(self, t: float) -> dict:
        return {}

    def close(self) -> None:
        pass


# ------------------------------------------------------------------------------------------------- frame figures
@dataclass
class FrameSummary:
    """Frame timing of a paced run (arrays per frame, milliseconds) and its clocks."""

    rate_hz: float
    pace: float
    overrun: str
    physics_ms: np.ndarray
    lateness_ms: np.ndarray
    cycle_ms: np.ndarray
    missed: np.ndarray
    simulated_s: float
    """Simulated time the loop advanced [s]."""
    wall_s: float
    """Wall time from the first frame's start to the end of the last frame's wait [s]."""
    slip_s: float = 0.0
    """Sum of the overruns the ``slow`` policy let the simulated clock fall behind by [s]."""
    cpu_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """CPU time of the process per frame's physics [ms] (``time.process_time``; below the wall time when the
    process was not running, e.g. preempted on a busy machine; above it when the log's thread compressed meanwhile)."""

    @property
    def frames(self) -> int:
        return len(self.physics_ms)

    @property
    def misses(self) -> int:
        return int(np.count_nonzero(self.missed))

    @staticmethod
    def _figures(values) -> tuple:
        if not len(values):
            return (math.nan, math.nan, math.nan)
        return (float(np.median(values)), float(np.percentile(values, 99)), float(np.max(values)))

    @property
    def physics(self) -> tuple:
        """(median, p99, max) of the physics time per frame [ms]."""
        return self._figures(self.physics_ms)

    @property
    def cpu(self) -> tuple:
        """(median, p99, max) of the process's CPU time per frame's physics [ms]."""
        return self._figures(self.cpu_ms)

    @property
    def lateness(self) -> tuple:
        """(median, p99, max) of the frames' start lateness [ms]."""
        return self._figures(self.lateness_ms)

    def text(self) -> str:
        period = 1e3 / self.rate_hz
        pm, p99, pmax = self.physics
        lm, l99, lmax = self.lateness
        pace = "unpaced" if self.pace == 0 else f"pace {self.pace:g}"
        return "\n".join([
            f"frames        {self.frames} at {self.rate_hz:g} Hz ({period:.2f} ms), {pace}, overrun policy {self.overrun}",
            f"physics [ms]  median {pm:.3f}  p99 {p99:.3f}  max {pmax:.3f}  "
            f"(share of the frame: median {100 * pm / period:.1f} %, p99 {100 * p99 / period:.1f} %)",
            f"physics CPU   median {self.cpu[0]:.3f}  p99 {self.cpu[1]:.3f}  max {self.cpu[2]:.3f} [ms] (process time)",
            f"lateness [ms] median {lm:.3f}  p99 {l99:.3f}  max {lmax:.3f}",
            f"missed        {self.misses} deadline{'s' if self.misses != 1 else ''}",
            f"clocks        simulated {self.simulated_s:.4f} s in {self.wall_s:.4f} s of wall time"
            + (f"; the simulated clock slipped {self.slip_s:.4f} s" if self.slip_s else ""),
        ])

    def info(self) -> dict:
        """Entries of the log's ``hydroplant.result`` record."""
        pm, p99, pmax = self.physics
        lm, l99, lmax = self.lateness
        return {"frames": self.frames, "frame_rate_hz": float(self.rate_hz), "physics_ms_median": pm,
                "physics_ms_p99": p99, "physics_ms_max": pmax, "physics_cpu_ms_median": self.cpu[0],
                "physics_cpu_ms_p99": self.cpu[1], "lateness_ms_median": lm, "lateness_ms_p99": l99,
                "lateness_ms_max": lmax, "missed_deadlines": self.misses, "overrun": self.overrun,
                "pace": float(self.pace), "simulated_s": float(self.simulated_s), "wall_s": float(self.wall_s),
                "slip_s": float(self.slip_s)}


@dataclass
class PlayResult:
    """A paced run: the run's :class:`~sim.run.runner.RunResult` and its :class:`FrameSummary`."""

    run: object
    frames: FrameSummary

    def summary_text(self) -> str:
        return self.frames.text() + "\n" + self.run.summary_text()


# ------------------------------------------------------------------------------------------------- the frame driver
class FrameDriver:
    """The ``driver`` of :func:`sim.run.runner.run` that steps in paced frames (see the module docstring).

    ``source``: the live :class:`~sim.live.protocol.CommandSource` (None with ``commands``); ``commands``: a recorded
    :class:`~sim.run.commands.CommandTable` to replay instead (its frames are the recorded ones); ``frames=False``
    (replay only) steps in the runner's own blocks, unpaced, writing no topic of its own; ``resume``: a
    :func:`sim.run.snapshot.capture` to start from; ``sinks``: :class:`~sim.live.protocol.FrameSink` objects shown
    every frame (a sink with ``attach(log)`` is attached to the log first); ``metadata``: extra ``hydroplant.run``
    entries.
    """

    def __init__(self, source=None, *, options: PlayOptions | None = None, commands: CommandTable | None = None,
                 frames: bool = True, resume: dict | None = None, sinks=(), metadata: Mapping | None = None):
        if (source is None) == (commands is None):
            raise ValueError("give either a command source or recorded commands")
        self.source, self.table, self.frames = source, commands, bool(frames) or commands is None
        self.options = options or PlayOptions()
        self.resume, self.sinks = resume, list(sinks)
        opts = self.options
        self.metadata = {"play_rate_hz": repr(float(opts.rate_hz)), "play_pace": repr(float(opts.pace)),
                         "play_overrun": opts.overrun, "play_snapshot_hz": repr(float(opts.snapshot_hz)),
                         "play_commands": "replayed" if commands is not None else "live"} if self.frames else {}
        self.metadata.update(metadata or {})
        self.summary: FrameSummary | None = None
        self.mapping = None
        self.warned: set = set()

    # -- runner hooks ---------------------------------------------------------------------------------------------
    def scene(self, scene):
        """Every valve and pump of the circuit becomes a held input of the command table (the scenario's own
        schedules give the start values and are otherwise not applied)."""
        net, scenario = scene.network, scene.scenario
        names = list(net.valve_names) + list(net.pump_names)
        self.names = names
        self.valves = len(net.valve_names)
        start = 0 if self.resume is None else int(self.resume["step_index"])
        if self.table is None:
            from sim.live.mapping import check_targets

            self.mapping = scenario.mapping
            if self.mapping is not None:
                check_targets(self.mapping, set(names), str(scenario.path))
            self.table = CommandTable(names, scenario.dt)
            t = start * scenario.dt
            row = np.zeros(len(names))
            for j, name in enumerate(names):
                s = scenario.inputs.get(name)
                if s is not None:
                    row[j] = float(s(t)) if callable(s) else float(s)
            self.row = row
            self.table.append(start, self.command_row(t))
        else:
            if list(self.table.names) != names:
                raise CircuitError(f"the recorded commands name {list(self.table.names)}, the circuit has {names}")
        self.metadata["command_inputs"] = json.dumps(names)
        # what a Scenario object given in code may have changed against its file (LoggedRun applies it again)
        self.metadata["play_settings"] = json.dumps({name: getattr(scenario, name) for name in SETTINGS})
        scene.scenario = dataclasses.replace(scenario, inputs=self.table.inputs())
        return scene

    def prepare(self, plant) -> None:
        if self.resume is not None:
            snap.restore(plant, self.resume)

    def start(self, log, loop) -> None:
        self.log = log
        if not self.frames:
            return
        schema, fields = commands_schema(self.names)
        self.commands = log.cdr_channel(COMMANDS_TOPIC, schema, fields=fields,
                                        metadata={"inputs": json.dumps(self.names), "units": "valve -, pump rev/s"})
        self.frame_channel = log.cdr_channel(FRAME_TOPIC, FRAME_STATS, fields=list(FRAME_FIELDS), metadata={"units": "ms"})
        self.snapshots = log.channel(snap.SNAPSHOT_TOPIC, "hydroplant.Snapshot",
                                     {"title": "hydroplant.Snapshot", "type": "object",
                                      "description": "Full plant state; float64 arrays as base64 of their raw bytes"})
        for sink in self.sinks:
            attach = getattr(sink, "attach", None)
            if callable(attach):
                attach(log)

    def result_info(self) -> dict:
        return {} if self.summary is None else self.summary.info()

    # -- commands -------------------------------------------------------------------------------------------------
    def command_row(self, t: float) -> np.ndarray:
        """The held row after polling the source at ``t``: mapped axes and direct names over the last row, clipped
        to each input's range (valves [−1, 1], pumps the pump speed range); other names are ignored."""
        values = self.source.poll(t) or {}
        names = self.names
        direct = set(names)
        if self.mapping is not None:
            values = self.mapping.apply(values, passthrough=direct)
        row = self.row
        for name, value in values.items():
            if name not in direct:
                self.warned.add(name)
                continue
            value = float(value)
            if not math.isfinite(value):
                continue
            j = names.index(name)
            low, high = (-1.0, 1.0) if j < self.valves else (float(_PUMP_SPEED["low"]), float(_PUMP_SPEED["high"]))
            row[j] = min(high, max(low, value))
        return row.copy()

    # -- the loop -------------------------------------------------------------------------------------------------
    def drive(self, loop) -> None:
        plant = loop.plant
        advance = loop.blocks if getattr(plant, "fast", False) else loop.per_step
        if not self.frames:
            advance()
            return
        try:
            self._frames(loop, advance)
        finally:
            for sink in self.sinks:
                sink.close()
            if self.source is not None:
                self.source.close()

    def _frames(self, loop, advance) -> None:
        plant, log, opts, table = loop.plant, self.log, self.options, self.table
        dt, end, first = plant.dt, loop.steps, plant.step_index
        live = self.source is not None
        steps_per_frame = 1.0 / (opts.rate_hz * dt)
        period = 1.0 / opts.rate_hz
        wall_per_sim = 1.0 / opts.pace if opts.pace > 0 else 0.0
        every = max(1, int(round(1.0 / (opts.snapshot_hz * dt)))) if opts.snapshot_hz > 0 else None
        self.write_snapshot(plant)
        next_snapshot = math.inf if every is None else (first // every + 1) * every
        self.warm_up(loop)
        physics, cpu, lateness, cycles, missed = [], [], [], [], []
        window = deque(maxlen=STATS_WINDOW)
        slip = 0.0
        shown = bool(self.sinks)
        drain_log = getattr(log, "drain", None)
        row_index = 0 if live else int(table.rows_at(first * dt))
        k = 0
        t0 = time.perf_counter()
        while plant.step_index < end and loop.status == "complete":
            start_step = plant.step_index
            start_wall = time.perf_counter()
            if live:
                stop_step = min(max(first + int(round((k + 1) * steps_per_frame)), start_step + 1), end)  # >= 1 step
                if k:
                    table.append(start_step, self.command_row(start_step * dt))
                row = table.values[-1]
            else:
                row_index = int(table.rows_at(start_step * dt))
                following = table.steps[row_index + 1] if row_index + 1 < table.count else end
                stop_step = min(int(following), end)
                row = table.values[row_index]
            scheduled = t0 + slip + (start_step - first) * dt * wall_per_sim
            late = max(0.0, start_wall - scheduled) if wall_per_sim else 0.0
            self.commands.append(start_step, (float(start_step), *row))
            tic, cpu_tic = time.perf_counter(), time.process_time()
            advance(stop_step)
            work = time.perf_counter() - tic
            cpu.append(time.process_time() - cpu_tic)
            if plant.step_index >= next_snapshot and loop.status == "complete":
                self.write_snapshot(plant)
                next_snapshot = (plant.step_index // every + 1) * every
            deadline = t0 + slip + (plant.step_index - first) * dt * wall_per_sim
            now = time.perf_counter()
            miss = now > deadline if wall_per_sim else work > period
            stats = FrameStats(k, plant.step_index * dt, work, (max(deadline, now) if wall_per_sim else now) - start_wall,
                               late, bool(miss))
            self.frame_channel.append(plant.step_index, frame_row(stats))
            if miss and not any(missed):
                self.overrun_event(loop, stats, now - deadline if wall_per_sim else work - period)
            physics.append(work)
            lateness.append(late)
            cycles.append(stats.cycle)
            missed.append(stats.missed)
            if shown:
                window.append((work, stats.missed))
                loop.drain()  # the frame's samples into the log (a live stream sends what the log has)
                if callable(drain_log):
                    drain_log()
                self.show(plant, stats, window)
            if wall_per_sim:
                now = time.perf_counter()
                if now < deadline:
                    time.sleep(deadline - now)
                elif opts.overrun == "slow":
                    slip += now - deadline
            k += 1
        wall = time.perf_counter() - t0
        ms = lambda a: 1e3 * np.asarray(a, float)  # noqa: E731
        self.summary = FrameSummary(opts.rate_hz, opts.pace, opts.overrun, ms(physics), ms(lateness), ms(cycles),
                                    np.asarray(missed, bool), (plant.step_index - first) * dt, wall, slip, ms(cpu))
        if self.warned:
            from sim.io.mcap_log import LogLevel

            loop.event(plant.step_index, LogLevel.WARNING, "commands ignored (not an axis of the mapping, nor "
                                f"a valve or pump of the circuit): {sorted(self.warned)}")

    def overrun_event(self, loop, stats: FrameStats, over: float) -> None:
        """A warning event at the run's first missed deadline, naming the overrun policy (the others are counted on
        ``/hydroplant/frame`` and in the summary)."""
        from sim.io.mcap_log import LogLevel

        then = {"catch-up": "the frames after it run back to back until the loop is on time",
                "slow": "the simulated clock falls behind by the overrun"}[self.options.overrun]
        loop.event(loop.plant.step_index, LogLevel.WARNING,
                            f"frame {stats.index} (t = {stats.sim_time:.4f} s) missed its deadline by {1e3 * over:.2f} ms "
                            f"(physics {1e3 * stats.physics:.2f} ms); overrun policy {self.options.overrun}: {then}")

    def warm_up(self, loop) -> None:
        """One-time costs before the clock starts, so that the first frames keep their deadlines: the log's encoder
        (the first sample and snapshot are written out now) and, for a block-stepping plant, the compiled step's
        first call (one step taken and undone: :func:`sim.run.snapshot.restore` gives back the state bit for bit)."""
        loop.drain()
        self.log.flush()
        plant = loop.plant
        if getattr(plant, "fast", False) and plant.step_index < loop.steps:
            state = snap.capture(plant)
            plant.advance(1)
            snap.restore(plant, state)

    def write_snapshot(self, plant) -> None:
        self.snapshots.write(plant.step_index, snap.encode(snap.capture(plant)))

    def show(self, plant, stats: FrameStats, window) -> None:
        """The frame to the sinks: MuJoCo ``qpos``, named values in display units, the timing."""
        net, state = plant.network, plant.net_state
        values = {"frame/physics_ms": 1e3 * stats.physics, "frame/lateness_ms": 1e3 * stats.lateness,
                  "frame/missed": float(stats.missed),
                  f"frame/physics_ms_max_{STATS_WINDOW}": 1e3 * max(w for w, _ in window),
                  f"frame/missed_{STATS_WINDOW}": float(sum(m for _, m in window))}
        p = state.node_pressure
        for a, cap, rod in zip(net.cylinder_actuator, net.cylinder_cap_node, net.cylinder_rod_node):
            name = net.actuator_names[a]
            values[f"{name}/stroke_m"] = float(state.actuator_position[a])
            values[f"{name}/p_cap_bar"] = float(p[cap]) / 1e5
            values[f"{name}/p_rod_bar"] = float(p[rod]) / 1e5
        for j, name in enumerate(net.valve_names):
            values[f"{name}/command"] = float(plant.control.valve_command[j])
            values[f"{name}/spool"] = float(state.valve_spool[j])
        if hasattr(plant, "data"):
            qpos = plant.data.qpos.copy()
        else:
            qpos = plant.xmodel.qpos_qvel(plant.state)[0]
        for sink in self.sinks:
            sink.show(stats.sim_time, qpos, values, stats)


# ------------------------------------------------------------------------------------------------- entry points
def play(scenario, *, source=None, sinks=(), options: PlayOptions | None = None, out=None, overrides: dict | None = None,
         overwrite: bool = False, stop=None, resume: dict | None = None, commands: CommandTable | None = None,
         metadata: Mapping | None = None) -> PlayResult:
    """Run ``scenario`` (path or :class:`~sim.io.scenario.Scenario`) in paced frames; see the module docstring.

    ``source``: the command source (default: :class:`ScheduleSource` of the scenario's inputs, a scripted
    operator); ``commands``: a recorded table to replay instead; ``resume``: a snapshot to start from;
    ``out``, ``overrides``, ``overwrite``, ``stop``: as :func:`sim.run.runner.run`.
    """
    from sim.run.runner import run

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if source is None and commands is None:
        source = ScheduleSource(scenario.with_overrides(**(overrides or {})).inputs)
    extra = {"play_overrides": json.dumps({k: v for k, v in (overrides or {}).items() if v is not None}),
             **(metadata or {})}
    driver = FrameDriver(source, options=options, commands=commands, resume=resume, sinks=sinks, metadata=extra)
    result = run(scenario, out=out, overrides=overrides, overwrite=overwrite, stop=stop, driver=driver)
    return PlayResult(result, driver.summary)


SETTINGS = ("pbd_blend", "monitor", "fidelity", "actuator_fidelity", "log_rate_hz", "tf_rate_hz", "qpos", "qvel",
            "equilibrium", "start_contacts", "base_pressure", "pressures")
"""Scenario fields besides the run metadata's that a replay needs as they were (``play_settings`` in the log)."""
RUN_KEYS = {"mode": str, "coupling": str, "dt_s": float, "duration_s": float, "hydraulic_substeps": int,
            "pbd_substeps": int, "pbd_iterations": int}


class LoggedRun:
    """The inputs of a logged run, rebuilt from the log alone: its attached files written to a temporary folder
    (the same relative layout, the same scenario and scene names), the run settings from its metadata.  Use as a
    context manager; ``scenario`` and ``overrides`` are then what :func:`sim.run.runner.run` takes."""

    def __init__(self, log_path):
        from sim.io.mcap_log import read_log
        from sim.io.mcap_file import RUN_METADATA

        self.path = Path(log_path)
        if not self.path.is_file():
            raise CircuitError(f"{self.path}: log file not found" if not self.path.exists() else f"{self.path}: not a regular file")
        try:
            self.log = read_log(self.path)
        except (OSError, ValueError, EOFError, LookupError) as exc:
            raise CircuitError(f"{self.path}: not a readable MCAP log ({type(exc).__name__}: {exc})") from None
        self.meta = self.log.metadata.get(RUN_METADATA, {})
        if "scenario.toml" not in self.log.attachments or "scenario" not in self.meta:
            raise CircuitError(f"{self.path}: no attached scenario; not a hydroplant run log")
        self.dt = float(self.meta["dt_s"])
        self._tmp = None

    def __enter__(self) -> "LoggedRun":
        self._tmp = tempfile.TemporaryDirectory(prefix="hydroplant-log-")
        self.scenario = self._materialise(Path(self._tmp.name))
        self.overrides = self._overrides()
        return self

    def __exit__(self, *exc) -> None:
        self._tmp.cleanup()

    def _overrides(self) -> dict:
        meta = self.meta
        out = {}
        for key, kind in RUN_KEYS.items():
            if key in meta:
                out[key.removesuffix("_s")] = kind(meta[key])
        if meta.get("mode") == "pbd-naive":
            out.pop("coupling", None)
        if meta.get("stepper", "default") != "default":
            out["stepper"] = meta["stepper"]
        out.update(json.loads(meta.get("play_overrides", "{}")))
        out.update(json.loads(meta.get("play_settings", "{}")))
        return out

    def _materialise(self, root: Path) -> Path:
        attachments = self.log.attachments
        scenario_text = attachments["scenario.toml"]
        try:
            table = tomllib.loads(scenario_text.decode("utf-8"))
        except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise CircuitError(f"{self.path}: the attached scenario.toml does not parse ({exc})") from None
        scene = table.get("scene", {})
        mjcf_rel, circuit_rel = Path(scene.get("mjcf", "")), Path(scene.get("circuit", ""))
        csv_rel = Path(table["inputs_csv"]) if isinstance(table.get("inputs_csv"), str) else None
        others = [n for n in attachments if n not in ("scenario.toml", "circuit.toml", "inputs.csv", mjcf_rel.name)]
        ups = sum(Path(p).parts.count("..") for p in [mjcf_rel, circuit_rel, csv_rel or Path("."), *others])
        folder = root.joinpath(*(["d"] * (ups + 1)), self.meta.get("scene", "scene"))
        scenario_path = folder / Path(self.meta["scenario"]).name

        def put(path: Path, data: bytes) -> None:
            path = Path(os.path.normpath(path))
            if root not in path.parents:
                raise CircuitError(f"{self.path}: attachment path {path} leaves the rebuilt folder")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)

        put(scenario_path, scenario_text)
        put(folder / circuit_rel, attachments["circuit.toml"])
        if csv_rel is not None and "inputs.csv" in attachments:
            put(folder / csv_rel, attachments["inputs.csv"])
        mjcf = Path(os.path.normpath(folder / mjcf_rel))
        put(mjcf, attachments[mjcf_rel.name])
        for name in others:
            put(mjcf.parent / name, attachments[name])
        return scenario_path

    def commands(self) -> CommandTable | None:
        """The recorded commands (None for a log without them: its scenario's schedules are the inputs)."""
        if COMMANDS_TOPIC not in self.log:
            return None
        return table_from_log(self.log, self.dt)

    def first_snapshot(self) -> dict | None:
        """The log's first snapshot (None without snapshots)."""
        if snap.SNAPSHOT_TOPIC not in self.log:
            return None
        return snap.decode(self.log.topic(snap.SNAPSHOT_TOPIC).messages[0])

    def snapshot_at(self, at: float) -> dict:
        """The last snapshot at or before simulated time ``at`` [s]."""
        if snap.SNAPSHOT_TOPIC not in self.log:
            raise CircuitError(f"{self.path}: no snapshots ({snap.SNAPSHOT_TOPIC}); logs of 'hydroplant play' carry them")
        topic = self.log.topic(snap.SNAPSHOT_TOPIC)
        times = topic.log_time / 1e9
        index = np.flatnonzero(times <= at + 0.5 * self.dt)
        if not len(index):
            raise CircuitError(f"{self.path}: --at {at!r} s is before the first snapshot at {times[0]:.6g} s")
        return snap.decode(topic.messages[int(index[-1])])


def replay(log_path, *, out=None, overwrite: bool = False, paced: PlayOptions | None = None, stop=None):
    """Run a logged run again from its log alone with its recorded commands: the runner's own blocks, unpaced
    (a :class:`~sim.run.runner.RunResult`), or paced frames with ``paced`` options (a :class:`PlayResult`).  Every
    logged sample equals the original's bit for bit."""
    from sim.run.runner import run

    with LoggedRun(log_path) as logged:
        table = logged.commands()
        if table is None:
            raise CircuitError(f"{log_path}: no recorded commands ({COMMANDS_TOPIC}); logs of 'hydroplant play' carry them")
        meta = {"replay_of": str(log_path), "play_overrides": logged.meta.get("play_overrides", "{}")}
        start = logged.first_snapshot()  # a resumed run's log starts at its first snapshot
        driver = FrameDriver(commands=table, frames=paced is not None, options=paced, metadata=meta,
                             resume=start if start is not None and start["step_index"] > 0 else None)
        result = run(logged.scenario, out=out, overrides=logged.overrides, overwrite=overwrite, stop=stop, driver=driver)
    return result if paced is None else PlayResult(result, driver.summary)


def resume(log_path, at: float, *, out=None, overwrite: bool = False, source=None, options: PlayOptions | None = None,
           sinks=(), stop=None):
    """Continue a logged run from its last snapshot at or before ``at`` [s].

    Without ``source``: with the recorded commands in the runner's own blocks (a :class:`~sim.run.runner.RunResult`
    whose samples equal the original's from the snapshot on).  With ``source``: paced frames driven by it
    (a :class:`PlayResult`; ``options`` as :func:`play`'s)."""
    from sim.run.runner import run

    with LoggedRun(log_path) as logged:
        state = logged.snapshot_at(float(at))
        meta = {"resumed_from": str(log_path), "resumed_at_s": repr(state["step_index"] * logged.dt),
                "play_overrides": logged.meta.get("play_overrides", "{}")}
        if source is None:
            table = logged.commands()
            if table is None:
                raise CircuitError(f"{log_path}: no recorded commands ({COMMANDS_TOPIC}) to resume with")
            driver = FrameDriver(commands=table, frames=False, resume=state, metadata=meta)
            return run(logged.scenario, out=out, overrides=logged.overrides, overwrite=overwrite, stop=stop, driver=driver)
        driver = FrameDriver(source, options=options, resume=state, sinks=sinks, metadata=meta)
        result = run(logged.scenario, out=out, overrides=logged.overrides, overwrite=overwrite, stop=stop, driver=driver)
        return PlayResult(result, driver.summary)


__all__ = ["FrameDriver", "FrameSummary", "HoldSource", "LoggedRun", "PlayOptions", "PlayResult", "ProgramSource",
           "ScheduleSource", "play", "replay", "resume"]


# ------------------------------------------------------------------------------------------------- command line


def add_parser(subparsers) -> None:
    """``hydroplant play``: declared in :mod:`sim.commands` (so ``--help`` imports nothing heavy)."""
    from sim.commands import add_play

    add_play(subparsers)


def _endpoints(args, scene=None, launch=None):
    """The command source and frame sinks the options ask for (the optional live modules imported only then);
    ``scene``: the loaded scene the viewer shows (``--view``); ``launch``: the viewer's window opener (tests pass a
    stand-in; default :func:`mujoco.viewer.launch_passive`)."""
    sinks, source = [], None
    live = None
    if args.input == "keyboard" and not args.view:
        raise CircuitError("play: --input keyboard reads the keys of the viewer window: add --view")
    if args.view:
        from sim.io.foxglove_scene import CylinderPins  # noqa: PLC0415 - only with a window
        from sim.live.devices import KeyboardSource  # noqa: PLC0415
        from sim.live.viewer import ViewerOverlay  # noqa: PLC0415

        if scene is None:
            raise CircuitError("play: --view shows a SCENARIO or --example (not --replay or --resume)")
        keys = KeyboardSource() if args.input == "keyboard" else None
        sinks.append(ViewerOverlay(scene.mjmodel, CylinderPins.of_scene(scene), key_callback=keys.key if keys else None,
                                   launch=launch))
        source = keys
    if args.foxglove is not None or args.input == "foxglove":
        from sim.live.foxglove_live import FoxgloveLive  # noqa: PLC0415 - optional extra 'live'

        live = FoxgloveLive(port=8765 if args.foxglove is None else args.foxglove)
        sinks.append(live)
        print(f"hydroplant: live Foxglove stream on ws://127.0.0.1:{live.port}", file=sys.stderr)
    if args.input == "foxglove":
        source = live.commands
    elif args.input == "gamepad":
        from sim.live.devices import GamepadSource  # noqa: PLC0415 - optional extra 'gamepad'

        source = GamepadSource.open()
    elif args.input == "none":
        source = HoldSource()
    return source, sinks


def main(args) -> int:
    from sim.commands import EXIT_DIVERGED
    from sim.io.examples import example_path

    options = PlayOptions(rate_hz=args.rate, pace=args.pace, overrun=args.overrun, snapshot_hz=args.snapshot_hz)
    from_log = [name for name in ("replay", "resume") if getattr(args, name) is not None]
    given = (args.scenario is not None) + (args.example is not None) + len(from_log)
    if given != 1:
        raise CircuitError("play: give one of a SCENARIO file, --example NAME, --replay LOG or --resume LOG")
    if (args.at is None) != (args.resume is None):
        raise CircuitError("play: --resume LOG and --at T go together")
    stop = getattr(args, "stop", None)  # hydroplant's signal check (sim.cli)
    overrides = {"mode": args.mode, "coupling": args.coupling, "dt": args.dt, "duration": args.duration,
                 "hydraulic_substeps": args.substeps, "pbd_substeps": args.pbd_substeps,
                 "monitor": False if args.no_monitor else None}
    scenario = example_path(args.example) if args.example else args.scenario
    if scenario is not None and args.input in ("keyboard", "gamepad"):
        scenario = load_scenario(scenario)
        if scenario.mapping is None:
            from hydraulics.circuit import load_circuit  # noqa: PLC0415
            from hydraulics.components import VALVE_KINDS  # noqa: PLC0415
            from sim.live.mapping import Mapping  # noqa: PLC0415

            valves = {c.name for c in load_circuit(scenario.circuit).by_kind(*VALVE_KINDS)}
            preset = Mapping.preset(args.pattern)  # the pattern's functions this machine has
            scenario = dataclasses.replace(scenario, mapping=Mapping(
                {axis: m for axis, m in preset.axes.items() if m.valve in valves}, args.pattern))
            print(f"hydroplant: {args.input} axes drive the valves by the {args.pattern.upper()} excavator pattern "
                  "(--pattern; a [mapping] section in the scenario overrides it)", file=sys.stderr)
    if args.replay is not None:
        if args.view:
            raise CircuitError("play: --view shows a SCENARIO or --example (not --replay or --resume)")
        result = replay(args.replay, out=args.out, overwrite=args.overwrite, paced=options, stop=stop)
    else:
        scene = None
        if args.view and scenario is not None:
            from sim.io.scene import load_scene  # noqa: PLC0415

            scene = load_scene((scenario if isinstance(scenario, Scenario) else load_scenario(scenario))
                               .with_overrides(**overrides))
        source, sinks = _endpoints(args, scene)
        if args.resume is not None:
            if source is None:
                with LoggedRun(args.resume) as logged:
                    source = ScheduleSource(load_scenario(logged.scenario).inputs)
            result = resume(args.resume, args.at, out=args.out, overwrite=args.overwrite, source=source,
                            options=options, sinks=sinks, stop=stop)
        else:
            result = play(scenario, source=source, sinks=sinks, options=options, out=args.out, overrides=overrides,
                          overwrite=args.overwrite, stop=stop)
    print(result.summary_text())
    return 0 if result.run.status == "complete" else EXIT_DIVERGED


def run_from_log(args):
    """``hydroplant run --replay LOG`` / ``--resume LOG --at T``: the run's result, or None when neither is given."""
    if args.replay is None and args.resume is None:
        if args.at is not None:
            raise CircuitError("run: --at T needs --resume LOG")
        return None
    if args.replay is not None and args.resume is not None:
        raise CircuitError("run: give --replay LOG or --resume LOG, not both")
    if args.scenario is not None or args.example is not None:
        raise CircuitError("run: --replay and --resume rebuild the run from the log; give no SCENARIO or --example")
    if args.resume is not None:
        if args.at is None or not (math.isfinite(args.at) and args.at >= 0):
            raise CircuitError(f"run: --resume needs --at T, a simulated time >= 0 [s] (got {args.at!r})")
        return resume(args.resume, args.at, out=args.out, overwrite=args.overwrite)
    return replay(args.replay, out=args.out, overwrite=args.overwrite)
