"""Stability maps: run a scenario at the extremes, per method, and classify every run.

``hydroplant stability SCENARIO | --example NAME [--quick] [--out DIR] [--scheduler ADDR] [--json] ...`` builds a
grid of *configurations* (scenario variants) × step sizes × methods, runs every
point through :func:`sim.run.runner.run`, and classifies each run as

``stable-accurate``
    finished, pressures inside the physical bounds, and within ``tolerance``
    of a fine reference of the same configuration;
``stable-inaccurate``
    finished and physical, but further than ``tolerance`` from the reference;
``diverged``
    the runner stopped it (NaN/inf, failed hydraulic step, energy growth), or a
    node pressure left [cavitation floor (−ceiling without one), ceiling × ``PRESSURE_BOUND_MARGIN``],
    the ceiling being the highest of relief cracking + full-flow override, the
    initial pressure and the reference's peak, plus the spike of a moving load
    trapped by a closing valve (:func:`variant_info`); the time and the
    component of the failure are recorded.

Configurations (each written as modified copies of the circuit, MJCF and
scenario files into ``OUT/variants/<id>/``; ``models/`` is never touched):

* ``beta=<β>``: fluid bulk modulus (explicitly given initial pressures keep
  their compression (p − p_ref)/β, so a closed chamber keeps its oil content);
* ``mass=<s>``: every body's mass and inertia and every joint's armature × s;
* ``dead=<V>``: every cylinder's cap and rod dead volume = V;
* ``event=valve_slam``: ideal spools (τ = 0), every valve commanded 0 → +1 in
  one step at 0.1·D and back to 0 at 0.5·D;
* ``event=pump_start``: valves centred (closed centre), pumps 0 → nominal speed
  in one step at 0.1·D;
* ``event=end_stop``: every limited cylinder starts ``v_full·0.3·D`` short of its
  extended end stop moving at ``v_full`` (all pump flow through its cap area), valves +1;
* ``event=cavitation``: pumps stopped, every valve opened in one step at 0.1·D
  in the direction the load pulls (the supply side is closed, the growing
  chamber cavitates).

The parameter configurations use the valve slam as their excitation when the
scene has valves (the scenario's own inputs otherwise).  D, the configuration
duration, is ``PERIODS`` periods of the fastest oil column of the nominal scene
(:mod:`sim.run.guards`), clipped to [``duration_min``, ``duration_max``]; a run is cut at
``max_steps`` steps (``pbd_max_steps`` in the PBD modes; flagged ``truncated``) and
lengthened to ``min_steps`` steps.
Runs go through the block-stepping runner; the pressure bounds are checked on the
per-step extremes it reports (``RunResult.extremes_every_step``), and a run whose
extremes cover only the logged samples is repeated step by step (``run(..., fast=False)``).
The reference of a configuration is the implicit MuJoCo run at
dt_ref = clip(``REFERENCE_OMEGA_DT``/ω_h, 1e-5 s, 1e-3 s) of that configuration.
The error is the larger of the maximum deviation of actuator positions
(relative to the reference's range, at least 1 % of the stroke) and the RMS
deviation of node pressures (relative to the reference's range, at least 1 % of
the pressure ceiling) at the run's logged samples inside the reference window; a
run with fewer than ``MIN_COMPARED_SAMPLES`` steps in that window is inaccurate.

Outputs in ``OUT``: ``stability.csv`` (one row per run), ``stability-<method>.png``
(heat maps of dt against each swept quantity), ``summary.txt`` (the stability
boundary per method).  The runs go through :func:`sim.tools.sweep.run_sweep` (process
pool, or Dask with ``--scheduler``), cached in ``OUT/cache`` (keyed on the point, the hash of the hydraulics/ and sim/ source and
the contents of the variant files) so an interrupted map resumes.  On Dask the variants' files travel to the
workers as content (:func:`sim.tools.sweep.scene_bundle`); a run that cannot be made has its error text in
the ``error`` column, in ``summary.txt`` and in the ``--json`` document (and is not cached).

Exit status: 0 when no run diverged or failed, 4 when the map is written but some did (a map that reaches
the explicit coupling's limit exits 4 by design), 2 for bad input.  Methods are named as in :mod:`sim.methods`
(``mujoco:implicit``; file names ``stability-<scene>-mujoco-implicit.png``).
"""

from __future__ import annotations

import argparse
import csv
import importlib
import json
import math
import os
import re
import shutil
import sys
import time as _time
import tomllib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from hydraulics.extras import require
from sim.io.scenario import ScenarioError, load_scenario

# --------------------------------------------------------------------------- constants
CLASS_ACCURATE = "stable-accurate"
CLASS_INACCURATE = "stable-inaccurate"
CLASS_DIVERGED = "diverged"
CLASSES = (CLASS_ACCURATE, CLASS_INACCURATE, CLASS_DIVERGED)

PERIODS = 3.0  # periods of the fastest nominal oil column in a configuration's duration
REFERENCE_OMEGA_DT = 0.05  # ω_h·dt of the reference run (20 steps per radian)
REFERENCE_DT_RANGE = (1e-5, 1e-4)  # s: clip of the reference step (valve and relief transients need ≤ 1e-4 s)
REFERENCE_MAX_STEPS = 20000  # a reference longer than this is shortened (and flagged)
PRESSURE_BOUND_MARGIN = 1.25  # [-] on the physical pressure ceiling
POSITION_ERROR_FLOOR = 0.01  # of the stroke (cylinders) / rad (motors): smallest range an error is relative to
PRESSURE_ERROR_FLOOR = 0.01  # of the pressure ceiling
MOTOR_ANGLE_FLOOR = 1.0  # rad: smallest motor-shaft range an error is relative to
MIN_COMPARED_SAMPLES = 3  # logged samples after t = 0 inside the reference window needed to call a run accurate
SAMPLES_PER_RUN = 400  # logged samples over a configuration's duration
EVENT_START = 0.1  # of D: when events fire
SLAM_CLOSE = 0.5  # of D: when the slammed valves close again
END_STOP_HIT = 0.3  # of D: when the end-stop event reaches the stop at full speed
STEP_EDGE = 1e-9  # s: width of a one-step input change in a schedule

METHODS = {
    "mujoco:implicit": ("mujoco", "implicit", False),
    "mujoco:explicit": ("mujoco", "explicit", False),
    "mujoco:rosenbrock": ("mujoco", "rosenbrock", False),
    "pbd:implicit": ("pbd", "implicit", False),
    "pbd:rosenbrock+blend": ("pbd", "rosenbrock", True),  # (on request)
    "pbd-naive": ("pbd-naive", "implicit", False),
}
"""Method name (:mod:`sim.methods`) → (mode, coupling, PBD mode's θ-rule ``pbd_blend``); ``--methods`` takes any
other method name as well."""
REFERENCE_METHOD = "mujoco:implicit"


def method_settings(name: str) -> tuple:
    """(mode, coupling, pbd_blend) of a method name (:func:`sim.methods.parse_method`)."""
    if name in METHODS:
        return METHODS[name]
    from sim.methods import MethodError, parse_method

    try:
        m = parse_method(name)
    except MethodError as exc:
        raise StabilityError(f"--methods: {exc}") from None
    return m.mode, m.coupling, m.blend


def method_file_label(name: str) -> str:
    """A method's name where ``:`` and ``+`` may not stand (file names): ``mujoco-implicit``."""
    return name.replace(":", "-").replace("+", "-")
EVENTS = ("valve_slam", "pump_start", "end_stop", "cavitation")
SWEEPS = ("beta", "mass", "dead", "event")


