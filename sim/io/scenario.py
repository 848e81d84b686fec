"""Scenario files: which scene, which run settings, which operator inputs.

A scenario (TOML) names the MJCF and the circuit (paths relative to the
scenario file), the mode and coupling, the step size and duration, the
initial state, the operator inputs as piecewise-linear schedules (or a CSV
file), and the log settings.  :func:`load_scenario` validates everything and
raises :class:`ScenarioError` naming the file, the field and the allowed range.

Example::

    [scene]
    mjcf = "boom.xml"
    circuit = "boom.circuit.toml"
    [run]
    mode = "mujoco"            # mujoco | pbd
    coupling = "rosenbrock"    # rosenbrock (default) | implicit | implicit-linear | explicit (the first and third: one hydraulic substep; in PBD mode per XPBD substep)
    dt = 0.001                 # s
    duration = 6.0             # s
    [initial]
    qpos = { boom_hinge = 0.2 }
    equilibrium = true
    [inputs]
    boom_valve = { t = [0.0, 1.0, 1.3], value = [0.0, 0.0, 1.0] }
    [log]
    rate_hz = 100

Fidelity (see :data:`hydraulics.network.FIDELITIES`) is the scene's default level,
``[run] fidelity`` or ``[fidelity] default``, overridable per cylinder or motor::

    [fidelity]
    default = "compressible"
    boom_cyl = "lines"         # this cylinder's hoses as pi-lines, the others lumped

Levels mix freely: ``incompressible`` actuators among compressible ones become rigid actuators
of the compressible network (:class:`hydraulics.coupling.CouplingMixed`).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from hydraulics.circuit import read_toml
from hydraulics.components import COMPONENT_TYPES
from hydraulics.files import check_regular, read_text, resolve
from hydraulics.network import FIDELITIES

from sim.io.errors import ScenarioError
from sim.methods import COUPLINGS, DEFAULT_COUPLING, MODES, NAIVE
from sim.live.mapping import parse_mapping

LINEAR_COUPLINGS = ("implicit-linear", "rosenbrock")  # one linearly implicit step per plant step (PBD: per substep)
STEPPER_NAMES = ("implicit_euler", "explicit_euler", "reference")
DEFAULT_BASE_PRESSURE = 1.0e6  # Pa absolute: the low side of a loaded cylinder at t = 0
DT_RANGE = (1e-9, 1.0)  # s, [low, high]: 1 ns is the resolution of the log's timestamps
DURATION_MAX = 1e6  # s
RATE_RANGE = (1e-6, 1e9)  # Hz, [low, high] for [log] rate_hz and tf_rate_hz (above 1/dt: every step)
VALVE_COMMAND_RANGE = (-1.0, 1.0)  # [-]: spool command, -1 and +1 fully open to either side, 0 centred


@dataclass(frozen=True)
class Schedule:
    """Piecewise-linear input u(t), held constant outside its knots."""

    t: np.ndarray  # s, strictly increasing
    value: np.ndarray

    def __call__(self, time: float) -> float:
        return float(np.interp(time, self.t, self.value))


@dataclass(frozen=True)
class Scenario:
    """A validated scenario (all paths absolute, all quantities SI)."""

    path: Path
    mjcf: Path
    circuit: Path
    mode: str = "mujoco"
    coupling: str = DEFAULT_COUPLING
    stepper: str | None = None
    dt: float = 1e-3
    duration: float = 1.0
    hydraulic_substeps: int = 1
    pbd_substeps: int = 20
    pbd_iterations: int = 1
    pbd_blend: bool = False  # PBD mode: blend each row's pressure force by θ = blend_factor (as MuJoCo mode); False: θ = 1
    fidelity: str = "compressible"
    actuator_fidelity: dict = field(default_factory=dict)  # actuator name -> level overriding `fidelity`
    qpos: dict = field(default_factory=dict)
    qvel: dict = field(default_factory=dict)
    equilibrium: bool = True
    start_contacts: str = "exclude"  # [initial] start_contacts: contacts of the start pose in the equilibrium or not
    base_pressure: float = DEFAULT_BASE_PRESSURE
    pressures: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)
    log_rate_hz: float = 100.0
    tf_rate_hz: float = 100.0  # [log] tf_rate_hz: /tf (Foxglove's 3D view) at most this often [Hz]
    log_dir: Path | None = None
    inputs_csv: Path | None = None  # the inputs CSV file the schedules were read from, if any
    monitor: bool = True  # [monitor] enabled: a run beyond the plausibility bounds stops (sim.run.monitor); False: warns
    mapping: object = None  # [mapping]: device axes -> valve commands for `hydroplant play` (sim.live.mapping.Mapping)
    controllers: dict = field(default_factory=dict)  # [controllers.NAME]: name -> PidSpec (inputs driven by feedback)

    @property
    def name(self) -> str:
        """Scenario name: the file name without ``.scenario.toml``."""
        return self.path.name.removesuffix(".toml").removesuffix(".scenario")

    @property
    def fidelity_label(self) -> str:
        """The default level and its per-actuator overrides, e.g. ``compressible (boom_cyl: lines)``."""
        overrides = {k: v for k, v in self.actuator_fidelity.items() if v != self.fidelity}
        if not overrides:
            return self.fidelity
        return f"{self.fidelity} (" + ", ".join(f"{k}: {v}" for k, v in sorted(overrides.items())) + ")"

    @property
    def scene_name(self) -> str:
        return self.path.parent.name

    @property
    def step_count(self) -> int:
        return int(round(self.duration / self.dt))

    @property
    def log_every(self) -> int:
        """Physics steps between logged samples (≥ 1)."""
        return max(1, int(round(1.0 / (self.log_rate_hz * self.dt))))

    @property
    def tf_every(self) -> int:
        """Physics steps between ``/tf`` samples: the multiple of :attr:`log_every` nearest to one period of
        ``tf_rate_hz``, at least ``log_every`` (``/tf`` is a view of the joints, which take every sample; a 3D
        panel redraws at ≈ 60 Hz, so ``/tf`` at 1 kHz would be a quarter of an every-step log's bytes for nothing)."""
        return self.log_every * max(1, int(round(1.0 / (self.tf_rate_hz * self.dt * self.log_every))))

    def with_overrides(self, **changes) -> "Scenario":
        """A copy with some run settings replaced (None values are ignored) and re-validated."""
        changes = {k: v for k, v in changes.items() if v is not None}
        if "compiled" in changes:
            _error(f"{self.path} (override)", COMPILED_KEY_MESSAGE)
        new = replace(self, **changes)
        _validate_run(new, f"{self.path} (command-line override)")
        return new


COMPILED_KEY_MESSAGE = (
    "field 'run.compiled': the kernels always run compiled, there is no other path to select; remove the field "
    "(to run the same kernels as plain Python for debugging, set the environment variable NUMBA_DISABLE_JIT=1)")


def _error(where, message):
    raise ScenarioError(f"{where}: {message}")


def _number(table, key, where, *, low=None, high=None, low_open=True, default=None, integer=False):
    if key not in table:
        if default is None:
            _error(where, f"missing field '{key}'")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        _error(where, f"field '{key}': expected a number, got {value!r}")
    try:
        value = float(value)
    except OverflowError:
        value = math.inf  # rejected as out of range below
    ok = math.isfinite(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if integer and ok:
        ok = value == int(value)
    if not ok:
        left = "(" if low_open else "["
        kind = "an integer" if integer else "a number"
        _error(where, f"field '{key}': {value!r} is not {kind} in {left}{low if low is not None else '-inf'}, {high if high is not None else 'inf'}]")
    return int(value) if integer else value


START_CONTACTS = ("exclude", "include")
"""``[initial] start_contacts``: whether the contacts MuJoCo finds at the start pose carry load in the equilibrium start
and in ``check`` (``exclude``: the machine is balanced as if they were not there, as by hand statics)."""


def _choice(table, key, where, choices, default):
    value = table.get(key, default)
    if value not in choices and value is not None:
        _error(where, f"field '{key}': {value!r} is not one of {list(choices)}")
    return value


def _flag(table, key, where, default):
    value = table.get(key, default)
    if not isinstance(value, bool):
        _error(where, f"field '{key}': expected true or false, got {value!r}")
    return value


def _schedule(name, spec, where, *, field=None) -> Schedule:
    where = f"{where}, field '{field or 'inputs.' + name}'"
    if isinstance(spec, bool) or isinstance(spec, str):
        _error(where, f"expected a number or a table {{ t = [...], value = [...] }}, got {spec!r}")
    if isinstance(spec, (int, float)):
        spec = {"t": [0.0], "value": [spec]}
    if not isinstance(spec, dict) or set(spec) != {"t", "value"}:
        _error(where, "expected a table with exactly the keys 't' (s) and 'value'")
    for key in ("t", "value"):
        items = spec[key]
        if not isinstance(items, list) or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in items):
            _error(where, f"'{key}' must be an array of numbers (not true/false, strings or tables), got {items!r:.80}")
    try:
        t = np.array(spec["t"], dtype=float)
        value = np.array(spec["value"], dtype=float)
    except (TypeError, ValueError, OverflowError):
        _error(where, "'t' and 'value' must be arrays of finite numbers")
    if t.ndim != 1 or t.shape != value.shape or len(t) == 0:
        _error(where, f"'t' and 'value' must be non-empty arrays of equal length (got {t.shape} and {value.shape})")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(value))):
        _error(where, "NaN or inf in the schedule; every knot must be finite")
    if np.any(np.diff(t) <= 0):
        _error(where, "'t' must be strictly increasing")
    return Schedule(t, value)


