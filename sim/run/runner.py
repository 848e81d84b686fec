"""Run a scenario: build the scene and plant, step, log to MCAP, summarise.

Library use::

    from sim.run.runner import run
    result = run("models/boom/lift.scenario.toml", out="logs/lift.mcap")
    print(result.summary_text())

MuJoCo mode with the implicit coupling and the compiled kernels (the
defaults) advances :class:`~sim.plants.mujoco_fast.MujocoPlantFast` in blocks
of one ``mj_step(m, d, nstep=n)``: one log interval (``scenario.log_every``
steps), or as many whole intervals as fit in :func:`block_steps` (100 steps, or
2 s of simulated time when that is more: the default 100 Hz log at 1 kHz, blocks
of 200 intervals; every step: blocks of 2000, bounded by the recorder's ring).
The plant records the log samples inside a block from its
compiled loop straight into the recorder's ring
(``MujocoPlantFast.advance(n, record, every)``), so a block runs one step past
its last sample; a sample that ends a block (every-step logging, the run's
last step) is captured from Python (:meth:`RunRecorder.capture`).  Every
other configuration and ``run(..., fast=False)`` step one step at a time.  Both paths log the same
values to round-off (``tests/test_runner_fast.py``), and recorded and
captured samples are bit-identical.

Log samples are kept raw in the recorder's ring and their fields
derived and written per batch of up to ``sim.run.recorder.RING_SIZE`` samples,
and at every periodic flush of the log; the energy-growth check runs on each
batch and stops the run at the first offending sample: the log ends there,
marked ``diverged`` at that sample's time, and the result's time, steps,
strokes, joints and energy terms are those of that sample (the plant itself
may have run on to the end of the batch).

A run that diverges (non-finite state, or a hydraulic step that fails) stops
at that step with the time and the component named, and its log keeps every
logged step up to it, marked ``diverged`` (a failed block is rewound and
replayed step by step to find that step).  Peak and minimum pressures are
over every step on the per-step path; on the block path they are over every
step when the plant keeps per-step extremes, else over the block ends (the
log rate).  An exception or Ctrl-C leaves a
finished, indexed log marked ``incomplete``.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import platform
import sys
import tempfile
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from sim import version
from hydraulics.components import CircuitError
from sim.run.compile_watch import CompileWatch
from sim.run.guards import check_plant
from sim.io.files import PARTIAL_SUFFIX, check_output, free_path, read_bytes
from sim.io.mcap_log import LogLevel, LogWriter
from sim.run.monitor import RunMonitor, Violation
from sim.run.recorder import RING_SIZE, RunRecorder
from sim.io.scenario import Scenario, load_scenario
from sim.plants.controllers import load_python_controllers
from sim.io.scene import load_scene

DEFAULT_LOG_DIR = Path("logs")
PROGRESS_AFTER = 3.0  # s of wall time before a progress line is shown (on a terminal only)
PROGRESS_EVERY = 0.5  # s of wall time between two redraws of the progress line
# A run has diverged when its mechanical + oil energy grows beyond what the pumps put in:
ENERGY_GROWTH_LIMIT = 3.0  # relative to |initial energy| + pump work (symplectic steps swing by less)
ENERGY_GROWTH_FLOOR = 1.0  # J, so that machines starting at zero energy are not flagged by round-off


def make_plant(scene, *, fast: bool = True):
    """The plant for the scenario's mode.

    MuJoCo mode uses :class:`~sim.plants.mujoco_fast.MujocoPlantFast` when ``fast``
    (the default): with the implicit coupling and the compiled kernels it steps
    whole blocks inside ``mj_step``, otherwise it falls back to the per-step
    :class:`~sim.plants.mujoco.MujocoPlant` path (its ``fast`` attribute is then
    False).  ``fast=False`` forces :class:`MujocoPlant`.
    """
    mode = scene.scenario.mode
    if mode == "mujoco":
        if fast:
            from sim.plants.mujoco_fast import MujocoPlantFast

            plant = MujocoPlantFast(scene)
        else:
            from sim.plants.mujoco import MujocoPlant

            plant = MujocoPlant(scene)
    else:
        from sim.plants.pbd import make_pbd_plant  # noqa: PLC0415 - optional until the PBD mode exists

        plant = make_pbd_plant(scene, block=fast)  # fast=False: the PBD plant steps one step at a time too
    plant.python_controller = load_python_controllers(plant)  # the scenario's `type = "python"` controller, if any
    return plant


class _Snapshot:
    """Everything a :class:`MujocoPlantFast` block changes, so a failed block can be replayed step by step.

    The MjData's integration state (``mj_getState``), the energy ledger and the controls
    (which ``advance`` writes in place) are copied; the network state, efforts, θ,
    ``last_report`` and the pressure extremes are kept by reference: ``advance`` replaces
    them with new objects and never writes into them (see :class:`MujocoPlantFast`).
    """

    SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
    LEDGER = ("pump_work", "motor_work", "dissipated_hydraulic", "dissipated_friction", "dissipated_mechanical")

    def __init__(self, plant):
        # a plant with its own snapshot()/restore() (PbdPlant) keeps its body state itself; else MjData's
        self.own = callable(getattr(plant, "snapshot", None)) and callable(getattr(plant, "restore", None))
        self.buffer = None if self.own else np.empty(mujoco.mj_stateSize(plant.model, self.SPEC))
        self.extreme_names = tuple(name for name in _PLANT_EXTREMES if hasattr(plant, name))
        self.valve_command = np.empty_like(plant.control.valve_command)
        self.pump_speed = np.empty_like(plant.control.pump_speed)
        self.take(plant)

    def take(self, plant) -> None:
        if self.own:
            self.plant_state = plant.snapshot()
        else:
            mujoco.mj_getState(plant.model, plant.data, self.buffer, self.SPEC)
        self.step_index = plant.step_index
        self.net_state, self.effort, self.theta, self.last_report = plant.net_state, plant.effort, plant.theta, plant.last_report
        e = plant.energy
        self.ledger = (e.pump_work, e.motor_work, e.dissipated_hydraulic, e.dissipated_friction, e.dissipated_mechanical)
        control = plant.control
        np.copyto(self.valve_command, control.valve_command)
        np.copyto(self.pump_speed, control.pump_speed)
        self.extremes = [getattr(plant, name) for name in self.extreme_names]
        self.controller_state = plant.controller_state.copy()  # (written in place by the blocks)

    def restore(self, plant) -> None:
        if self.own:
            plant.restore(self.plant_state)
        else:
            mujoco.mj_setState(plant.model, plant.data, self.buffer, self.SPEC)
        plant.step_index = self.step_index
        plant.net_state, plant.effort, plant.theta, plant.last_report = self.net_state, self.effort, self.theta, self.last_report
        for name, value in zip(self.LEDGER, self.ledger):
            setattr(plant.energy, name, value)
        plant.control.valve_command[:] = self.valve_command
        plant.control.pump_speed[:] = self.pump_speed
        for name, value in zip(self.extreme_names, self.extremes):
            setattr(plant, name, value)
        plant.controller_state[:] = self.controller_state


# Steps between snapshots of the block path: a failed block is replayed from the last snapshot (the
# steps before the block again without logging, then the block one step at a time; the same arithmetic).
SNAPSHOT_STEPS = 100

# Shortest block of the block path [steps] when the log interval is shorter: whole log intervals up to
# ``block_steps(dt)`` steps go into one ``advance`` (one block per sample cost ≈ 18 µs per step of Python around
# ``mj_step`` at the default 100 Hz log of a 1 kHz run; 100 steps amortise it to < 2 µs).  The default
# log interval and every-step logging then step the plant in the same blocks.
MIN_BLOCK_STEPS = 100
# Simulated time a block spans at least [s] when that is more than MIN_BLOCK_STEPS steps: what is left per block
# (the compiled call's dispatch, ~150 arguments for PBD mode, the snapshot, committing the recorded samples, the
# monitor's checks, the hand-over of a batch to the log) is 0.1–0.4 ms, i.e. 4–12 % of a 100-step block of the
# excavator at 1 kHz.  One block per periodic flush of the log (sim.io.log_writer.DEFAULT_FLUSH_INTERVAL) hands each
# batch to the log's writer thread once, as the block that follows starts (paired in-process runs of the logged 20 s
# dig, implicit, 1 kHz: with blocks of 0.5 s the logged run takes 4 % longer at the default 100 Hz and 2 % longer
# logging every step, its own thread executing 1.0 % and 2.3 % more instructions).
BLOCK_SECONDS = 2.0


def block_steps(dt: float) -> int:
    """Steps per block of the block path at step ``dt`` [s]: MIN_BLOCK_STEPS, or BLOCK_SECONDS of simulated time
    when that is more (1 kHz: 2000; 1200 Hz: 2400; 60 Hz frames: 120; 10 Hz frames: 100)."""
    return max(MIN_BLOCK_STEPS, int(round(BLOCK_SECONDS / dt)))


class _NonFinite:
    """Stands for a block whose recorded samples were not finite (replayed step by step like a failed one)."""

    success = False
    message = ""


_NONFINITE = _NonFinite()

# Verdicts of _Loop.block_checks
_GO_ON, _REPLAY, _STOP = "go on", "replay", "stop"


# Per-step extremes a plant may keep over its blocks (running max / min of the end-of-step node pressures [Pa] and
# actuator coordinates [m | rad] of every successful step, initial state included); used when present.
_PLANT_EXTREMES = ("node_pressure_max", "node_pressure_min", "actuator_position_max", "actuator_position_min")


@dataclass
class RunResult:
    """Outcome of a run."""

    scenario: Scenario
    log_path: Path
    status: str
    message: str
    simulated_time: float
    wall_time: float
    steps: int
    peak_pressure: dict = field(default_factory=dict)  # node -> Pa
    min_pressure: dict = field(default_factory=dict)
    final_joints: dict = field(default_factory=dict)  # joint -> rad or m
    final_strokes: dict = field(default_factory=dict)  # cylinder -> m
    energy: dict = field(default_factory=dict)
    extremes_every_step: bool = True
    """Whether ``peak_pressure``/``min_pressure`` cover every step (False: only the logged samples, see :class:`_Loop`)."""
    compile_time: float = 0.0
    """Wall time [s] before the timed loop spent compiling the kernels, or loading them from numba's disk cache: the
    compilations while the scene loaded, the plant's construction and the warm-up (:func:`warm_up`); not part of
    ``wall_time``."""
    kernels_compiled: int = 0
    """Functions numba compiled for this run (0 when every kernel came from the disk cache or an earlier run)."""

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second of the timed loop (compilation excluded)."""
        return self.simulated_time / self.wall_time if self.wall_time > 0 else math.inf

    def summary_text(self) -> str:
        s = self.scenario
        lines = [
            f"scenario      {s.path}",
            f"mode          {s.mode}, coupling {s.coupling}, dt {s.dt:g} s, hydraulic substeps {s.hydraulic_substeps}",
            f"status        {self.status}{': ' + self.message if self.message else ''}",
            f"simulated     {self.simulated_time:.4f} s in {self.steps} steps",
            f"wall time     {self.wall_time:.3f} s  (real-time factor {self.real_time_factor:.2f}; "
            + (f"compile {self.compile_time:.1f} s excluded)" if self.kernels_compiled else
               f"kernels loaded in {self.compile_time:.1f} s, excluded)"),
            "pressures     node: min .. peak [bar]" + ("" if self.extremes_every_step else
                                                           f" (at the logged samples, {s.log_rate_hz:g} Hz)"),
        ]
        for node, peak in self.peak_pressure.items():
            lines.append(f"  {node:<28s} {self.min_pressure[node] / 1e5:9.2f} .. {peak / 1e5:9.2f}")
        if self.final_strokes:
            lines.append("final strokes [m]  " + ", ".join(f"{k} {v:.4f}" for k, v in self.final_strokes.items()))
        if self.final_joints:
            lines.append("final joints [rad|m]  " + ", ".join(f"{k} {v:.4f}" for k, v in self.final_joints.items()))
        if self.energy:
            e = self.energy
            lines.append(
                "energy [J]    pump work {pump_work:.4g} = d(kin+pot+oil) {delta:.4g} + dissipated {dissipated:.4g} + residual {residual:.4g} "
                "({relative:.2%} of pump work)".format(**e)
            )
        lines.append(f"log           {self.log_path}")
        return "\n".join(lines)