@dataclass(frozen=True)
class Grid:
    """What a stability map sweeps; see the module docstring."""

    dts: tuple = (1e-5, 1e-4, 3e-4, 1e-3, 3e-3, 1.0 / 120.0, 1.0 / 60.0, 1.0 / 30.0)
    """Physics steps [s]."""
    bulk_moduli: tuple = (1e8, 1e9, 1e10)
    """Fluid bulk moduli [Pa]."""
    mass_scales: tuple = (0.01, 100.0)
    """Factors on every body's mass and inertia [-]."""
    dead_volumes: tuple = (1e-7,)
    """Cylinder dead volumes [m³]."""
    events: tuple = EVENTS
    sweeps: tuple = SWEEPS
    methods: tuple | None = None
    """Method labels (default: every available method)."""
    duration_min: float = 0.05  # s
    duration_max: float = 0.3  # s
    max_steps: int = 5000
    """Steps after which a run is cut (flagged ``truncated``)."""
    pbd_max_steps: int = 5000
    """The same for the PBD modes (compiled XPBD, 20 substeps per step: 4–6 ms per step, 7–13 ms in pbd-naive)."""
    min_steps: int = 20
    tolerance: float = 0.05
    """Largest relative error of a ``stable-accurate`` run [-]."""


DEFAULT_GRID = Grid()
QUICK_GRID = Grid(
    dts=(1e-4, 1e-3, 1.0 / 30.0), bulk_moduli=(1e8, 1e10), mass_scales=(0.01, 100.0), dead_volumes=(1e-7,),
    duration_min=0.03, duration_max=0.1, max_steps=600, pbd_max_steps=60, min_steps=10,
)


class StabilityError(ScenarioError):
    """A stability map cannot be built for this input (names the file or option)."""