CONTROLLER_TYPES = ("pid", "python")
SENSOR_KINDS = ("stroke", "speed", "joint", "joint_speed", "pressure", "flow", "pump_speed")  # hydraulics.controllers
ANTI_WINDUP = ("none", "clamp", "back_calculation")  # hydraulics.controllers.ANTI_WINDUP
GAIN_LIMIT = 1e12  # |kp|, |ki|, |kd| at most this (in output units per sensor unit)
DERIVATIVE_FILTER_MAX = 1e3  # s
TRACKING_TIME_MAX = 1e6  # s
CONTROL_RATE_RANGE = (1e-6, 1e9)  # Hz; above 1/dt: every step


@dataclass(frozen=True)
class PidSpec:
    """``[controllers.NAME]`` with ``type = "pid"`` (law: :mod:`hydraulics.controllers`), SI units.

    ``output``: the valve or pump input it drives; ``sensor``: ``(kind, name)`` from ``"KIND:NAME"``, kind one of
    :data:`SENSOR_KINDS`; ``setpoint``: a :class:`Schedule` in the sensor's unit; gains ``kp`` [out/unit],
    ``ki`` [out/(unit·s)], ``kd`` [out·s/unit]; ``derivative_filter`` T_f [s]; ``rate`` [Hz] (None: every step);
    ``low``/``high``: output limits (None: the input's range); ``anti_windup`` one of :data:`ANTI_WINDUP`;
    ``tracking_time`` T_t [s] of back-calculation (None: T_i = kp/ki, or the sample period without kp or ki)."""

    output: str
    sensor: tuple
    setpoint: Schedule
    kp: float = 0.0
    ki: float = 0.0
    kd: float = 0.0
    derivative_filter: float = 0.0
    rate: float | None = None
    low: float | None = None
    high: float | None = None
    anti_windup: str = "clamp"
    tracking_time: float | None = None