def default_log_path(scenario: Scenario) -> Path:
    """logs/<scene>-<scenario>-<mode>-<coupling>-<UTC time>.mcap, with ``-2``, ``-3``, ... before ``.mcap`` when
    that name or its ``.partial`` exists already (:func:`sim.io.files.free_path`): a default name never names an
    existing file (two runs that still pick one name at once: the second's exclusive ``.partial`` is refused
    and :func:`run` takes the next name)."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%S%fZ")
    name = f"{scenario.scene_name}-{scenario.name}-{scenario.mode}-{scenario.coupling}-{stamp}.mcap"
    return free_path((scenario.log_dir or DEFAULT_LOG_DIR) / name)


DEFAULT_NAME_TRIES = 100  # default log names tried when other runs take them at the same instant


class LogWriteError(CircuitError):
    """The log could not be written (a full disk, a folder that became read-only); the message names it."""


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM / SIGHUP, see :mod:`sim.cli`) stopped a run; ``log_path`` is its finished log, marked incomplete."""

    def __init__(self, log_path: Path):
        super().__init__(str(log_path))
        self.log_path = log_path


def input_files(scene) -> list[tuple[str, str, Path, bytes]]:
    """Every file the run is built from, as ``(attachment name, media type, path, bytes)``, read now.

    The scenario (``scenario.toml``), the circuit (``circuit.toml``), the inputs CSV when there is one
    (``inputs.csv``), the MJCF's includes and assets (named by their path relative to the MJCF's folder),
    and the MJCF itself last (under its own file name).
    """
    scenario = scene.scenario
    files = [("scenario.toml", "application/toml", scenario.path, read_bytes(scenario.path, "scenario", CircuitError)),
             ("circuit.toml", "application/toml", scenario.circuit, read_bytes(scenario.circuit, "circuit", CircuitError))]
    if scenario.inputs_csv is not None:
        files.append(("inputs.csv", "text/csv", scenario.inputs_csv, read_bytes(scenario.inputs_csv, "inputs CSV", CircuitError)))
    model = list(scene.model_files)
    folder = Path(scenario.mjcf).parent
    for f in model[1:]:
        media = "application/xml" if f.kind == "include" else "application/octet-stream"
        files.append((os.path.relpath(f.path, folder), media, f.path, f.data))
    main = model[0].data if model else read_bytes(scenario.mjcf, "MJCF", CircuitError)
    files.append((scenario.mjcf.name, "application/xml", scenario.mjcf, main))
    return files