# --------------------------------------------------------------------------- TOML text
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _toml_string(text: str) -> str:
    """A TOML basic string (JSON escapes, plus DEL, which TOML does not allow raw)."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _toml_key(key) -> str:
    key = str(key)
    return key if _BARE_KEY.fullmatch(key) else _toml_string(key)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()) + " }" if value else "{}"
    raise TypeError(f"cannot write {type(value).__name__} {value!r} as TOML")


def dump_toml(data: dict) -> str:
    """TOML text of a document made of tables, arrays of tables, strings, numbers, booleans and arrays.

    The inverse of ``tomllib.loads`` for the documents hydroplant reads
    (non-finite floats are written as ``inf``/``nan``).
    """
    lines: list[str] = []

    def table(prefix, body):
        scalars = {k: v for k, v in body.items() if not _is_table(v) and not _is_table_array(v)}
        for k, v in scalars.items():
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
        for k, v in body.items():
            name = f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k)
            if _is_table(v):
                lines.append("")
                lines.append(f"[{name}]")
                table(name, v)
            elif _is_table_array(v):
                for item in v:
                    lines.append("")
                    lines.append(f"[[{name}]]")
                    table(name, item)

    table("", data)
    return "\n".join(lines).lstrip("\n") + "\n"


def _is_table(value) -> bool:
    return isinstance(value, dict)


def _is_table_array(value) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


# --------------------------------------------------------------------------- scene facts
@dataclass(frozen=True)
class SceneFacts:
    """What the grid needs to know about the base scenario (JSON-friendly)."""

    scenario: str
    scene: str
    mjcf: str
    circuit: str
    valves: tuple
    pumps: dict  # pump name -> nominal speed [rev/s]
    cylinders: tuple
    motors: tuple
    limited_cylinders: tuple  # cylinders whose tendon has an end stop
    pull_sign: dict  # valve-driven actuator name -> -1/+1: direction the load pulls
    valve_actuator: dict  # valve name -> actuator name it drives (or "")
    valve_low: dict  # valve name -> its lowest command [-] (-1 for a 4/3 valve, 0 for a variable orifice)
    full_flow: float  # m³/s: delivery of all pumps at nominal speed
    full_speed: dict  # cylinder -> v_full [m/s] (all pump flow through the cap area)
    stroke: dict  # cylinder -> stroke [m]
    bulk_modulus: float
    reference_pressure: float
    cavitation_pressure: float | None
    pressure_ceiling: float  # Pa: max(relief + override, initial max) of the base scene, before margin
    omega_h_max: float  # rad/s at the nominal initial state
    duration: float  # s: the configuration duration D

    @property
    def default_event(self) -> str:
        return "valve_slam" if self.valves else "none"


def relief_ceiling(network) -> float:
    """Highest pressure [Pa] a relief lets a node reach: outlet + cracking + full pump flow / gradient (0 without reliefs)."""
    s = network.relief_branches
    if s.stop == s.start:
        return 0.0
    flow = float(np.sum(network.pump_displacement * network.pump_nominal_speed[network.pump_index] * network.pump_efficiency)) if len(network.pump_names) else 0.0
    outlet = np.where(network.node_fixed[network.branch_to[s]], network.node_fixed_pressure[network.branch_to[s]], network.fluid.reference_pressure)
    return float(np.max(outlet + network.relief_cracking + flow / network.relief_gradient))


def scene_facts(scenario_path, grid: Grid = DEFAULT_GRID) -> SceneFacts:
    """Load the base scenario once and collect what the variants need."""
    from sim.run.guards import check
    from sim.plants.mujoco import MujocoPlant
    from sim.io.scene import load_scene

    scenario = load_scenario(scenario_path)
    probe = scenario.with_overrides(mode="mujoco", coupling="implicit")
    if probe.fidelity == "incompressible":
        raise StabilityError(f"{scenario.path}, field 'run.fidelity': the stability map needs oil-column states; 'incompressible' has none (use 'compressible' or 'lines')")
    scene = load_scene(probe)
    plant = MujocoPlant(scene)
    net = scene.network
    m = scene.mjmodel
    holding = plant.holding_efforts()
    cylinders = tuple(net.actuator_names[a] for a in net.cylinder_actuator)
    motors = tuple(net.actuator_names[a] for a in net.motor_actuator)
    limited = tuple(
        name for i, name in enumerate(net.actuator_names)
        if scene.binding.tendon_id[i] >= 0 and bool(m.tendon_limited[scene.binding.tendon_id[i]])
    )
    flow = float(np.sum(net.pump_displacement * net.pump_nominal_speed[net.pump_index] * net.pump_efficiency)) if len(net.pump_names) else 0.0
    full_speed = {name: flow / float(net.cylinder_cap_area[i]) for i, name in enumerate(cylinders)}
    stroke = {name: float(net.cylinder_stroke[i]) for i, name in enumerate(cylinders)}
    valve_actuator = {}
    for v, valve in enumerate(net.valve_names):
        work_nodes = {net.branch_to[b] for b in range(len(net.orifice_valve)) if net.orifice_valve[b] == v and net.orifice_sign[b] != 0}
        work_nodes |= {net.branch_from[b] for b in range(len(net.orifice_valve)) if net.orifice_valve[b] == v and net.orifice_sign[b] != 0}
        driven = ""
        for i, a in enumerate(net.cylinder_actuator):
            if net.cylinder_cap_node[i] in work_nodes:
                driven = net.actuator_names[a]
        for i, a in enumerate(net.motor_actuator):
            if net.motor_a_node[i] in work_nodes:
                driven = net.actuator_names[a]
        valve_actuator[valve] = driven
    # the load pulls against the holding effort: a positive holding force means it pulls the cylinder in
    pull_sign = {name: (-1 if holding[a] > 0 else 1) for a, name in enumerate(net.actuator_names)}
    initial_max = float(np.max(np.where(net.node_fixed, -np.inf, plant.net_state.node_pressure), initial=0.0))
    ceiling = max(relief_ceiling(net), initial_max)
    report = check(scene, plant.net_state)
    omega = max((r.omega_h for r in report.rows), default=0.0)
    duration = grid.duration_max if omega <= 0 else float(np.clip(PERIODS * 2.0 * math.pi / omega, grid.duration_min, grid.duration_max))
    fluid = net.fluid
    return SceneFacts(
        scenario=str(scenario.path), scene=scenario.scene_name, mjcf=str(scenario.mjcf), circuit=str(scenario.circuit),
        valves=tuple(net.valve_names), pumps={p: float(net.pump_nominal_speed[i]) for i, p in enumerate(net.pump_names)},
        cylinders=cylinders, motors=motors, limited_cylinders=tuple(c for c in limited if c in cylinders),
        pull_sign=pull_sign, valve_actuator=valve_actuator,
        valve_low=dict(zip(net.valve_names, net.valve_command_low.tolist())), full_flow=flow, full_speed=full_speed, stroke=stroke,
        bulk_modulus=fluid.bulk_modulus, reference_pressure=fluid.reference_pressure,
        cavitation_pressure=fluid.cavitation_pressure, pressure_ceiling=ceiling, omega_h_max=omega, duration=duration,
    )


def applicable_events(facts: SceneFacts) -> tuple:
    """Events the scene can stage: valves for slams and cavitation, pumps for the pump start, limited cylinders for end stops."""
    events = []
    if facts.valves:
        events.append("valve_slam")
    if facts.pumps:
        events.append("pump_start")
    if facts.limited_cylinders and facts.valves and facts.pumps:
        events.append("end_stop")
    if facts.valves and facts.pumps:
        events.append("cavitation")
    return tuple(events)


# --------------------------------------------------------------------------- configurations
@dataclass(frozen=True)
class Config:
    """One scenario variant: which quantity is changed and the excitation."""

    sweep: str  # "nominal", "beta", "mass", "dead", "event"
    value: object = None  # β [Pa], scale [-], V [m³] or event name
    event: str = "none"
    bulk_modulus: float | None = None
    mass_scale: float = 1.0
    dead_volume: float | None = None

    @property
    def id(self) -> str:
        if self.sweep == "nominal":
            return f"nominal-{self.event}"
        if self.sweep == "event":
            return f"event-{self.event}"
        return f"{self.sweep}-{self.value:.3g}-{self.event}"


def grid_configs(facts: SceneFacts, grid: Grid) -> list[Config]:
    """Configurations of a map (duplicates removed; the nominal one first)."""
    excite = facts.default_event
    configs = [Config("nominal", None, excite)]
    if "beta" in grid.sweeps:
        configs += [Config("beta", b, excite, bulk_modulus=b) for b in grid.bulk_moduli]
    if "mass" in grid.sweeps:
        configs += [Config("mass", s, excite, mass_scale=s) for s in grid.mass_scales]
    if "dead" in grid.sweeps and facts.cylinders:
        configs += [Config("dead", v, excite, dead_volume=v) for v in grid.dead_volumes]
    if "event" in grid.sweeps:
        for e in grid.events:
            if e in applicable_events(facts) and e != excite:
                configs.append(Config("event", e, e))
    return configs


def _scale_floats(text: str, factor: float) -> str:
    return " ".join(repr(float(v) * factor) for v in text.split())


def scale_mjcf_masses(source: Path, target: Path, factor: float) -> None:
    """Write ``source`` MJCF to ``target`` with every mass, inertia, density and armature × ``factor``.

    Relative asset paths (compiler dirs, includes) are rewritten relative to the
    target's folder (unchanged when it is the source's), so the copy names the same
    files; raises StabilityError when the compiled mass of the moving bodies does not
    scale by ``factor`` (masses the edit could not reach; bodies welded to the world, a
    floor whose mass MuJoCo infers from its geoms, are not counted: they move nothing).
    """
    import mujoco

    tree = ET.parse(source)
    root = tree.getroot()
    base = source.parent.resolve()
    here = Path(target).parent.resolve()

    def moved(value: str) -> str:
        return Path(os.path.relpath(base / value, here)).as_posix() if here != base else value

    compiler = root.find("compiler")
    if compiler is None:
        compiler = ET.Element("compiler")
        root.insert(0, compiler)
    for attr in ("meshdir", "texturedir", "assetdir"):
        value = compiler.get(attr)
        if value is not None and not os.path.isabs(value):
            compiler.set(attr, moved(value))
    if compiler.get("assetdir") is None and compiler.get("meshdir") is None and here != base:
        compiler.set("assetdir", moved("."))
    for include in root.iter("include"):
        if not os.path.isabs(include.get("file", "/")):
            include.set("file", moved(include.get("file")))
    for element in root.iter("inertial"):
        element.set("mass", repr(float(element.get("mass", "0")) * factor))
        for attr in ("diaginertia", "fullinertia"):
            if element.get(attr):
                element.set(attr, _scale_floats(element.get(attr), factor))
    for element in root.iter("geom"):
        for attr in ("mass", "density"):
            if element.get(attr):
                element.set(attr, repr(float(element.get(attr)) * factor))
    for element in root.iter("joint"):
        if element.get("armature"):
            element.set("armature", _scale_floats(element.get("armature"), factor))
    tree.write(target, encoding="unicode")
    try:
        before = mujoco.MjModel.from_xml_path(str(source))
        after = mujoco.MjModel.from_xml_path(str(target))
    except Exception as exc:
        raise StabilityError(f"{source}: the mass-scaled copy {target} does not compile: {exc}") from None
    moving = np.asarray(before.body_weldid) != 0  # (a body welded to the world moves nothing: its mass is left out)
    total_before, total_after = float(np.sum(before.body_mass[moving])), float(np.sum(after.body_mass[moving]))
    if not math.isclose(total_after, factor * total_before, rel_tol=1e-6):
        raise StabilityError(
            f"{source}: scaling masses by {factor:g} gave {total_after:g} kg of moving bodies instead of "
            f"{factor * total_before:g} kg (masses set through defaults or inferred from geoms without density are not "
            "reached)"
        )


def _schedule(knots) -> dict:
    """{t, value} of a piecewise-constant schedule given as [(t, value), ...] with one-step edges."""
    t, v = [], []
    for time_s, value in knots:
        if t and time_s <= t[-1]:
            time_s = t[-1] + STEP_EDGE
        t.append(float(time_s))
        v.append(float(value))
    return {"t": t, "value": v}


def _step(before, after, at) -> dict:
    """Schedule that changes from ``before`` to ``after`` in one step at time ``at``."""
    return _schedule([(0.0, before), (at - STEP_EDGE, before), (at, after)]) if at > STEP_EDGE else _schedule([(0.0, after)])


def end_stop_pose(scene, facts: SceneFacts, gap_time: float):
    """qpos, qvel (dicts by joint name) that put every limited cylinder v_full·gap_time short of its extended stop, moving at v_full.

    Gauss–Newton on the cylinder extensions together with the MJCF's equality constraints
    (loop closures, :func:`sim.plants.constraints.equality_rows`), so the pose and the
    velocities stay on the closed loops.
    """
    import mujoco

    from sim.plants.constraints import actuator_moments, equality_rows
    from sim.io.scene import initial_qpos_qvel

    m = scene.mjmodel
    net = scene.network
    d = mujoco.MjData(m)
    qpos, _ = initial_qpos_qvel(scene)
    d.qpos[:] = qpos
    ids = scene.binding.actuator_id
    rows = [a for a, name in enumerate(net.actuator_names) if name in facts.limited_cylinders]
    target = np.array([facts.stroke[net.actuator_names[a]] - facts.full_speed[net.actuator_names[a]] * gap_time for a in rows])
    target = np.maximum(target, 0.5 * np.array([facts.stroke[net.actuator_names[a]] for a in rows]))
    for _ in range(30):
        mujoco.mj_forward(m, d)
        x = d.actuator_length[ids[rows]] - scene.binding.closed_length[rows]
        J = actuator_moments(m, d, ids)[rows]
        G, violation, _ = equality_rows(m, d)
        error = target - x
        if max(np.max(np.abs(error), initial=0.0), np.max(np.abs(violation), initial=0.0)) < 1e-9:
            break
        step = np.linalg.lstsq(np.vstack([J, G]), np.r_[error, -violation], rcond=None)[0]
        mujoco.mj_integratePos(m, d.qpos, step, 1.0)
    mujoco.mj_forward(m, d)
    J = actuator_moments(m, d, ids)[rows]
    G, _, _ = equality_rows(m, d)
    speed = np.array([facts.full_speed[net.actuator_names[a]] for a in rows])
    qvel = np.linalg.lstsq(np.vstack([J, G]), np.r_[speed, np.zeros(len(G))], rcond=None)[0] if len(rows) else np.zeros(m.nv)
    names_q, names_v = {}, {}
    for j in range(m.njnt):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        if name and int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            names_q[name] = float(d.qpos[m.jnt_qposadr[j]])
            names_v[name] = float(qvel[m.jnt_dofadr[j]])
    return names_q, names_v


def copy_model(mjcf, directory) -> Path:
    """Copy an MJCF with its includes and assets (:func:`sim.io.scene.mjcf_files`) below ``directory``, keeping
    their layout relative to each other; returns the copy of the MJCF."""
    from sim.io.scene import mjcf_files

    files = mjcf_files(mjcf)
    root = Path(os.path.commonpath([str(f.path.parent) for f in files]))
    for f in files:
        target = Path(directory) / f.path.relative_to(root)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(f.data)
    return Path(directory) / files[0].path.relative_to(root)


def write_variant(facts: SceneFacts, config: Config, directory) -> Path:
    """Write the circuit, MJCF (with its includes and assets, in ``model/``) and scenario of ``config`` into
    ``directory``; returns the scenario path.

    The folder is self-contained: the scenario names its files relative to itself, so it can be moved or
    shipped to a Dask worker as content (:func:`sim.tools.sweep.scene_bundle`).
    """
    directory = Path(directory).resolve()
    directory.mkdir(parents=True, exist_ok=True)
    base = Path(facts.scenario)
    scenario = tomllib.loads(base.read_text())
    circuit = tomllib.loads(Path(facts.circuit).read_text())
    D = facts.duration
    fluid = circuit.setdefault("fluid", {})
    if config.bulk_modulus is not None:
        fluid["bulk_modulus"] = float(config.bulk_modulus)
        initial = scenario.get("initial", {})
        if initial.get("equilibrium", True) is False and initial.get("pressures"):
            # keep the compression (p − p_ref)/β of explicitly given pressures: same oil content
            ratio = config.bulk_modulus / facts.bulk_modulus
            ref = facts.reference_pressure
            initial["pressures"] = {k: ref + (float(v) - ref) * ratio for k, v in initial["pressures"].items()}
    from hydraulics.components import VALVE_KINDS  # noqa: PLC0415  (the tool's start-up imports no kernel module)

    for component in circuit.get("component", []):
        if component.get("type") == "cylinder" and config.dead_volume is not None:
            component["dead_volume_cap"] = float(config.dead_volume)
            component["dead_volume_rod"] = float(config.dead_volume)
        if component.get("type") in VALVE_KINDS and config.event == "valve_slam":
            component["time_constant"] = 0.0
    circuit_path = directory / Path(facts.circuit).name
    circuit_path.write_text(dump_toml(circuit))
    mjcf_path = copy_model(facts.mjcf, directory / "model")
    if config.mass_scale != 1.0:
        scaled = mjcf_path.with_name(f"{mjcf_path.stem}-mass{mjcf_path.suffix}")  # next to the copy: same relative paths
        scale_mjcf_masses(mjcf_path, scaled, config.mass_scale)
        mjcf_path = scaled
    scenario["scene"] = {"mjcf": mjcf_path.relative_to(directory).as_posix(), "circuit": circuit_path.name}
    if "inputs_csv" in scenario:
        csv_source = (base.parent / scenario["inputs_csv"]).resolve()
        (directory / csv_source.name).write_bytes(csv_source.read_bytes())
        scenario["inputs_csv"] = csv_source.name
    inputs = scenario.get("inputs", {})
    at = EVENT_START * D
    if config.event == "valve_slam":
        inputs = {name: _step(0.0, speed, 0.0) for name, speed in facts.pumps.items()}
        for valve in facts.valves:
            inputs[valve] = _schedule([(0.0, 0.0), (at - STEP_EDGE, 0.0), (at, 1.0), (SLAM_CLOSE * D - STEP_EDGE, 1.0), (SLAM_CLOSE * D, 0.0)])
    elif config.event == "pump_start":
        inputs = {name: _step(0.0, speed, at) for name, speed in facts.pumps.items()}
        inputs.update({valve: _schedule([(0.0, 0.0)]) for valve in facts.valves})
    elif config.event == "end_stop":
        inputs = {name: _schedule([(0.0, speed)]) for name, speed in facts.pumps.items()}
        inputs.update({valve: _schedule([(0.0, 1.0)]) for valve in facts.valves})
    elif config.event == "cavitation":
        inputs = {name: _schedule([(0.0, 0.0)]) for name in facts.pumps}
        for valve in facts.valves:
            sign = max(facts.pull_sign.get(facts.valve_actuator.get(valve, ""), -1), facts.valve_low[valve])
            inputs[valve] = _step(0.0, float(sign), at)
    if config.event != "none":
        scenario.pop("inputs_csv", None)
    scenario["inputs"] = inputs
    if config.event == "end_stop":
        from sim.io.scene import load_scene

        probe = directory / "probe.scenario.toml"
        probe.write_text(dump_toml(scenario))
        try:
            scene = load_scene(load_scenario(probe))
        finally:
            probe.unlink()
        qpos, qvel = end_stop_pose(scene, facts, END_STOP_HIT * D)
        initial = scenario.setdefault("initial", {})
        initial["qpos"] = qpos
        initial["qvel"] = qvel
    scenario.setdefault("log", {})
    path = directory / f"{config.id}.scenario.toml"
    path.write_text(dump_toml(scenario))
    return path


# --------------------------------------------------------------------------- one run
def run_point(point: dict) -> dict:
    """Run one grid point (a JSON dict, see :func:`build_points`) and return its JSON result.

    Top-level and picklable for process pools and Dask.  Never raises for a
    diverging run; an exception inside the run is reported as ``error``.
    """
    import tempfile

    with tempfile.TemporaryDirectory(prefix="hydroplant-stability-") as tmp:
        return _run_point(point, _log_path(point, Path(tmp)))


def _log_path(point: dict, tmp: Path) -> Path:
    """Where a point's log goes: ``log_dir / log`` (the map's folder on this machine), an absolute ``log`` as it
    is, otherwise a temporary folder (a Dask worker: the log is read there and not kept)."""
    log = Path(point["log"])
    if point.get("log_dir") is not None or log.is_absolute():
        return Path(point.get("log_dir") or "") / log
    return tmp / log.name


def _run_point(point: dict, log_path: Path) -> dict:
    from sim.io.mcap_log import read_log
    from sim.run.runner import run
    from sim.tools.sweep import point_file

    out = dict(point)
    scenario = point_file(point)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    overrides = {"mode": point["mode"], "coupling": point["coupling"], "dt": point["dt"], "duration": point["duration"],
                 "log_rate_hz": point["log_rate_hz"], "pbd_blend": point.get("pbd_blend") or None,
                 "pbd_substeps": point.get("pbd_substeps"),  # (None: the scenario's)
                 "monitor": False}  # the map classifies every run by its own bounds (classify); the monitor only warns
    start = _time.perf_counter()
    try:
        result = run(scenario, out=log_path, overrides=overrides, progress=False, overwrite=True)
        if not result.extremes_every_step:
            # the block-stepping runner only saw the pressures at its log samples (a plant without
            # per-step extremes): the bounds check needs every step, so repeat the run step by step
            result = run(scenario, out=log_path, overrides=overrides, progress=False, fast=False, overwrite=True)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # a crash is a result of the map, not of the tool
        out.update(status="error", message=f"{type(exc).__name__}: {exc}", steps=0, simulated_time=0.0,
                   wall_time=_time.perf_counter() - start, samples=None, peak_pressure={}, min_pressure={})
        return out
    out.update(
        status=result.status, message=result.message, steps=result.steps, simulated_time=result.simulated_time,
        wall_time=result.wall_time, peak_pressure=result.peak_pressure, min_pressure=result.min_pressure,
        energy_relative_residual=_finite_or_none(result.energy.get("relative")),
        extremes_every_step=bool(result.extremes_every_step),
    )
    out["samples"] = _samples(read_log(log_path), point["actuators"])
    if not point.get("keep_log"):
        log_path.unlink(missing_ok=True)
    return out


def _finite_or_none(value):
    return float(value) if value is not None and math.isfinite(value) else None


def _samples(log, actuators) -> dict:
    """Logged time [s], actuator positions and node pressures as JSON lists (non-finite → None)."""
    samples = {"t": None, "x": {}, "p": {}}
    for name, kind in actuators:
        topic = f"/hydroplant/cylinders/{name}" if kind == "cylinder" else f"/hydroplant/motors/{name}"
        data = log.topic(topic)
        samples["t"] = (data.log_time / 1e9).tolist()
        samples["x"][name] = [_finite_or_none(v) for v in data["position_m" if kind == "cylinder" else "angle_rad"]]
    nodes = log.topic("/hydroplant/nodes")
    for key in nodes.fields if hasattr(nodes, "fields") else _numeric_fields(nodes):
        if key.startswith("pressure_pa."):
            samples["p"][key.removeprefix("pressure_pa.")] = [_finite_or_none(v) for v in nodes[key]]
    if samples["t"] is None:
        samples["t"] = (nodes.log_time / 1e9).tolist()
    return samples


def _numeric_fields(topic) -> list:
    return sorted(topic.messages[0].keys()) if topic.messages else []


# --------------------------------------------------------------------------- the grid
def method_labels(grid: Grid) -> tuple:
    """Methods to map: the grid's, or every available one (PBD when sim.plants.pbd imports)."""
    if grid.methods:
        from sim.methods import MethodError, parse_method

        try:
            return tuple(parse_method(m).name for m in grid.methods)
        except MethodError as exc:
            raise StabilityError(f"--methods: {exc}; e.g. {', '.join(METHODS)}") from None
    from sim.methods import default_methods

    return default_methods(pbd_available())