@dataclass(frozen=True)
class PythonSpec:
    """``[controllers.NAME]`` with ``type = "python"``: ``python = "module:function"``, a callable
    ``controller(t, sensors) -> commands`` (:mod:`sim.plants.controllers`), asked at ``rate`` [Hz] (None: every
    step) with the sensors ``sensors`` (``"KIND:NAME"`` strings) and allowed to set the inputs ``outputs``."""

    python: str
    sensors: tuple
    outputs: tuple
    rate: float | None = None


def _sensor(text, where, key="sensor"):
    if not isinstance(text, str) or ":" not in text:
        _error(where, f"field '{key}': expected \"KIND:NAME\" with KIND one of {list(SENSOR_KINDS)}, got {text!r}")
    kind, name = text.split(":", 1)
    if kind not in SENSOR_KINDS or not name:
        _error(where, f"field '{key}': {text!r}: KIND must be one of {list(SENSOR_KINDS)} and NAME non-empty")
    return kind, name


def _controllers(table, where, inputs) -> dict:
    """``[controllers.NAME]`` tables: name -> :class:`PidSpec` or :class:`PythonSpec`; an input driven by a
    controller cannot also have a schedule (``[inputs]``, ``inputs_csv``) nor a second controller."""
    if not isinstance(table, dict):
        _error(where, "[controllers] must hold tables [controllers.NAME] with type = 'pid' or 'python'")
    out, driven = {}, {}
    for name, spec in table.items():
        w = f"{where}, [controllers.{name}]"
        if not isinstance(spec, dict):
            _error(w, "expected a table with type = 'pid' or 'python'")
        kind = _choice(spec, "type", w, CONTROLLER_TYPES, None)
        if kind is None:
            _error(w, f"missing field 'type' (one of {list(CONTROLLER_TYPES)})")
        allowed = ({"type", "output", "sensor", "setpoint", "kp", "ki", "kd", "derivative_filter", "rate", "low", "high",
                    "anti_windup", "tracking_time"} if kind == "pid" else {"type", "python", "sensors", "outputs", "rate"})
        unknown = sorted(set(spec) - allowed)
        if unknown:
            _error(w, f"unknown field(s) {unknown} for type '{kind}'; allowed: {sorted(allowed)}")
        rate = _number(spec, "rate", w, low=CONTROL_RATE_RANGE[0], high=CONTROL_RATE_RANGE[1], low_open=False,
                       default=math.nan)
        rate = None if math.isnan(rate) else rate
        if kind == "python":
            target = spec.get("python")
            if not isinstance(target, str) or target.count(":") != 1 or not all(target.split(":")):
                _error(w, f"field 'python': expected \"module:function\", got {target!r}")
            sensors, outputs = spec.get("sensors", []), spec.get("outputs")
            if not isinstance(sensors, list):
                _error(w, "field 'sensors': expected an array of \"KIND:NAME\" strings")
            if not isinstance(outputs, list) or not outputs or not all(isinstance(o, str) for o in outputs):
                _error(w, "field 'outputs': expected a non-empty array of valve or pump names")
            spec_out = PythonSpec(target, tuple(":".join(_sensor(t, w, "sensors")) for t in sensors), tuple(outputs), rate)
            names = outputs
        else:
            output = spec.get("output")
            if not isinstance(output, str):
                _error(w, "field 'output': the name of the valve or pump it drives is required")
            if "setpoint" not in spec:
                _error(w, "missing field 'setpoint' (a number or { t = [...], value = [...] } in the sensor's unit)")
            setpoint = _schedule(name, spec["setpoint"], where, field=f"controllers.{name}.setpoint")
            gains = {k: _number(spec, k, w, low=-GAIN_LIMIT, high=GAIN_LIMIT, low_open=False, default=0.0)
                     for k in ("kp", "ki", "kd")}
            low = _number(spec, "low", w, low=-1e12, high=1e12, low_open=False, default=math.nan)
            high = _number(spec, "high", w, low=-1e12, high=1e12, low_open=False, default=math.nan)
            if not (math.isnan(low) or math.isnan(high)) and not low < high:
                _error(w, f"fields 'low', 'high': {low!r} must be below {high!r}")
            tracking = _number(spec, "tracking_time", w, low=0.0, high=TRACKING_TIME_MAX, default=math.nan)
            spec_out = PidSpec(
                output=output, sensor=_sensor(spec.get("sensor"), w), setpoint=setpoint, **gains,
                derivative_filter=_number(spec, "derivative_filter", w, low=0.0, high=DERIVATIVE_FILTER_MAX,
                                          low_open=False, default=0.0),
                rate=rate, low=None if math.isnan(low) else low, high=None if math.isnan(high) else high,
                anti_windup=_choice(spec, "anti_windup", w, ANTI_WINDUP, "clamp"),
                tracking_time=None if math.isnan(tracking) else tracking)
            names = [output]
        for input_name in names:
            if input_name in inputs:
                _error(w, f"input '{input_name}' is driven by this controller and also has a schedule ([inputs] or "
                          f"inputs_csv); give it one source")
            if input_name in driven:
                _error(w, f"input '{input_name}' is already driven by controller '{driven[input_name]}'")
            driven[input_name] = name
        out[name] = spec_out
    return out