def run_metadata(scenario: Scenario, plant=None) -> dict:
    """The hydroplant.run metadata record (all strings).

    With ``plant``, ``stepping`` says how it is advanced: ``"blocks"`` (whole
    blocks inside ``mj_step``, :class:`~sim.plants.mujoco_fast.MujocoPlantFast`)
    or ``"per-step"``.
    """
    extra = {} if plant is None else {"stepping": "blocks" if getattr(plant, "fast", False) else "per-step"}
    return {
        "scenario": str(scenario.path),
        "scene": scenario.scene_name,
        "mode": scenario.mode,
        "coupling": "explicit" if scenario.mode == "pbd-naive" else scenario.coupling,
        "stepper": str(scenario.stepper or "default"),
        "dt_s": repr(scenario.dt),
        "duration_s": repr(scenario.duration),
        "hydraulic_substeps": str(scenario.hydraulic_substeps),
        "pbd_substeps": str(scenario.pbd_substeps),
        "pbd_iterations": str(scenario.pbd_iterations),
        "fidelity": scenario.fidelity_label,  # the level, with per-actuator overrides
        "log_rate_hz": repr(scenario.log_rate_hz),
        "tf_rate_hz": repr(scenario.tf_rate_hz),
        "hydroplant_version": version(),
        "mujoco_version": mujoco.__version__,
        "numpy_version": np.__version__,
        "python_version": platform.python_version(),
        **extra,
    }