def pbd_available() -> bool:
    try:
        importlib.import_module("sim.plants.pbd")
    except Exception:
        return False
    return True


def reference_dt(omega_h: float) -> float:
    """Step of a configuration's reference run: REFERENCE_OMEGA_DT/ω_h clipped to REFERENCE_DT_RANGE."""
    low, high = REFERENCE_DT_RANGE
    return high if omega_h <= 0 else float(np.clip(REFERENCE_OMEGA_DT / omega_h, low, high))


def variant_info(scenario_path, full_flow: float) -> dict:
    """ω_h max [rad/s], the (name, kind) actuators and the pressure ceiling [Pa] of a variant at its initial state.

    The ceiling is max(relief + full-flow override, initial pressure) plus the
    largest trapped-load spike √(2·E·β_eff/V) over the actuator chambers, with E
    the kinetic energy of the actuator's inertia at the speed the full pump
    flow gives through its smaller area (a moving load stopped by a closing valve).
    """
    from sim.run.guards import check
    from sim.plants.mujoco import MujocoPlant
    from sim.io.scene import load_scene

    scenario = load_scenario(scenario_path).with_overrides(mode="mujoco", coupling="implicit")
    scene = load_scene(scenario)
    plant = MujocoPlant(scene)
    net = scene.network
    report = check(scene, plant.net_state)
    state = plant.net_state
    free = ~net.node_fixed
    initial_max = float(np.max(np.where(free, state.node_pressure, -np.inf), initial=0.0))
    beta = net.effective_bulk_modulus(state.node_pressure, state.actuator_position)
    volume, _ = net.node_volume_at(state.actuator_position, state.node_pressure)
    base = max(relief_ceiling(net), initial_max)
    ceilings = {net.node_names[n]: base for n in np.flatnonzero(free)}
    rows = {r.actuator: r for r in report.rows}

    def add_spike(actuator, speed, nodes):
        energy = 0.5 * rows[actuator].effective_mass * speed**2
        for node in nodes:
            if free[node] and math.isfinite(energy):
                name = net.node_names[node]
                ceilings[name] = max(ceilings[name], base + math.sqrt(2.0 * energy * beta[node] / volume[node]))

    for i, a in enumerate(net.cylinder_actuator):
        add_spike(net.actuator_names[a], full_flow / float(net.cylinder_rod_area[i]), (net.cylinder_cap_node[i], net.cylinder_rod_node[i]))
    for i, a in enumerate(net.motor_actuator):
        add_spike(net.actuator_names[a], full_flow * 2.0 * math.pi / float(net.motor_displacement[i]), (net.motor_a_node[i], net.motor_b_node[i]))
    return {
        "omega_h": max((r.omega_h for r in report.rows), default=0.0),
        "actuators": [(r.actuator, r.kind) for r in report.rows],
        "pressure_ceiling": max(ceilings.values(), default=base),
        "node_ceilings": ceilings,
    }