def _csv_inputs(path: Path, where) -> dict:
    """Schedules from a CSV file whose first column is time [s] and whose header names the inputs."""
    text = read_text(path, "inputs CSV", ScenarioError)
    try:
        rows = [row for row in csv.reader(io.StringIO(text, newline="")) if row]
    except csv.Error as exc:
        _error(f"{path}", f"not a valid CSV file: {exc}")
    if len(rows) < 2 or rows[0][0].strip() != "t":
        _error(f"{path}", "a header row starting with 't' and at least one data row are required")
    header = [h.strip() for h in rows[0]]
    if any(len(row) != len(header) for row in rows[1:]):
        _error(f"{path}", f"every row needs {len(header)} columns, like the header")
    try:
        data = np.array([[float(x) for x in row] for row in rows[1:]], dtype=float)
    except ValueError as exc:
        _error(f"{path}", f"not a number: {exc}")
    return {name: _schedule(name, {"t": data[:, 0].tolist(), "value": data[:, i].tolist()}, str(path)) for i, name in enumerate(header) if i}


def _validate_run(s: Scenario, where):
    if s.mode not in MODES:
        _error(where, f"field 'run.mode': {s.mode!r} is not one of {list(MODES)}")
    if s.coupling not in COUPLINGS:
        _error(where, f"field 'run.coupling': {s.coupling!r} is not one of {list(COUPLINGS)}")
    if s.coupling in LINEAR_COUPLINGS and s.mode != NAIVE and s.hydraulic_substeps != 1:  # pbd-naive: always explicit
        _error(where, f"field 'run.coupling': {s.coupling!r} takes one hydraulic substep per step, so it needs "
                      f"hydraulic_substeps = 1 (got {s.hydraulic_substeps}; coupling = 'implicit' takes several)")
    if s.stepper is not None and s.stepper not in STEPPER_NAMES:
        _error(where, f"field 'run.stepper': {s.stepper!r} is not one of {list(STEPPER_NAMES)}")
    if not (isinstance(s.dt, (int, float)) and math.isfinite(s.dt) and DT_RANGE[0] <= s.dt <= DT_RANGE[1]):
        _error(where, f"field 'run.dt': {s.dt!r} is not in [{DT_RANGE[0]:g}, {DT_RANGE[1]:g}] s")
    if not (isinstance(s.duration, (int, float)) and math.isfinite(s.duration) and 0.0 < s.duration <= DURATION_MAX):
        _error(where, f"field 'run.duration': {s.duration!r} is not in (0, {DURATION_MAX:g}] s")
    if s.step_count < 1 or s.duration < s.dt * (1.0 - 1e-9):
        _error(where, f"field 'run.duration': {s.duration!r} s is shorter than one step (dt = {s.dt!r} s); "
                      f"the run would take no step; it must be in [dt, {DURATION_MAX:g}] s")
    for key in ("hydraulic_substeps", "pbd_substeps", "pbd_iterations"):
        value = getattr(s, key)
        if not (isinstance(value, int) and 1 <= value <= 100000):
            _error(where, f"field 'run.{key}': {value!r} is not an integer in [1, 100000]")
    if s.fidelity not in FIDELITIES:
        _error(where, f"field 'run.fidelity': {s.fidelity!r} is not one of {list(FIDELITIES)}")
    if not isinstance(s.actuator_fidelity, dict):
        _error(where, "field 'fidelity': expected a table of actuator name = level")
    for name, level in s.actuator_fidelity.items():
        if level not in FIDELITIES:
            _error(where, f"field 'fidelity.{name}': {level!r} is not one of {list(FIDELITIES)}")
    for key, value in (("rate_hz", s.log_rate_hz), ("tf_rate_hz", s.tf_rate_hz)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and RATE_RANGE[0] <= value <= RATE_RANGE[1]):
            _error(where, f"field 'log.{key}': {value!r} is not in [{RATE_RANGE[0]:g}, {RATE_RANGE[1]:g}] Hz")