def run(scenario, *, out=None, overrides: dict | None = None, progress: bool = False, overwrite: bool = False,
        fast: bool = True, stop=None, driver=None, warn: bool | None = None, warm: bool = True) -> RunResult:
    """Run a scenario (path or :class:`Scenario`) and write its MCAP log; see the module docstring.

    ``out``: the log file (default :func:`default_log_path`).  Before the run starts it is checked
    by :func:`sim.io.files.check_output`: an existing file is replaced only with ``overwrite=True``,
    and never when it is one of the run's inputs (scenario, circuit, MJCF, its includes and assets,
    inputs CSV) or not a regular file; refusals raise :class:`CircuitError`.  Every input file is
    attached to the log (:func:`input_files`).

    ``fast=False`` forces the per-step path (:class:`~sim.plants.mujoco.MujocoPlant`
    in MuJoCo mode).

    ``progress``: show a progress line on stderr during a long run.  ``warn``: print the load-time
    warnings (stability guards, parts of the circuit not built) on stderr; default: as ``progress``
    (``hydroplant run`` always prints them, ``--no-progress`` leaves out the progress line only).
    The warnings are in the log's guard report either way.

    ``stop``: a callable without arguments, the caller's request to stop (``hydroplant run`` passes
    whether a signal arrived, in case a library turned its interrupt into an error and handled it);
    asked before the log is opened and before every step or block, and when it returns True the run
    stops as on Ctrl-C (:class:`KeyboardInterrupt`: before the log is opened, no log is written).

    ``driver``: what advances the plant instead of the run's own blocks (``hydroplant play``'s paced frames,
    :class:`sim.run.play.FrameDriver`): an object with ``scene(scene) -> Scene`` (the scene to build the plant of,
    e.g. its scenario's inputs replaced by operator commands), ``prepare(plant)`` (before the first sample, e.g. a resumed
    state), ``metadata`` (extra ``hydroplant.run`` entries, str → str), ``start(log, loop)`` (its own topics),
    ``drive(loop)`` (calls ``loop.blocks(until)`` or ``loop.per_step(until)``) and ``result_info()`` (entries of
    the ``hydroplant.result`` record).  The log, its checks and its samples are the run's own.

    ``warm``: before the clock starts, compile (or load from numba's disk cache) every kernel the run calls, by a
    short throwaway run (:func:`warm_up`), so that ``wall_time`` and ``real_time_factor`` are the stepping alone;
    the time it took is ``compile_time``.  A compilation (a cold cache) is announced on stderr with its progress
    (:class:`~sim.run.compile_watch.CompileWatch`).  ``warm=False`` leaves the kernels to their first call.

    Raises :class:`RunInterrupted` (a :class:`KeyboardInterrupt`) naming the log when interrupted
    while the log is written.
    """
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if overrides:
        scenario = scenario.with_overrides(**overrides)
    # compile_time: the kernels compiled while the scene loads (its start-up equilibrium), then building the plant
    # (MuJoCo mode compiles or loads its control callback there) and the warm-up
    warn = progress if warn is None else warn
    with CompileWatch(f"{scenario.scene_name}/{scenario.name}", scenario.mode, show=warm) as watch:
        scene = load_scene(scenario)
        if driver is not None:
            scene = driver.scene(scene)
        inputs = input_files(scene)
        if out is not None:
            log_path = check_output(out, [path for _, _, path, _ in inputs], overwrite=overwrite)
        if scene.network.pruned and warn:
            print(f"hydroplant: not built (connected to no cylinder or motor): {', '.join(scene.network.pruned)}",
                  file=sys.stderr)
        compile_time, set_up = watch.seconds, _time.perf_counter()
        plant = make_plant(scene, fast=fast)
        if driver is not None:
            driver.prepare(plant)
        guard = check_plant(plant)  # load-time stability guards: warn, never fail
        if warm:
            warm_up(scenario, fast=fast, stop=stop)
        compile_time += _time.perf_counter() - set_up
    if warn:
        for text in guard.warnings:
            print(f"hydroplant: warning: {text}", file=sys.stderr)
    attachments = [(name, media, data) for name, media, _, data in inputs]
    net = plant.network
    if stop is not None and stop():
        raise KeyboardInterrupt
    metadata = run_metadata(scenario, plant)
    if driver is not None:
        metadata.update(driver.metadata)
    if out is not None:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        writer = LogWriter(log_path, dt=scenario.dt, run_metadata=metadata, attachments=attachments, overwrite=overwrite,
                           batch_size=RING_SIZE)  # (a ring of the recorder is one batch of the log)
    else:
        log_path, writer = _default_writer(scenario, metadata, attachments)
    try:
        with writer as log:
            loop, wall = _run_loop(log, plant, scenario, guard, (progress, stop), driver)
    except KeyboardInterrupt:
        raise RunInterrupted(log_path) from None
    except OSError as exc:  # a full disk, a folder gone or made read-only during the run
        partial = log_path.with_name(log_path.name + PARTIAL_SUFFIX)
        if os.path.lexists(partial):
            kept = f"; the data written so far is in {partial} ('hydroplant log recover {partial}' once the cause is fixed)"
        else:
            kept = "; the log written so far is finished and marked incomplete" if os.path.lexists(log_path) else ""
        raise LogWriteError(f"{log_path}: cannot write the log ({exc.strerror or exc}){kept}") from None
    if progress and wall > PROGRESS_AFTER and sys.stderr.isatty():
        print(file=sys.stderr)
    e = plant.energy
    sample = loop.sample  # the last logged sample (the final step, the failing step, or where energy growth was found)
    pump_work, dissipated = sample["pump_work"], sample["dissipated"]
    total = sample["kinetic"] + sample["potential"] + sample["oil"]
    steps = plant.step_index if loop.stop_step is None else loop.stop_step
    if loop.stop_step is None:
        q, x = plant.joint_state()[0], plant.net_state.actuator_position
    else:  # the plant ran on past the sample (energy growth is checked per batch of samples)
        q, x = sample["joint_position"], sample["actuator_position"]
    strokes = {net.actuator_names[a]: float(x[a]) for a in net.cylinder_actuator}
    free = [i for i in range(len(net.node_names)) if not net.node_fixed[i]]
    return RunResult(
        scenario=scenario,
        log_path=log_path,
        status=loop.status,
        message=loop.message,
        simulated_time=steps * plant.dt,
        wall_time=wall,
        steps=steps,
        peak_pressure={net.node_names[i]: float(loop.peak[i]) for i in free},
        min_pressure={net.node_names[i]: float(loop.low[i]) for i in free},
        final_joints=dict(zip(plant.joint_names, map(float, q))),
        final_strokes=strokes,
        extremes_every_step=loop.extremes_every_step,
        compile_time=compile_time,
        kernels_compiled=watch.count,
        energy={
            "pump_work": pump_work,
            "delta": total - e.initial_total,
            "dissipated": dissipated,
            "residual": sample["residual"],
            "relative": sample["residual"] / pump_work if pump_work else 0.0,
        },
    )