def build_points(facts: SceneFacts, grid: Grid, out_dir) -> tuple[list, list, list]:
    """Write every variant and return (points, configs-with-metadata, bundles); each point is a JSON dict for
    :func:`run_point` naming its variant's files by a :class:`~sim.tools.sweep.Bundle` (``bundle``, ``scenario``)
    and its log relative to ``out_dir`` (``log``)."""
    out_dir = Path(out_dir)
    methods = method_labels(grid)
    points, configs = [], []
    D = facts.duration
    rate = SAMPLES_PER_RUN / D
    from sim.tools.sweep import code_hash, scene_bundle

    code = code_hash()
    bundles = []  # cached runs are reused only with the same hydraulics/ and sim/ source
    for config in grid_configs(facts, grid):
        path = write_variant(facts, config, out_dir / "variants" / config.id)

        info = variant_info(path, facts.full_flow)
        omega, actuators = info["omega_h"], info["actuators"]
        dt_ref = reference_dt(omega)
        ref_duration = min(D, REFERENCE_MAX_STEPS * dt_ref)
        configs.append({"config": config.id, "sweep": config.sweep, "value": config.value, "event": config.event,
                        "scenario": str(path), "omega_h": omega, "reference_dt": dt_ref, "pressure_ceiling": info["pressure_ceiling"]})
        bundle, rel = scene_bundle(path)
        bundles.append(bundle)
        common = {"config": config.id, "sweep": config.sweep, "value": config.value, "event": config.event,
                  "scenario": rel, "bundle": bundle.digest, "omega_h": omega, "actuators": actuators, "log_rate_hz": rate,
                  "pressure_ceiling": info["pressure_ceiling"], "node_ceilings": info["node_ceilings"], "code": code}
        ref = dict(common, method=REFERENCE_METHOD, mode="mujoco", coupling="implicit", dt=dt_ref, duration=ref_duration,
                   reference=True, truncated=ref_duration < D, log=f"logs/{config.id}-reference.mcap")
        points.append(ref)
        for label in methods:
            mode, coupling, blend = method_settings(label)
            for dt in grid.dts:
                steps = int(round(D / dt))
                duration = D
                cap = grid.pbd_max_steps if mode in ("pbd", "pbd-naive") else grid.max_steps
                if steps > cap:
                    duration = cap * dt
                elif steps < grid.min_steps:
                    duration = grid.min_steps * dt
                same = label == REFERENCE_METHOD and math.isclose(dt, dt_ref) and math.isclose(duration, ref_duration)
                points.append(dict(common, method=label, mode=mode, coupling=coupling, pbd_blend=blend, dt=float(dt),
                                   duration=float(duration),
                                   reference=False, truncated=duration < D * (1 - 1e-9), same_as_reference=same,
                                   log=f"logs/{config.id}-{method_file_label(label)}-{dt:.3g}.mcap"))
    return points, configs, bundles


# --------------------------------------------------------------------------- classification
def _series(samples, group, name):
    values = samples[group].get(name)
    return None if values is None else np.array([np.nan if v is None else v for v in values], float)


def relative_error(result: dict, reference: dict, facts: SceneFacts, ceiling: float) -> tuple[float, float]:
    """(position error, pressure error) of ``result`` against ``reference`` at the run's logged samples, each relative (see module docstring)."""
    a, r = result.get("samples"), reference.get("samples")
    if not a or not r or not r["t"] or not a["t"]:
        return math.nan, math.nan
    t_ref = np.array(r["t"])
    t = np.array(a["t"])
    keep = t <= t_ref[-1] + 1e-12
    if not np.any(keep):
        return math.nan, math.nan
    t = t[keep]
    ex, ep = 0.0, 0.0
    for name, kind in result["actuators"]:
        x, x_ref = _series(a, "x", name)[keep], _series(r, "x", name)
        floor = POSITION_ERROR_FLOOR * facts.stroke[name] if kind == "cylinder" else MOTOR_ANGLE_FLOOR
        scale = max(float(np.nanmax(x_ref) - np.nanmin(x_ref)), floor)
        ex = max(ex, _deviation(x, np.interp(t, t_ref, x_ref)) / scale)
    from sim.run.recorder import field_name

    for node in reference.get("peak_pressure") or {}:  # free nodes only: tanks hold their pressure
        p, p_ref = _series(a, "p", field_name(node)), _series(r, "p", field_name(node))
        if p is None or p_ref is None:
            continue
        scale = max(float(np.nanmax(p_ref) - np.nanmin(p_ref)), PRESSURE_ERROR_FLOOR * ceiling)
        ep = max(ep, _rms_deviation(p[keep], np.interp(t, t_ref, p_ref)) / scale)
    return (ex if math.isfinite(ex) else math.inf), (ep if math.isfinite(ep) else math.inf)