def as_scenario(scenario, *, duration: float | None = None) -> Scenario:
    """``scenario`` itself, or the scenario loaded from that path; with ``duration`` [s] overridden when given."""
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if duration is not None:
        scenario = scenario.with_overrides(duration=duration)
    return scenario


def load_scenario(path) -> Scenario:
    """Read and validate a scenario file."""
    path = resolve(path, "scenario", ScenarioError)
    where = str(path)
    data = read_toml(path, "scenario", ScenarioError)
    allowed = {"scene", "run", "initial", "inputs", "inputs_csv", "log", "fidelity", "monitor", "mapping", "controllers"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        _error(where, f"unknown top-level key(s) {unknown}; allowed: {sorted(allowed)}")
    scene = data.get("scene")
    if not isinstance(scene, dict):
        _error(where, "missing table [scene] with 'mjcf' and 'circuit'")
    files = {}
    for key in ("mjcf", "circuit"):
        if not isinstance(scene.get(key), str):
            _error(where, f"field 'scene.{key}': a path relative to the scenario file is required")
        what = f"field 'scene.{key}' of {where}: {'MJCF' if key == 'mjcf' else 'circuit'}"
        files[key] = resolve(path.parent / scene[key], what, ScenarioError)
        check_regular(files[key], what, ScenarioError)
    run = data.get("run", {})
    initial = data.get("initial", {})
    log = data.get("log", {})
    for name, table in (("run", run), ("initial", initial), ("log", log)):
        if not isinstance(table, dict):
            _error(where, f"[{name}] must be a table")
    allowed_keys = {
        "scene": {"mjcf", "circuit"},
        "run": {"mode", "coupling", "stepper", "dt", "duration", "hydraulic_substeps", "pbd_substeps", "pbd_iterations",
                "pbd_blend", "fidelity"},
        "initial": {"qpos", "qvel", "equilibrium", "start_contacts", "base_pressure", "pressures"},
        "log": {"rate_hz", "tf_rate_hz"},
    }
    if "compiled" in run:
        _error(where, COMPILED_KEY_MESSAGE)
    for name, table in (("scene", scene), ("run", run), ("initial", initial), ("log", log)):
        unknown = sorted(set(table) - allowed_keys[name])
        if unknown:
            _error(where, f"unknown field(s) in [{name}]: {unknown}; allowed: {sorted(allowed_keys[name])}")
    w = f"{where}, [run]"
    dt = _number(run, "dt", w, low=DT_RANGE[0], high=DT_RANGE[1], low_open=False, default=1e-3)
    duration = _number(run, "duration", w, low=0.0, high=DURATION_MAX, default=1.0)

    def joint_table(key):
        table = initial.get(key, {})
        if not isinstance(table, dict):
            _error(where, f"field 'initial.{key}': expected a table of joint name = value")
        for name, value in table.items():
            _number(table, name, f"{where}, [initial.{key}]")
        return {k: float(v) for k, v in table.items()}

    pressures = initial.get("pressures", {})
    if not isinstance(pressures, dict):
        _error(where, "field 'initial.pressures': expected a table of net name = absolute pressure [Pa]")
    for name in pressures:
        _number(pressures, name, f"{where}, [initial.pressures]", low=0.0, high=1e10, low_open=False)  # Pa absolute
    equilibrium = initial.get("equilibrium", True)
    if not isinstance(equilibrium, bool):
        _error(where, f"field 'initial.equilibrium': expected true or false, got {equilibrium!r}")
    fidelity = _choice(run, "fidelity", w, FIDELITIES, "compressible")
    actuator_fidelity = {}
    fidelity_table = data.get("fidelity", {})
    if not isinstance(fidelity_table, dict):
        _error(where, f"[fidelity] must be a table of default = level and actuator name = level; levels: {list(FIDELITIES)}")
    for name, level in fidelity_table.items():
        if not isinstance(level, str) or level not in FIDELITIES:
            _error(where, f"field 'fidelity.{name}': {level!r} is not one of {list(FIDELITIES)}")
        if name == "default":
            if "fidelity" in run and run["fidelity"] != level:
                _error(where, f"field 'fidelity.default': {level!r} contradicts field 'run.fidelity' = {run['fidelity']!r}; give one of them")
            fidelity = level
        else:
            actuator_fidelity[name] = level
    inputs_table = data.get("inputs", {})
    if not isinstance(inputs_table, dict):
        _error(where, "[inputs] must be a table of input name = schedule")
    inputs = {name: _schedule(name, spec, where) for name, spec in inputs_table.items()}
    inputs_csv = None
    if "inputs_csv" in data:
        if not isinstance(data["inputs_csv"], str):
            _error(where, "field 'inputs_csv': a path relative to the scenario file is required")
        inputs_csv = resolve(path.parent / data["inputs_csv"], f"field 'inputs_csv' of {where}: inputs CSV", ScenarioError)
        inputs.update(_csv_inputs(inputs_csv, where))
    controllers = _controllers(data.get("controllers", {}), where, inputs)
    scenario = Scenario(
        path=path,
        mjcf=files["mjcf"],
        circuit=files["circuit"],
        mode=run.get("mode", "mujoco"),
        coupling=run.get("coupling", DEFAULT_COUPLING),
        stepper=run.get("stepper"),
        dt=dt,
        duration=duration,
        hydraulic_substeps=_number(run, "hydraulic_substeps", w, low=1, high=1e5, low_open=False, default=1, integer=True),
        pbd_substeps=_number(run, "pbd_substeps", w, low=1, high=1e5, low_open=False, default=20, integer=True),
        pbd_iterations=_number(run, "pbd_iterations", w, low=1, high=1e5, low_open=False, default=1, integer=True),
        fidelity=fidelity,
        actuator_fidelity=actuator_fidelity,
        pbd_blend=_flag(run, "pbd_blend", w, False),
        qpos=joint_table("qpos"),
        qvel=joint_table("qvel"),
        equilibrium=equilibrium,
        start_contacts=_choice(initial, "start_contacts", f"{where}, [initial]", START_CONTACTS, "exclude"),
        base_pressure=_number(initial, "base_pressure", f"{where}, [initial]", low=0.0, high=1e8, default=DEFAULT_BASE_PRESSURE),
        pressures={k: float(v) for k, v in pressures.items()},
        inputs=inputs,
        inputs_csv=inputs_csv,
        log_rate_hz=_number(log, "rate_hz", f"{where}, [log]", low=RATE_RANGE[0], high=RATE_RANGE[1], low_open=False, default=100.0),
        tf_rate_hz=_number(log, "tf_rate_hz", f"{where}, [log]", low=RATE_RANGE[0], high=RATE_RANGE[1], low_open=False, default=100.0),
        monitor=_monitor_enabled(data.get("monitor", {}), where),
        mapping=_mapping(data.get("mapping"), where),
        controllers=controllers,
    )
    _validate_run(scenario, where)
    return scenario


def _mapping(table, where):
    """``[mapping]`` (device axes to valve commands, :func:`sim.live.mapping.parse_mapping`), or None."""
    if table is None:
        return None

    return parse_mapping(table, where)


def _monitor_enabled(table, where) -> bool:
    """``[monitor] enabled`` (default true): whether the plausibility monitor stops a run that leaves its bounds."""
    if not isinstance(table, dict) or set(table) - {"enabled"}:
        _error(where, "[monitor] must be a table with the one field 'enabled' (true or false)")
    return _flag(table, "enabled", f"{where}, [monitor]", True)


PUMP_KINDS = ("pump_fixed", "pump_compensated")


def input_range(circuit, name: str):
    """Allowed range ``(low, high, unit)`` of the scenario input ``name`` of ``circuit``, or None if no valve or pump has it.

    A valve's spool command is in its type's ``COMMAND_RANGE`` [-] (:data:`VALVE_COMMAND_RANGE` for the 4/3 valve,
    [0, 1] for a variable orifice); a pump's shaft speed in the range
    of its type's ``speed`` field [rev/s] (``[0, 1000]`` rev/s for :class:`hydraulics.components.PumpFixed`
    and :class:`~hydraulics.components.PumpCompensated`: the pumps turn one way; 1000 rev/s is 60 000 rpm,
    beyond any hydraulic pump).
    """
    for c in circuit.components:
        if c.name != name:
            continue
        if c.kind in PUMP_KINDS:
            meta = {f.name: f.metadata for f in dataclasses.fields(COMPONENT_TYPES[c.kind])}["speed"]
            return float(meta["low"]), float(meta["high"]), meta["unit"]
        command_range = getattr(COMPONENT_TYPES[c.kind], "COMMAND_RANGE", None)
        if command_range is not None:  # a valve kind's spool (or opening) command
            return (*command_range, "")
    return None


def check_input_ranges(scenario: Scenario, circuit) -> None:
    """Refuse schedule values outside each input's physical range (:func:`input_range`), naming the input and knot.

    Inputs that name no valve or pump are left to the caller (:func:`sim.io.scene.load_scene` names them).
    """
    for name, schedule in scenario.inputs.items():
        bounds = input_range(circuit, name) if isinstance(schedule, Schedule) else None
        if bounds is None:
            continue
        low, high, unit = bounds
        bad = np.flatnonzero((schedule.value < low) | (schedule.value > high))
        if len(bad):
            i = int(bad[0])
            kind = "pump speed" if unit else "valve command"
            _error(f"{scenario.path}, field 'inputs.{name}'",
                   f"value {float(schedule.value[i])!r} at t = {float(schedule.t[i])!r} s is outside the {kind} range "
                   f"[{low:g}, {high:g}]{' ' + unit if unit else ''} of '{name}' in {scenario.circuit}")
