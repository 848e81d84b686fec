"""Run a scenario: build the scene and plant, step, log to MCAP, summarise.

Library use::

    from sim.runner import run
    result = run("models/boom/lift.scenario.toml", out="logs/lift.mcap")
    print(result.summary_text())

A run that diverges (non-finite state, or a hydraulic step that fails) stops
at that step with the time and the component named, and its log keeps every
logged step up to it, marked ``diverged``.  An exception or Ctrl-C leaves a
finished, indexed log marked ``incomplete``.
"""

from __future__ import annotations

import datetime as _dt
import math
import platform
import sys
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from .guards import check_plant
from .mcap_log import LogLevel, LogWriter
from .recorder import RunRecorder
from .scenario import Scenario, load_scenario
from .scene import load_scene

DEFAULT_LOG_DIR = Path("logs")
PROGRESS_AFTER = 3.0  # s of wall time before a progress line is shown
# A run has diverged when its mechanical + oil energy grows beyond what the pumps put in:
ENERGY_GROWTH_LIMIT = 3.0  # relative to |initial energy| + pump work (symplectic steps swing by less)
ENERGY_GROWTH_FLOOR = 1.0  # J, so that machines starting at zero energy are not flagged by round-off


def make_plant(scene):
    """The plant for the scenario's mode."""
    mode = scene.scenario.mode
    if mode == "mujoco":
        from .plant_mujoco import MujocoPlant

        return MujocoPlant(scene)
    from .plant_pbd import make_pbd_plant  # noqa: PLC0415 - optional until the PBD mode exists

    return make_pbd_plant(scene)


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

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.simulated_time / self.wall_time if self.wall_time > 0 else math.inf

    def summary_text(self) -> str:
        s = self.scenario
        lines = [
            f"scenario      {s.path}",
            f"mode          {s.mode}, coupling {s.coupling}, dt {s.dt:g} s, hydraulic substeps {s.hydraulic_substeps}",
            f"status        {self.status}{': ' + self.message if self.message else ''}",
            f"simulated     {self.simulated_time:.4f} s in {self.steps} steps",
            f"wall time     {self.wall_time:.3f} s  (real-time factor {self.real_time_factor:.2f})",
            "pressures     node: min .. peak [bar]",
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
    """logs/<scene>-<scenario>-<mode>-<coupling>-<UTC time>.mcap"""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%S%fZ")
    return (scenario.log_dir or DEFAULT_LOG_DIR) / f"{scenario.scene_name}-{scenario.name}-{scenario.mode}-{scenario.coupling}-{stamp}.mcap"


def run_metadata(scenario: Scenario) -> dict:
    """The hydroplant.run metadata record (all strings)."""
    from importlib.metadata import version

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
        "fidelity": scenario.fidelity,
        "compiled": str(scenario.compiled),
        "log_rate_hz": repr(scenario.log_rate_hz),
        "hydroplant_version": version("hydroplant"),
        "mujoco_version": mujoco.__version__,
        "numpy_version": np.__version__,
        "python_version": platform.python_version(),
    }