def _deviation(a, b) -> float:
    """max |a − b|, infinite when either holds a non-finite value."""
    d = np.abs(a - b)
    return float(np.max(d, initial=0.0)) if np.all(np.isfinite(d)) else math.inf


def _rms_deviation(a, b) -> float:
    """RMS of a − b over the samples (pressure fronts shifted by a step would dominate a max norm), inf if non-finite."""
    d = a - b
    return float(np.sqrt(np.mean(d * d))) if len(d) and np.all(np.isfinite(d)) else (0.0 if not len(d) else math.inf)


def pressure_bounds(facts: SceneFacts, reference: dict | None, ceilings: dict | None = None) -> tuple[float, dict]:
    """Admissible node pressures of a configuration: (low [Pa], {node: high [Pa]}); see the module docstring.

    ``ceilings`` are the per-node ceilings of :func:`variant_info` (default: the
    base scene's single ceiling for every node the reference reports).
    """
    low = facts.cavitation_pressure if facts.cavitation_pressure is not None else -math.inf
    ok = reference is not None and reference.get("status") == "complete"
    peaks = reference["peak_pressure"] if ok else {}
    nodes = set(ceilings or {}) | set(peaks)
    high = {}
    for node in nodes:
        value = max((ceilings or {}).get(node, facts.pressure_ceiling), peaks.get(node, -math.inf))
        high[node] = value * PRESSURE_BOUND_MARGIN if math.isfinite(value) and value > 0 else math.inf
    if facts.cavitation_pressure is None:
        # no vapour floor (an idealised fluid): tension is bounded by the same energy as compression
        low = -max([v for v in high.values() if math.isfinite(v)] or [facts.pressure_ceiling * PRESSURE_BOUND_MARGIN])
    return low, high


_FAILURE = re.compile(r"t = ([-+0-9.eE]+) s, ([^:]+):")


def classify(result: dict, reference: dict | None, facts: SceneFacts, tolerance: float) -> dict:
    """Add ``class``, ``fail_time``, ``fail_component``, ``error_position``, ``error_pressure`` to a run result."""
    row = dict(result)
    low, highs = pressure_bounds(facts, reference, result.get("node_ceilings"))
    default_high = facts.pressure_ceiling * PRESSURE_BOUND_MARGIN if facts.pressure_ceiling > 0 else math.inf
    row.update(pressure_low=low, pressure_high=max(highs.values(), default=default_high), fail_time=None, fail_component="",
               error_position=None, error_pressure=None)
    if result["status"] in ("diverged", "error"):
        row["class"] = CLASS_DIVERGED
        match = _FAILURE.search(result.get("message", ""))
        if match:
            row["fail_time"], row["fail_component"] = float(match.group(1)), match.group(2).strip()
        else:
            row["fail_component"] = "run error" if result["status"] == "error" else ""
        return row
    peak, least = result.get("peak_pressure") or {}, result.get("min_pressure") or {}
    bad = [(n, p, highs.get(n, default_high)) for n, p in peak.items() if not (p <= highs.get(n, default_high))]
    bad += [(n, p, highs.get(n, default_high)) for n, p in least.items() if not (p >= low - 1.0)]
    if bad:
        node, value, high = bad[0]
        row["class"] = CLASS_DIVERGED
        row["fail_component"] = f"node {node}"
        row["fail_time"] = _first_exceedance(result, node, low, high)
        row["message"] = (f"pressure of node '{node}' reached {value:.4g} Pa, outside the physical bounds "
                          f"[{low:.4g}, {high:.4g}] Pa" + ("" if row["fail_time"] is not None else " between the logged samples"))
        return row
    if reference is None or reference.get("status") != "complete":
        row["class"] = CLASS_INACCURATE
        row["message"] = (row.get("message") or "") + " (no valid reference)"
        return row
    compared = [t for t in (result.get("samples") or {}).get("t") or [] if 0.0 < t <= reference["simulated_time"] + 1e-12]
    if len(compared) < MIN_COMPARED_SAMPLES:
        row["class"] = CLASS_INACCURATE
        row["message"] = (f"dt too coarse for the configuration: {len(compared)} step(s) inside the {reference['simulated_time']:.4g} s "
                          f"the reference covers (at least {MIN_COMPARED_SAMPLES} needed to call it accurate)")
        return row
    ceiling = row["pressure_high"] / PRESSURE_BOUND_MARGIN if math.isfinite(row["pressure_high"]) else 1e7
    ex, ep = relative_error(result, reference, facts, ceiling)
    row["error_position"], row["error_pressure"] = _finite_or_none(ex), _finite_or_none(ep)
    row["class"] = CLASS_ACCURATE if max(ex, ep) <= tolerance else CLASS_INACCURATE
    return row


def _first_exceedance(result, node, low, high):
    from sim.run.recorder import field_name

    samples = result.get("samples")
    if not samples or field_name(node) not in samples["p"]:
        return None
    p = _series(samples, "p", field_name(node))
    bad = np.flatnonzero(~((p >= low - 1.0) & (p <= high)))
    return float(samples["t"][bad[0]]) if len(bad) else None


# --------------------------------------------------------------------------- the map
@dataclass
class StabilityMap:
    """Classified runs of one scenario (``rows``) with the facts and grid that made them."""

    facts: SceneFacts
    grid: Grid
    rows: list
    configs: list
    out_dir: Path | None = None
    files: dict = field(default_factory=dict)

    def methods(self) -> list:
        """The methods mapped, in the order of the rows."""
        return list(dict.fromkeys(r["method"] for r in self.rows if not r["reference"]))

    def cell(self, method, config_id, dt) -> dict | None:
        for r in self.rows:
            if r["method"] == method and r["config"] == config_id and not r["reference"] and math.isclose(r["dt"], dt):
                return r
        return None

    def boundaries(self) -> dict:
        """Per method and configuration: the largest dt up to which every run is stable, the first diverged dt, ω_h·dt at both."""
        out = {}
        for method in self.methods():
            per = {}
            for c in self.configs:
                cells = sorted((r for r in self.rows if r["method"] == method and r["config"] == c["config"] and not r["reference"]),
                               key=lambda r: r["dt"])
                stable, first_bad, accurate = None, None, None
                for r in cells:
                    if r["class"] == CLASS_DIVERGED:
                        first_bad = r
                        break
                    stable = r
                    if r["class"] == CLASS_ACCURATE:
                        accurate = r
                per[c["config"]] = {
                    "omega_h": c["omega_h"],
                    "max_stable_dt": stable["dt"] if stable else None,
                    "max_accurate_dt": accurate["dt"] if accurate else None,
                    "first_diverged_dt": first_bad["dt"] if first_bad else None,
                    "first_diverged_omega_dt": c["omega_h"] * first_bad["dt"] if first_bad else None,
                    "max_stable_omega_dt": c["omega_h"] * stable["dt"] if stable else None,
                    "failure": (f"t = {first_bad['fail_time']:.4g} s, {first_bad['fail_component']}"
                                if first_bad and first_bad["fail_time"] is not None else (first_bad or {}).get("fail_component", "")),
                }
            out[method] = per
        return out

    def summary(self) -> str:
        """Text summary of the stability boundary per method."""
        lines = [f"stability map of {self.facts.scene}/{Path(self.facts.scenario).name}",  # no absolute path in the docs
                 f"scene {self.facts.scene}; configuration duration {self.facts.duration:.4g} s; "
                 f"nominal omega_h max {self.facts.omega_h_max:.4g} rad/s; tolerance {self.grid.tolerance:g}; "
                 f"dt {', '.join(f'{d:.3g}' for d in self.grid.dts)} s"]
        counts = {}
        for r in self.rows:
            if not r["reference"]:
                counts.setdefault(r["method"], {c: 0 for c in CLASSES})[r["class"]] += 1
        for method, per in self.boundaries().items():
            c = counts.get(method, {})
            lines.append("")
            lines.append(f"{method}: {c.get(CLASS_ACCURATE, 0)} stable-accurate, {c.get(CLASS_INACCURATE, 0)} stable-inaccurate, "
                         f"{c.get(CLASS_DIVERGED, 0)} diverged")
            runs = [r for r in self.rows if r["method"] == method and not r["reference"]]
            stable_w = [r["omega_h"] * r["dt"] for r in runs if r["class"] != CLASS_DIVERGED]
            bad_w = [r["omega_h"] * r["dt"] for r in runs if r["class"] == CLASS_DIVERGED]
            below = [w for w in stable_w if not bad_w or w < min(bad_w)]
            lines.append(
                f"  smallest diverged omega_h*dt: {min(bad_w):.3g}" if bad_w else "  no divergence on the grid"
            )
            lines[-1] += f"; largest stable omega_h*dt: {max(stable_w):.3g}" if stable_w else "; no stable run"
            if bad_w and below:
                lines[-1] += f" (all runs below {min(bad_w):.3g} are stable; largest of them {max(below):.3g})"
            for config, v in per.items():
                fmt = lambda x: "-" if x is None else f"{x:.3g}"  # noqa: E731
                lines.append(
                    f"  {config:<28s} omega_h {v['omega_h']:9.4g} rad/s  stable dt <= {fmt(v['max_stable_dt']):>8s} s "
                    f"(omega_h*dt {fmt(v['max_stable_omega_dt']):>7s})  accurate dt <= {fmt(v['max_accurate_dt']):>8s} s  "
                    f"diverged from {fmt(v['first_diverged_dt']):>8s} s {v['failure']}"
                )
        errors = [r for r in self.rows if r.get("status") == "error"]
        if errors:
            lines += ["", f"runs that could not be made ({len(errors)}; counted as diverged above):"]
            lines += [f"  {r['method']} {r['config']} dt {r['dt']:.3g} s: {run_error(r)}" for r in errors]
        return "\n".join(lines)