WARM_UP_INTERVALS = 2  # log intervals of the throwaway run of warm_up (the first sample is recorded, the next captured)
WARMED_UP: set = set()
"""The :func:`warm_key` of every run this process has warmed up.  numba keeps a compiled (or loaded) kernel for the
life of the process, so a later run with the same key calls no kernel its warm-up did not (``compare``,
``tradeoff`` and the test suite run many in one process); another key is warmed up again."""


def warm_key(scenario: Scenario, fast: bool) -> tuple:
    """What selects the kernels a run calls: its mode, coupling, stepper, fidelity levels, stepping path
    (``fast``) and whether it logs every step.  A compiled kernel is keyed by the types of its arguments, which the
    duration, the step, the scene's size or the inputs do not change."""
    return (scenario.mode, scenario.coupling, scenario.stepper, scenario.fidelity_label, bool(fast),
            scenario.log_every == 1)


def warm_up(scenario: Scenario, *, fast: bool = True, stop=None) -> None:
    """Compile, or load from numba's disk cache, every kernel a run of ``scenario`` calls, unless this process
    warmed up a run with the same :func:`warm_key` already: a run of its first ``WARM_UP_INTERVALS`` log intervals
    and two steps (the same plant, stepping path, recorder and log writer) into a temporary log, deleted afterwards;
    its results are not used.

    The kernels are keyed by the types of their arguments, which a scenario's duration does not change, so the
    throwaway run calls the kernels of the full run and no other (a PBD run the PBD block and its callees, a MuJoCo
    run the control callback and the log writer's).  Ctrl-C (or ``stop``) during it raises
    :class:`KeyboardInterrupt`.
    """
    key = warm_key(scenario, fast)
    if key in WARMED_UP:
        return
    steps = min(scenario.step_count, WARM_UP_INTERVALS * scenario.log_every + 2)
    with tempfile.TemporaryDirectory(prefix="hydroplant-warm-up-") as folder:
        try:
            run(scenario.with_overrides(duration=steps * scenario.dt), out=Path(folder) / "warm-up.mcap", fast=fast,
                stop=stop, warm=False)
        except RunInterrupted:
            raise KeyboardInterrupt from None
    WARMED_UP.add(key)


def _default_writer(scenario: Scenario, metadata: dict, attachments):
    """The log at :func:`default_log_path`, the next free name when another run takes it at the same instant."""
    for _ in range(DEFAULT_NAME_TRIES):
        path = default_log_path(scenario)
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            return path, LogWriter(path, dt=scenario.dt, run_metadata=metadata, attachments=attachments,
                                   batch_size=RING_SIZE)
        except (FileExistsError, CircuitError):
            if not any(os.path.lexists(p) for p in (path, path.with_name(path.name + PARTIAL_SUFFIX))):
                raise  # refused for another reason
    raise CircuitError(f"{path.parent}: no free default log name after {DEFAULT_NAME_TRIES} tries; name one with --out")


def _run_loop(log: LogWriter, plant, scenario: Scenario, guard, caller, driver=None):
    """Step the plant through the run, logging to ``log``: the finished :class:`_Loop` and the wall time [s].
    ``caller`` = (progress line shown, stop request or None), as :func:`run` takes them; ``driver`` as :func:`run`'s."""
    progress, stop = caller
    # a ring holds the samples of one block (a block at most reaches the log's next flush, where the ring is pushed):
    # no larger than a run at a low log rate fills, since its fresh pages cost the run the first time they are written
    recorder = RunRecorder(log, plant, ring_size=block_steps(scenario.dt) // scenario.log_every + 1,
                           tf_every=scenario.tf_every)
    for text in guard.warnings:
        recorder.event(plant.step_index, LogLevel.WARNING, "stability guard: " + text)
    loop = _Loop(plant, recorder, log, scenario, progress and driver is None)
    loop.stop_request = stop
    if driver is not None:
        driver.start(log, loop)
        driver.drive(loop)
    elif getattr(plant, "fast", False):
        loop.blocks()
    else:
        loop.per_step()
    if loop.status == "complete" and loop.drain():  # the last batch of samples, checked like the others
        log.mark("complete")
    if driver is not None:
        log.mark(log.status, **driver.result_info())
    loop.finish_extremes()
    return loop, _time.perf_counter() - loop.start