def run(scenario, *, out=None, overrides: dict | None = None, progress: bool = False, overwrite: bool = True) -> RunResult:
    """Run a scenario (path or :class:`Scenario`) and write its MCAP log; see the module docstring."""
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if overrides:
        scenario = scenario.with_overrides(**overrides)
    scene = load_scene(scenario)
    if scene.network.pruned and progress:
        print(f"hydroplant: not built (connected to no cylinder or motor): {', '.join(scene.network.pruned)}", file=sys.stderr)
    plant = make_plant(scene)
    guard = check_plant(plant)  # load-time stability guards: warn, never fail
    if progress:
        for text in guard.warnings:
            print(f"hydroplant: warning: {text}", file=sys.stderr)
    log_path = Path(out) if out is not None else default_log_path(scenario)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    attachments = [
        ("scenario.toml", "application/toml", scenario.path.read_bytes()),
        ("circuit.toml", "application/toml", scenario.circuit.read_bytes()),
        (scenario.mjcf.name, "application/xml", scenario.mjcf.read_bytes()),
    ]
    steps = scenario.step_count
    every = scenario.log_every
    status, message = "complete", ""
    net = plant.network
    peak = np.array(plant.net_state.node_pressure)
    low = peak.copy()
    start = _time.perf_counter()
    last_progress = start
    with LogWriter(log_path, dt=scenario.dt, run_metadata=run_metadata(scenario), attachments=attachments, overwrite=overwrite) as log:
        recorder = RunRecorder(log, plant)
        for text in guard.warnings:
            recorder.event(0, LogLevel.WARNING, "stability guard: " + text)
        sample = recorder.sample(0)
        for n in range(steps):
            report = plant.step()
            p = plant.net_state.node_pressure
            if not report.success or not plant.finite():
                component = _failed_component(plant, report)
                status = "diverged"
                message = f"t = {plant.time:.6g} s, {component}: {report.message or 'non-finite state'}"
                recorder.sample(plant.step_index)
                recorder.event(plant.step_index, LogLevel.ERROR, "diverged: " + message)
                log.mark("diverged", time_s=repr(plant.time), component=component, message=message)
                break
            np.maximum(peak, p, out=peak)
            np.minimum(low, p, out=low)
            if plant.step_index % every == 0 or n == steps - 1:
                sample = recorder.sample(plant.step_index)
                gained = sample["kinetic"] + sample["potential"] + sample["oil"] - plant.energy.initial_total
                allowed = ENERGY_GROWTH_LIMIT * (abs(plant.energy.initial_total) + plant.energy.pump_work) + ENERGY_GROWTH_FLOOR
                if plant.coupling.name != "incompressible" and gained > allowed:  # (no energy terms without oil)
                    status = "diverged"
                    message = (
                        f"t = {plant.time:.6g} s, energy growth: the machine gained {gained:.4g} J, more than the "
                        f"{plant.energy.pump_work:.4g} J of pump work allows; the coupling is unstable at this step size"
                    )
                    recorder.event(plant.step_index, LogLevel.ERROR, "diverged: " + message)
                    log.mark("diverged", time_s=repr(plant.time), component="coupling (energy growth)", message=message)
                    break
            if progress:
                now = _time.perf_counter()
                if now - start > PROGRESS_AFTER and now - last_progress > 0.5:
                    last_progress = now
                    print(f"\r  {plant.time:8.3f} / {scenario.duration:g} s simulated", end="", file=sys.stderr, flush=True)
        if status == "complete":
            log.mark("complete")
        wall = _time.perf_counter() - start
    if progress and wall > PROGRESS_AFTER:
        print(file=sys.stderr)
    e = plant.energy
    dissipated = e.dissipated_hydraulic + e.dissipated_friction + e.dissipated_mechanical
    total = sample["kinetic"] + sample["potential"] + sample["oil"]
    q, _ = plant.joint_state()
    strokes = {net.actuator_names[a]: float(plant.net_state.actuator_position[a]) for a in net.cylinder_actuator}
    return RunResult(
        scenario=scenario,
        log_path=log_path,
        status=status,
        message=message,
        simulated_time=plant.time,
        wall_time=wall,
        steps=plant.step_index,
        peak_pressure={n: float(v) for n, v in zip(net.node_names, peak) if not net.node_fixed[net.node_names.index(n)]},
        min_pressure={n: float(v) for n, v in zip(net.node_names, low) if not net.node_fixed[net.node_names.index(n)]},
        final_joints=dict(zip(plant.joint_names, map(float, q))),
        final_strokes=strokes,
        energy={
            "pump_work": e.pump_work,
            "delta": total - e.initial_total,
            "dissipated": dissipated,
            "residual": sample["residual"],
            "relative": sample["residual"] / e.pump_work if e.pump_work else 0.0,
        },
    )


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