CSV_COLUMNS = (
    "method", "mode", "coupling", "config", "sweep", "value", "event", "dt", "omega_h", "omega_h_dt", "duration", "truncated",
    "class", "status", "fail_time", "fail_component", "error_position", "error_pressure", "pressure_low", "pressure_high",
    "peak_pressure_max", "min_pressure_min", "extremes_every_step", "steps", "simulated_time", "wall_time", "energy_relative_residual", "message", "reference",
    "error",
)


def write_csv(stability_map: StabilityMap, path) -> None:
    """One row per run (references included, ``reference`` = True)."""
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for r in stability_map.rows:
            row = dict(r)
            row["omega_h_dt"] = r["omega_h"] * r["dt"]
            row["peak_pressure_max"] = max((r.get("peak_pressure") or {}).values(), default="")
            row["min_pressure_min"] = min((r.get("min_pressure") or {}).values(), default="")
            row["message"] = (r.get("message") or "").replace("\n", " ")
            row["error"] = run_error(r)
            writer.writerow(row)


def run_error(row: dict) -> str:
    """The one-line error of a run that could not be made (exception type and message), or ``""``."""
    return " ".join(str(row.get("message") or "error (no message)").split()) if row.get("status") == "error" else ""


CLASS_COLOURS = {CLASS_ACCURATE: "#4caf50", CLASS_INACCURATE: "#ffc107", CLASS_DIVERGED: "#e53935"}
PANEL_TITLES = {"beta": "bulk modulus [Pa]", "mass": "mass scale [-]", "dead": "dead volume [m³]", "event": "event"}


def plot_maps(stability_map: StabilityMap, out_dir) -> dict:
    """One PNG per method: a heat map of dt (columns) against each swept quantity (rows); returns {method: path}."""
    matplotlib = require("matplotlib", "tools", "drawing the stability maps")

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    out_dir = Path(out_dir)
    files = {}
    dts = sorted(stability_map.grid.dts)
    panels = []
    for sweep in ("beta", "mass", "dead", "event"):
        rows = [c for c in stability_map.configs if c["sweep"] == sweep]
        if sweep == "event":
            rows = [c for c in stability_map.configs if c["sweep"] in ("nominal", "event")]
        if rows:
            panels.append((sweep, rows))
    cmap = ListedColormap(["#bdbdbd", CLASS_COLOURS[CLASS_ACCURATE], CLASS_COLOURS[CLASS_INACCURATE], CLASS_COLOURS[CLASS_DIVERGED]])
    code = {None: 0, CLASS_ACCURATE: 1, CLASS_INACCURATE: 2, CLASS_DIVERGED: 3}
    for method in stability_map.methods():
        heights = [max(len(rows), 1) + 1.2 for _, rows in panels]
        fig, axes = plt.subplots(len(panels), 1, figsize=(7.5, 0.42 * sum(heights) + 0.9), squeeze=False,
                                 gridspec_kw={"height_ratios": heights})
        for ax, (sweep, rows) in zip(axes[:, 0], panels):
            grid = np.zeros((len(rows), len(dts)))
            for i, c in enumerate(rows):
                for j, dt in enumerate(dts):
                    r = stability_map.cell(method, c["config"], dt)
                    grid[i, j] = code[r["class"] if r else None]
                    if r:
                        label = f"{c['omega_h'] * dt:.2g}" + ("*" if r.get("truncated") else "")
                        ax.text(j, i, label, ha="center", va="center", fontsize=7)
            ax.imshow(grid, cmap=cmap, vmin=0, vmax=3, aspect="auto")
            ax.set_xticks(range(len(dts)), [f"{d:.3g}" for d in dts], fontsize=7)
            labels = [(f"{c['value']:.3g}" if sweep != "event" else (c["event"] if c["sweep"] == "event" else f"{c['event']} (nominal)")) for c in rows]
            ax.set_yticks(range(len(rows)), labels, fontsize=7)
            ax.set_ylabel(PANEL_TITLES[sweep], fontsize=8)
        axes[-1, 0].set_xlabel("dt [s]   (cell text: omega_h*dt; * = truncated run)", fontsize=8)
        axes[0, 0].set_title(f"{stability_map.facts.scene}: {method}", fontsize=9)
        fig.legend(handles=[Patch(color=CLASS_COLOURS[k], label=k) for k in CLASSES], loc="lower center", ncol=3, fontsize=7,
                   frameon=False)
        fig.tight_layout(rect=(0, 0.04, 1, 1))
        path = out_dir / f"stability-{stability_map.facts.scene}-{method_file_label(method)}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        files[method] = path
    return files


def warm_up_points(points: list[dict]) -> None:
    """A few untimed steps of every method among ``points`` on the first variant, in this process (on each Dask
    worker before the map: imports and kernel compilation charged to no run). Failures are left to the points."""
    import tempfile

    from sim.run.runner import run
    from sim.tools.sweep import point_file

    done = set()
    with tempfile.TemporaryDirectory(prefix="hydroplant-warm-up-") as tmp:
        for point in points:
            key = (point["mode"], point["coupling"], bool(point.get("pbd_blend")))
            if key in done:
                continue
            done.add(key)
            overrides = {"mode": point["mode"], "coupling": point["coupling"], "dt": point["dt"],
                         "duration": min(point["duration"], 5 * point["dt"]), "pbd_blend": point.get("pbd_blend") or None,
                         "pbd_substeps": point.get("pbd_substeps"), "monitor": False}
            try:
                run(point_file(point), out=Path(tmp) / "warm-up.mcap", overrides=overrides, progress=False, overwrite=True)
            except Exception:  # noqa: BLE001 -- the point itself reports it
                continue