class _Loop:
    """The stepping loop of :func:`run`: checks, pressure extremes, log samples, progress line.

    Two drivers share the checks:

    :meth:`per_step`
        one ``plant.step()`` at a time (MuJoCo per-step path, PBD modes);
        divergence, peak and minimum pressures are checked after every step.
    :meth:`blocks`
        ``plant.advance(n)`` of a :class:`~sim.plants.mujoco_fast.MujocoPlantFast`
        in blocks chosen by :meth:`block_end`, the samples inside a block
        recorded by the plant (:meth:`RunRecorder.record_target`,
        :meth:`RunRecorder.commit_recorded`).  The plant's state is kept every
        ``SNAPSHOT_STEPS`` steps (:class:`_Snapshot`); a block that fails
        (hydraulic step failed, or a non-finite state in a recorded sample or
        at its end) is rewound to the last snapshot, advanced again to its start
        (unlogged), and replayed one ``advance(1)`` at a time through the
        per-step checks, so a divergence is reported at the failing step with
        the same time, component and log as on the per-step path (the replay
        repeats the block's arithmetic exactly).  Pressure extremes are taken
        over every step when the plant keeps them (``node_pressure_max`` /
        ``node_pressure_min``), else from the state at each block end, i.e. at
        the log rate.

    The plausibility monitor (:class:`sim.run.monitor.RunMonitor`, scenario
    ``[monitor] enabled``, ``hydroplant run --no-monitor``) checks the state at
    t = 0; pressures and strokes after every step on the per-step path and,
    on the block path, the plant's per-step extremes at each block end (a
    block whose extremes leave a bound is replayed step by step like a failed
    one, so the violation is reported at its step); energy residual, strokes
    and joint ranges on every batch of logged samples (:meth:`drain`); equality
    constraints per logged sample on the per-step path and per block end on
    the block path.  A violation stops the run (status ``diverged``, the log
    marked with ``check = "plausibility"``) or, with the monitor off, is
    written once per component and quantity as a warning event.
    """

    def __init__(self, plant, recorder: RunRecorder, log: LogWriter, scenario: Scenario, progress: bool):
        self.plant, self.recorder, self.log, self.scenario, self.progress = plant, recorder, log, scenario, progress
        self.steps = scenario.step_count
        self.every = scenario.log_every
        self.block_steps = block_steps(scenario.dt)
        self.status, self.message = "complete", ""
        self.peak = np.array(plant.net_state.node_pressure)
        self.low = self.peak.copy()
        self.per_step_extremes = all(hasattr(plant, name) for name in _PLANT_EXTREMES)
        self.extremes_every_step = not getattr(plant, "fast", False) or self.per_step_extremes or self.every == 1
        self.stop_step = None  # the step where energy growth was found (the plant may have run past it)
        self.stop_request = None  # the caller's request to stop (run(stop=...))
        self.replay_point = None  # the block path's _Snapshot (a failed block is replayed from it)
        # blocks of several log samples, recorded by the plant inside its compiled loop (MujocoPlantFast)
        self.record_blocks = bool(getattr(plant, "fast", False)) and recorder.records
        self.start = _time.perf_counter()
        self.last_progress = self.start
        self.sample: dict = {}
        self.monitor = RunMonitor(plant, enforce=getattr(scenario, "monitor", True))
        self.last_event_step = plant.step_index  # (a resumed run starts later than step 0)
        self.warnings: list = []  # (step, text) of the monitor's warnings not yet written (see accept)
        if not self.monitor.enforce:
            recorder.event(plant.step_index, LogLevel.WARNING, "plausibility monitor off (hydroplant run --no-monitor, or [monitor] "
                           "enabled = false): a state beyond its bounds is written as a warning and the run goes on")
        self.running = self.first_sample()

    def first_sample(self) -> bool:
        """The sample at t = 0 and the monitor's checks of that state; False when the run must stop there."""
        plant, monitor = self.plant, self.monitor
        found = monitor.check_start(plant)  # (before the sample's energy terms, NaN then, are checked)
        if found is not None and not self.accept(found):
            return False
        if not self.log_sample():
            return False
        state = plant.net_state
        found = monitor.check_state(plant.time, state.node_pressure, state.actuator_position)
        return self.accept(found or monitor.check_constraints(plant.time), capture=False)

    # ----------------------------------------------------------------- drivers
    def check_stop(self) -> None:
        """Raise :class:`KeyboardInterrupt` when the caller asked to stop (``run(stop=...)``)."""
        if self.stop_request is not None and self.stop_request():
            raise KeyboardInterrupt

    def per_step(self, until: int | None = None) -> None:
        """One ``plant.step()`` at a time up to step ``until`` (default: the run's last)."""
        plant = self.plant
        if not self.running or self.status != "complete":
            return
        until = self.steps if until is None else min(int(until), self.steps)
        while plant.step_index < until:
            self.check_stop()
            if not self.after_step(plant.step()):
                return
            self.show_progress()

    def block_end(self, k: int) -> int:
        """Where the block starting at step ``k`` ends.

        Without in-block recording: at the next log sample (or the last step).  With it: at the
        step after the block's last sample, so that the plant records every sample of the block
        from its compiled loop (a block's last step can only be captured from Python; at every-step
        logging, or at the end of the run, the block ends on that sample and it is captured).  A
        block holds one log interval, or as many whole intervals as fit in :func:`block_steps`, within
        the room left in the recorder's ring, and never a sample past the first one at or after the
        log's next periodic flush (so that the flush still writes every sample before it when due).
        """
        steps, every = self.steps, self.every
        end = min(k + every - k % every, steps)  # the next sample
        if self.record_blocks:
            last = end + (max(1, min(self.recorder.room, self.block_steps // every)) - 1) * every
            flush = self.log._next_flush_step
            if flush < math.inf:
                last = min(last, max(end, -(-int(flush) // every) * every))  # the first sample at or after the flush
            end = min(last, steps)
            if every > 1 and end < steps:  # one step further: the sample at `end` is recorded too
                end += 1
        return end

    def blocks(self, until: int | None = None) -> None:
        """Blocks of ``plant.advance`` up to step ``until`` (default: the run's last; a paced driver calls it once
        per frame, :mod:`sim.run.play`): the same blocks, clipped at ``until``."""
        plant, recorder, steps, every = self.plant, self.recorder, self.steps, self.every
        if not self.running or self.status != "complete":
            return
        until = steps if until is None else min(int(until), steps)
        if self.replay_point is None:
            self.replay_point = _Snapshot(plant)
        snapshot = self.replay_point
        while plant.step_index < until:
            self.check_stop()
            k = plant.step_index
            end = min(self.block_end(k), until)
            n = end - k
            if k - snapshot.step_index >= SNAPSHOT_STEPS:  # (a failed block is replayed from the last snapshot)
                snapshot.take(plant)
            rows = plant.record_rows(k, n, every) if self.record_blocks else 0
            if rows:  # the samples inside the block are recorded by the plant, straight into the recorder's ring
                plant.record_next(recorder.record_target(rows), every)
            report = plant.advance(n)
            if report.success:
                # commit the recorded samples if finite; capture the block's last step if it is a sample; check the
                # final state is finite (on the captured copy, as plant.finite())
                captured = end % every == 0 or end == steps
                if rows and (plant.recorded != rows or not plant.recorded_finite
                             or not recorder.commit_recorded((k // every + 1) * every, every, rows, checked=True)):
                    report = _NONFINITE
                else:
                    if captured:
                        due = recorder.capture(end)
                        finite = recorder.captured_finite()
                    else:
                        due, finite = recorder.due, plant.end_finite  # (plant.finite(), from the compiled loop)
                    verdict = self.block_checks(captured) if finite else _REPLAY
                    if verdict == _GO_ON:
                        if not self.per_step_extremes:
                            self.track_block()
                        # the next block's snapshot before the samples go to the log's writer thread: mj_getState
                        # lets go of the GIL, and the writer, woken by the hand-over, would take it for its Python
                        # and keep this thread waiting up to the interpreter's switch interval
                        if end - snapshot.step_index >= SNAPSHOT_STEPS and end < until:
                            snapshot.take(plant)
                        if due and not self.drain():
                            return
                        self.show_progress()
                        continue
                    if verdict == _STOP:
                        return
                    recorder.discard(rows + captured)
            if n == 1:  # a one-step block is its own replay
                if not self.after_step(report):
                    return
            else:  # rewind to the block's start, then find the failing step one step at a time
                snapshot.restore(plant)
                if k > plant.step_index:  # from the snapshot to the block's start: the same steps again, not logged
                    report = plant.advance(k - plant.step_index)
                    if not report.success or plant.step_index != k:  # (never: the same arithmetic succeeded before)
                        self.diverged(report)
                        return
                for _ in range(n):
                    if not self.after_step(plant.advance(1)):
                        return
            if report.success and not self.monitor.extremes_within(plant):
                # (never: the replay repeats the steps whose extremes left a bound, and after_step checks each; should
                # it not find the step, the run stops at the block's end rather than replaying every later block)
                if not self.accept(self.monitor.check_extremes(plant.time, plant)):
                    return
            self.show_progress()

    # ------------------------------------------------------------------ checks
    def after_step(self, report) -> bool:
        """Checks after one step; False when the run must stop."""
        plant = self.plant
        if not report.success or not plant.finite():
            self.diverged(report)
            return False
        state = plant.net_state
        p = state.node_pressure
        np.maximum(self.peak, p, out=self.peak)
        np.minimum(self.low, p, out=self.low)
        if not self.accept(self.monitor.check_state(plant.time, p, state.actuator_position)):
            return False
        if plant.step_index % self.every == 0 or plant.step_index == self.steps:
            return self.log_sample() and self.accept(self.monitor.check_constraints(plant.time), capture=False)
        return True

    def block_checks(self, captured: bool) -> str:
        """The monitor's checks after a successful block: ``_GO_ON``, ``_REPLAY`` (the plant's per-step extremes
        left a bound: replay the block step by step to find the step) or ``_STOP`` (the run stopped here)."""
        plant, monitor = self.plant, self.monitor
        if self.per_step_extremes:
            if not monitor.extremes_within(plant):
                if monitor.enforce:
                    return _REPLAY
                self.accept(monitor.check_extremes(plant.time, plant))  # (warns)
        else:
            state = plant.net_state
            if not self.accept(monitor.check_state(plant.time, state.node_pressure, state.actuator_position), capture=not captured):
                return _STOP
        if not self.accept(monitor.check_constraints(plant.time), capture=not captured):
            return _STOP
        return _GO_ON

    def accept(self, violation: Violation | None, *, capture: bool = True) -> bool:
        """True when the run goes on: no violation, or the monitor is off (a new kind of violation is then
        written as a warning event); else the run stops here (:meth:`implausible`, with a sample of the current
        state unless ``capture`` is False because it is logged already)."""
        monitor = self.monitor
        if monitor.accept(violation):
            if monitor.new_warning is not None:
                step = int(round(violation.time / self.plant.dt))
                # written when the samples up to it are checked (drain): a run stopped at an earlier sample never saw it
                self.warnings.append((step, f"plausibility (monitor off, the run goes on): {violation.message}"))
            return True
        self.implausible(violation, capture=capture)
        return False

    def write_warnings(self, upto: int) -> None:
        """Write the monitor's pending warnings at steps up to ``upto`` (the last logged sample); drop the later ones
        when the run has stopped."""
        keep = []
        for step, text in sorted(self.warnings):
            if step <= upto:
                self.event(step, LogLevel.WARNING, text)
            elif self.status == "complete":
                keep.append((step, text))
        self.warnings = keep

    def event(self, step: int, level: LogLevel, text: str) -> None:
        """An event at ``step``, or at the last event's step when that is later (events are written in step order;
        a check of a batch of samples finds a violation at a sample before a warning the per-step checks wrote;
        the text carries its own time)."""
        step = max(int(step), self.last_event_step)
        self.last_event_step = step
        self.recorder.event(step, level, text)

    def implausible(self, violation: Violation, *, capture: bool = True) -> None:
        """Stop the run at the plant's current step for a monitor violation: the log ends with this step's
        sample, marked ``diverged`` with ``check = "plausibility"``."""
        plant = self.plant
        if not self.drain():  # an earlier sample still in the ring stops the run there
            return
        if capture:
            self.recorder.capture(plant.step_index)
        self.drain(check=False)
        self.stop(violation, plant.step_index)

    def stop(self, violation: Violation, step: int) -> None:
        """Mark the run stopped by the monitor at ``step`` (its log already ends there)."""
        self.status, self.stop_step = "diverged", step
        self.message = f"{violation.message}; stopped by the plausibility monitor (hydroplant run --no-monitor goes on)"
        self.event(step, LogLevel.ERROR, "implausible: " + self.message)
        self.log.mark("diverged", time_s=repr(step * self.plant.dt), component=violation.component, message=self.message,
                      check="plausibility", quantity=violation.quantity)

    def track_block(self) -> None:
        plant = self.plant
        p = plant.net_state.node_pressure
        np.maximum(self.peak, p, out=self.peak)
        np.minimum(self.low, p, out=self.low)

    def finish_extremes(self) -> None:
        """Fold in the plant's own per-step extremes (when it keeps them; they cover every successful step)."""
        if self.per_step_extremes:
            np.maximum(self.peak, self.plant.node_pressure_max, out=self.peak)
            np.minimum(self.low, self.plant.node_pressure_min, out=self.low)

    def diverged(self, report) -> None:
        plant = self.plant
        if not self.drain():  # energy growth at an earlier sample still in the ring stops the run there
            return
        component = _failed_component(plant, report)
        self.status = "diverged"
        self.message = f"t = {plant.time:.6g} s, {component}: {report.message or 'non-finite state'}"
        self.recorder.capture(plant.step_index)
        self.drain(check=False)
        self.event(plant.step_index, LogLevel.ERROR, "diverged: " + self.message)
        self.log.mark("diverged", time_s=repr(plant.time), component=component, message=self.message)

    def log_sample(self) -> bool:
        """Capture a sample (its fields are derived and written per batch, :meth:`drain`); False when the run diverged."""
        if self.recorder.capture(self.plant.step_index):
            return self.drain()
        return True

    def drain(self, check: bool = True) -> bool:
        """Derive and write the captured samples, checking energy growth and the monitor's per-sample bounds
        (energy residual, strokes, joint ranges) on each; False when the run diverged.

        The first sample whose mechanical + oil energy grew beyond what the pumps put in, or
        that leaves a bound of the monitor, stops the run: the log ends with that sample,
        marked ``diverged`` at its time.
        """
        plant, recorder = self.plant, self.recorder
        batch = recorder.derive()
        if batch is None:
            return True
        bad = None
        # (no energy terms without oil; a pressure source's work counts as pump work: hydraulics.energy.source_power)
        if check and plant.coupling.name != "incompressible":
            e = plant.energy
            gained = batch["kinetic"] + batch["potential"] + batch["oil"] - e.initial_total
            allowed = ENERGY_GROWTH_LIMIT * (abs(e.initial_total) + batch["pump_work"]) + ENERGY_GROWTH_FLOOR
            over = np.flatnonzero(gained > allowed)
            if len(over):
                bad = int(over[0])
                step, gain, pump_work = int(batch["step"][bad]), float(gained[bad]), float(batch["pump_work"][bad])
        found = self.monitor.check_batch(batch, plant.dt, plant.energy.initial_total) if check else None
        if found is not None and self.monitor.enforce and (bad is None or found[0] < bad):
            recorder.push(found[0] + 1)
            self.sample = recorder.last
            self.stop(found[1], int(self.sample["step"]))
            return False
        if found is not None and (bad is None or found[0] <= bad):
            self.accept(found[1])  # the monitor is off: a warning
        recorder.push(None if bad is None else bad + 1)
        self.sample = recorder.last
        self.write_warnings(int(self.sample["step"]) if self.sample else 0)
        if bad is None:
            return True
        time = step * plant.dt  # as plant.time
        self.status, self.stop_step = "diverged", step
        self.message = (
            f"t = {time:.6g} s, energy growth: the machine gained {gain:.4g} J, more than the "
            f"{pump_work:.4g} J of pump work allows; the coupling is unstable at this step size"
        )
        self.event(step, LogLevel.ERROR, "diverged: " + self.message)
        self.log.mark("diverged", time_s=repr(time), component="coupling (energy growth)", message=self.message)
        return False

    def show_progress(self) -> None:
        """``\\r`` progress with an estimate of the time left, only when stderr is a terminal (never into a pipe or file)."""
        if self.progress and sys.stderr.isatty():
            now = _time.perf_counter()
            if now - self.start > PROGRESS_AFTER and now - self.last_progress > PROGRESS_EVERY:
                self.last_progress = now
                done = self.plant.time / self.scenario.duration if self.scenario.duration > 0 else 1.0
                eta = f", ETA {(now - self.start) * (1 - done) / done:.0f} s" if done > 0 else ""
                print(f"\r\033[K  {self.plant.time:8.3f} / {self.scenario.duration:g} s simulated{eta}", end="",
                      file=sys.stderr, flush=True)


def _failed_component(plant, report) -> str:
    """Name the component where a step failed: the first non-finite node, actuator or joint."""
    net = plant.network
    p = plant.net_state.node_pressure
    if report.message and "node '" in report.message:
        return "node " + report.message.split("node '")[1].split("'")[0]
    bad = np.flatnonzero(~np.isfinite(p))
    if len(bad):
        return f"node {net.node_names[bad[0]]}"
    q, qd = plant.joint_state()
    bad = np.flatnonzero(~(np.isfinite(q) & np.isfinite(qd)))
    if len(bad):
        return f"joint {plant.joint_names[bad[0]]}"
    return "hydraulic network"