def stability_map(scenario, *, grid: Grid = DEFAULT_GRID, out_dir=None, scheduler=None, workers=None,
                  keep_logs: bool = False, progress: bool = False, write: bool = True,
                  worker_timeout: float | None = None) -> StabilityMap:
    """Build, run and classify a stability map of ``scenario``; write CSV, figures and summary into ``out_dir``.

    With a Dask ``scheduler`` every variant's files travel to the workers as content, each worker first runs
    :func:`warm_up_points`, and ``worker_timeout`` [s] bounds the wait for a first worker; the runs' logs stay
    on the workers (``keep_logs`` needs the local pool).
    """
    from sim.tools.sweep import WORKER_TIMEOUT

    if keep_logs and scheduler is not None:
        raise StabilityError("--keep-logs: the logs of runs on Dask workers are not kept; run without --scheduler to keep them")
    scenario_path = Path(scenario)
    facts = scene_facts(scenario_path, grid)
    if out_dir is None:
        out_dir = Path("logs") / f"stability-{facts.scene}-{scenario_path.name.removesuffix('.toml').removesuffix('.scenario')}"
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    points, configs, bundles = build_points(facts, grid, out_dir)
    for p in points:
        p["keep_log"] = keep_logs
    if progress:
        print(f"hydroplant stability: {len(points)} runs ({len(configs)} configurations x {len(grid.dts)} dt x "
              f"{len(method_labels(grid))} methods + references) into {out_dir}", file=sys.stderr)
    start = _time.perf_counter()
    todo = [p for p in points if not p.get("same_as_reference")]
    from sim.tools.sweep import run_sweep

    from sim.progress import Progress

    report = Progress(len(todo), "hydroplant stability", "runs") if progress else None
    results = run_sweep(run_point, todo, scheduler=scheduler, workers=workers, cache_dir=out_dir / "cache", progress=report,
                        bundles=bundles, context={"log_dir": str(out_dir)} if scheduler is None else None,
                        worker_timeout=worker_timeout or WORKER_TIMEOUT, warm_up=warm_up_points)
    refs = {r["config"]: r for r in results if r["reference"]}
    # a grid point identical to its reference (implicit at dt_ref) is not run twice
    results += [dict(refs[p["config"]], **{k: p[k] for k in ("method", "reference", "truncated", "log")}) for p in points if p.get("same_as_reference")]
    rows = [classify(r, refs.get(r["config"]), facts, grid.tolerance) for r in results]
    for row in rows:
        row["error"] = run_error(row)  # the text of a run that could not be made, "" otherwise
    result = StabilityMap(facts, grid, rows, configs, out_dir)
    if write:
        write_csv(result, out_dir / "stability.csv")
        result.files = plot_maps(result, out_dir)
        (out_dir / "summary.txt").write_text(result.summary() + "\n")
        if not keep_logs:
            shutil.rmtree(out_dir / "logs", ignore_errors=True)
    if progress:
        print(f"hydroplant stability: done in {_time.perf_counter() - start:.1f} s", file=sys.stderr)
    return result


# --------------------------------------------------------------------------- CLI
def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``hydroplant stability`` (declared in :func:`sim.commands.add_stability`)."""
    from sim.commands import add_stability

    return add_stability(subparsers)


def failed_runs(stability_map: StabilityMap) -> list:
    """The rows of runs that diverged or failed (``status`` error), references included."""
    return [r for r in stability_map.rows if r["class"] == CLASS_DIVERGED or r.get("status") == "error"]


def result_json(stability_map: StabilityMap, exit_code: int) -> dict:
    """``stability --json``: the document of docs/cli-json.md."""
    counts = {}
    for r in stability_map.rows:
        if not r["reference"]:
            counts.setdefault(r["method"], {c: 0 for c in CLASSES})[r["class"]] += 1
    failed = failed_runs(stability_map)
    out_dir = stability_map.out_dir
    keys = ("method", "mode", "coupling", "config", "sweep", "value", "event", "dt", "omega_h", "duration", "truncated",
            "reference", "class", "status", "fail_time", "fail_component", "message", "error", "error_position",
            "error_pressure", "wall_time")
    return {
        "command": "stability", "status": "partial" if failed else "ok", "exit_code": exit_code,
        "scene": stability_map.facts.scene, "scenario": str(stability_map.facts.scenario),
        "out_dir": str(out_dir) if out_dir else None,
        "csv": str(out_dir / "stability.csv") if out_dir else None,
        "summary": str(out_dir / "summary.txt") if out_dir else None,
        "figures": {m: str(p) for m, p in stability_map.files.items()},
        "tolerance": stability_map.grid.tolerance, "dts_s": list(stability_map.grid.dts),
        "methods": {m: {"counts": counts.get(m, {}), "boundaries": b} for m, b in stability_map.boundaries().items()},
        "runs": [dict({k: r.get(k) for k in keys}, error=run_error(r)) for r in stability_map.rows],
        "diverged": sum(1 for r in failed if r["class"] == CLASS_DIVERGED and r.get("status") != "error"),
        "errors": sum(1 for r in failed if r.get("status") == "error"),
    }


def main(args) -> int:
    """``hydroplant stability``; returns the exit status: 0 no run diverged or failed, 4 some did (the map is
    written), 2 bad input (ScenarioError)."""
    from sim.cli import EXIT_OK, EXIT_PARTIAL, scenario_argument

    scenario = scenario_argument(args, "stability")
    as_json = getattr(args, "json", False)
    text = sys.stderr if as_json else sys.stdout
    if args.check:
        from sim.run.guards import check_scenario

        print(check_scenario(scenario).table(), file=text)
        if as_json:
            from sim.jsonout import emit

            emit({"command": "stability", "status": "ok", "exit_code": EXIT_OK, "scenario": str(scenario),
                  "check_only": True})
        return EXIT_OK
    require("matplotlib", "tools", "hydroplant stability")  # before any run: its maps are drawn at the end
    grid = QUICK_GRID if args.quick else DEFAULT_GRID
    changes = {}
    if args.dt:
        if any(d > 1.0 for d in args.dt):
            raise StabilityError(f"--dt: {max(args.dt)!r} is not in (0, 1] s")
        changes["dts"] = tuple(sorted(args.dt))
    if args.methods:
        changes["methods"] = args.methods
    if args.sweeps:
        changes["sweeps"] = args.sweeps
    if args.tolerance:
        changes["tolerance"] = args.tolerance
    grid = replace(grid, **changes)
    if not Path(scenario).is_file():
        raise ScenarioError(f"{scenario}: scenario file not found")
    if args.scheduler is not None:
        from sim.tools.sweep import WORKER_TIMEOUT, check_scheduler, check_workers

        if not args.scheduler.startswith(("tcp://", "tls://", "inproc://", "ucx://")):
            raise StabilityError(f"--scheduler: {args.scheduler!r} is not a scheduler address like tcp://host:8786")
        if args.keep_logs:
            raise StabilityError("--keep-logs: the logs of runs on Dask workers are not kept; run without --scheduler to keep them")
        check_scheduler(args.scheduler)  # one line now, not after the variants are built
        check_workers(args.scheduler, args.worker_timeout or WORKER_TIMEOUT)
    result = stability_map(scenario, grid=grid, out_dir=args.out, scheduler=args.scheduler, workers=args.workers,
                           keep_logs=args.keep_logs, progress=True, worker_timeout=args.worker_timeout)
    failed = failed_runs(result)
    code = EXIT_PARTIAL if failed else EXIT_OK
    print(result.summary(), file=text)
    print(f"\ncsv      {result.out_dir / 'stability.csv'}", file=text)
    for method, path in result.files.items():
        print(f"figure   {path}", file=text)
    print(f"summary  {result.out_dir / 'summary.txt'}", file=text)
    if failed:
        errors = sum(1 for r in failed if r.get("status") == "error")
        print(f"hydroplant stability: {len(failed)} of {len(result.rows)} runs diverged or failed ({errors} with an "
              "error); exit status 4", file=sys.stderr)
    if as_json:
        from sim.jsonout import emit

        emit(result_json(result, code))
    return code


__all__ = [
    "CLASSES", "CLASS_ACCURATE", "CLASS_DIVERGED", "CLASS_INACCURATE", "Config", "DEFAULT_GRID", "Grid", "METHODS",
    "QUICK_GRID", "SceneFacts", "StabilityError", "StabilityMap", "add_parser", "build_points", "classify", "copy_model",
    "dump_toml", "main", "run_error", "run_point", "scene_facts", "stability_map", "warm_up_points", "write_variant",
]
