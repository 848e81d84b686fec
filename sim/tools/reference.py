"""Converged reference runs: MuJoCo mode, implicit coupling, the step halved until it no longer matters.

A reference of a scenario is a MuJoCo-mode run with the implicit coupling at a step ``h``
small enough that halving it changes every compared signal -- joint positions, cylinder
strokes, chamber and motor port pressures (:func:`sim.tools.signals.log_signals`) -- by less than
a stated tolerance (:class:`Tolerance`).  :func:`compute_reference` runs ``h0, h0/2, h0/4, …``
and stops at the first pair ``(h, h/2)`` that passes :func:`check_convergence`; the run at
``h/2`` is the reference and the pair's changes are its convergence proof (for the
first-order schemes used here the error of the ``h/2`` run is about the change itself).
The step ladder starts at the scenario's ``dt`` (or ``start_dt``) rounded down to a divisor
of the log period, so that every run logs at the same instants and no comparison
interpolates.

References are cached in ``cache_dir/<key>/`` (default ``.cache/references/``), ``key`` the
SHA-256 of the MJCF (with its includes and assets), circuit, scenario and inputs CSV contents, the source code of ``hydraulics/``
and ``sim/`` (:func:`sim.tools.sweep.code_hash`), the effective run settings (duration, log rate,
fidelity and its per-actuator overrides, initial state, inputs) and the reference settings;
a cached reference is re-checked when it is loaded: its ``reference.json`` must hold that key,
the SHA-256 of both logs and a digest of all of it (:func:`sim.tools.sweep.entry_digest`), and
the two logs must still pass :func:`check_convergence`; an entry failing any check (damaged,
stale, or a file put there by hand) is ignored and the reference computed again.

:func:`require_converged` rejects a candidate pair of logs at ``h`` and ``h/2`` that is not
converged, with a message naming every signal that moved too much.

Point-wise or filtered: by default the change of every sample counts (point-wise). When the
dynamics are not point-wise step-convergent at any affordable step -- the excavator's teeth
stick-slipping in the soil, where the instants of the slips move with the step -- a
reference may instead be proven on the signals averaged over a centred moving window
(``filter_window`` [s], e.g. 0.1 s; :func:`sim.tools.signals.filtered_error_stats`): the same
tolerance then applies to the averaged signals, and the report says so. The point-wise
check is unchanged and stays the default.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
import tempfile
import time as _time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from sim import version
from sim.io.mcap_log import RUN_METADATA, read_log
from mcap.exceptions import McapError

from hydraulics.files import read_text
from sim.io.scenario import Scenario, ScenarioError, load_scenario
from sim.io.scene import input_paths
from sim.tools.sweep import code_hash, content_hash, entry_digest

__all__ = [
    "ConvergenceReport",
    "DEFAULT_CACHE_DIR",
    "NotConvergedError",
    "Reference",
    "SignalCheck",
    "Tolerance",
    "check_convergence",
    "compute_reference",
    "reference_key",
    "require_converged",
]

DEFAULT_CACHE_DIR = Path(".cache/references")
REFERENCE_VERSION = 1  # bump when what a reference is changes (invalidates caches)
REFERENCE_LOGS = ("coarse.mcap", "reference.mcap")  # the files of a cache entry besides reference.json
MAX_HALVINGS = 10  # default: at most h0 / 2**10
MAX_STEPS = 2_000_000  # default: no reference run longer than this many steps
DT_RATIO_SLACK = 1e-6  # relative slack on "the fine log is at exactly half the coarse step"


class NotConvergedError(ScenarioError):
    """A reference candidate is not converged; the message names the signals and the tolerance."""


@dataclass(frozen=True)
class Tolerance:
    """How much halving the step may change a signal: ``max(absolute, relative · range)``.

    Attributes
    ----------
    relative : float
        Fraction of the signal's peak-to-peak range in the finer run [-].
    joint : float
        Absolute floor for joint positions [rad, or m for slide joints].
    stroke : float
        Absolute floor for cylinder strokes [m].
    pressure : float
        Absolute floor for pressures [Pa].
    """

    relative: float = 1e-3
    joint: float = 1e-4
    stroke: float = 1e-4
    pressure: float = 1e4

    def __post_init__(self):
        for name, value in asdict(self).items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ScenarioError(f"reference tolerance: field '{name}': {value!r} is not a finite number >= 0")

    def allowed(self, kind: str, ref_range: float) -> float:
        """Allowed change of a signal of ``kind`` whose range is ``ref_range`` (signal units)."""
        floor = {"joint": self.joint, "stroke": self.stroke, "pressure": self.pressure}[kind]
        scaled = self.relative * ref_range if math.isfinite(ref_range) else 0.0
        return max(floor, scaled)

    def text(self) -> str:
        return (f"max({self.relative:.3g} × range, {self.joint:.3g} rad or m) for joints, "
                f"max({self.relative:.3g} × range, {self.stroke * 1e3:.3g} mm) for strokes, "
                f"max({self.relative:.3g} × range, {self.pressure / 1e5:.3g} bar) for pressures")


@dataclass(frozen=True)
class SignalCheck:
    """Change of one signal between the runs at ``h`` and ``h/2``."""

    name: str
    kind: str
    change: float  # largest |y_h - y_h/2| (signal units)
    allowed: float
    ref_range: float
    t_max: float  # time of the largest change [s]

    @property
    def ok(self) -> bool:
        return math.isfinite(self.change) and self.change <= self.allowed


@dataclass
class ConvergenceReport:
    """Outcome of :func:`check_convergence`.

    Attributes
    ----------
    converged : bool
        Every signal within tolerance and no problem found.
    dt_coarse, dt_fine : float
        Steps of the two logs [s] (NaN when a log does not say).
    tolerance : Tolerance
    checks : list of SignalCheck
    problems : list of str
        Reasons other than a signal's change (a run diverged, logs of different length …).
    coarse, fine : str
        The two log paths.
    """

    converged: bool
    dt_coarse: float
    dt_fine: float
    tolerance: Tolerance
    checks: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    coarse: str = ""
    fine: str = ""
    filter_window: float | None = None  # s: the signals were averaged over this window (None: point-wise)

    def metric_text(self) -> str:
        """``"point-wise"`` or ``"of the signals averaged over a centred 0.1 s moving window"``."""
        if self.filter_window:
            return f"of the signals averaged over a centred {self.filter_window:g} s moving window"
        return "point-wise"

    def failures(self) -> list:
        return [c for c in self.checks if not c.ok]

    def worst(self) -> SignalCheck | None:
        """The check with the largest change relative to what it is allowed."""
        return max(self.checks, key=lambda c: c.change / c.allowed if c.allowed > 0 else math.inf, default=None)

    def text(self) -> str:
        """Markdown: the verdict, the tolerance and one row per signal."""
        verdict = "converged" if self.converged else "NOT converged"
        lines = [
            f"Convergence ({self.metric_text()}): {verdict}: halving the step from {self.dt_coarse:.4g} s to "
            f"{self.dt_fine:.4g} s changes every compared signal by at most the tolerance {self.tolerance.text()}."
            if self.converged else
            f"Convergence ({self.metric_text()}): {verdict} (step {self.dt_coarse:.4g} s → {self.dt_fine:.4g} s; "
            f"tolerance {self.tolerance.text()}).",
        ]
        for problem in self.problems:
            lines.append(f"- problem: {problem}")
        lines += ["", "| signal | change h → h/2 | allowed | range | at t [s] | ok |", "|---|---|---|---|---|---|"]
        for c in self.checks:
            lines.append(f"| {c.name} | {_fmt(c.change, c.kind)} | {_fmt(c.allowed, c.kind)} | {_fmt(c.ref_range, c.kind)} | "
                         f"{c.t_max:.4g} | {'yes' if c.ok else 'NO'} |")
        return "\n".join(lines)

    def rejection(self) -> str:
        """One paragraph saying why the candidate is rejected."""
        parts = list(self.problems)
        bad = sorted(self.failures(), key=lambda c: -(c.change / c.allowed if c.allowed > 0 else math.inf))
        for c in bad[:4]:
            parts.append(f"{c.name} changed by {_fmt(c.change, c.kind)} at t = {c.t_max:.4g} s "
                         f"(allowed {_fmt(c.allowed, c.kind)})")
        if len(bad) > 4:
            parts.append(f"and {len(bad) - 4} more signals")
        return (f"reference rejected: not converged ({self.metric_text()}): halving the step from {self.dt_coarse:.4g} s to {self.dt_fine:.4g} s "
                f"({self.coarse} → {self.fine}): " + "; ".join(parts) + f". Tolerance: {self.tolerance.text()}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["checks"] = [asdict(c) for c in self.checks]
        return json.loads(json.dumps(d))  # NaN stays NaN (Python's json)

    @classmethod
    def from_dict(cls, d: dict) -> "ConvergenceReport":
        d = dict(d)
        d["tolerance"] = Tolerance(**d["tolerance"])
        d["checks"] = [SignalCheck(**c) for c in d["checks"]]
        return cls(**d)


def _fmt(value: float, kind: str) -> str:
    if not math.isfinite(value):
        return str(value)
    if kind == "pressure":
        return f"{value / 1e5:.3g} bar"
    if kind == "stroke":
        return f"{value * 1e3:.3g} mm"
    return f"{value:.3g} rad or m"


def _log_dt(log) -> float:
    try:
        return float(log.metadata.get(RUN_METADATA, {}).get("dt_s", "nan"))
    except ValueError:
        return math.nan


def check_convergence(coarse, fine, tolerance: Tolerance | None = None, *,
                      filter_window: float | None = None) -> ConvergenceReport:
    """Does halving the step change every compared signal by less than the tolerance?

    Parameters
    ----------
    coarse, fine : str, Path or RunLog
        Logs of the same scenario at steps ``h`` and ``h/2``.
    tolerance : Tolerance, optional
        Allowed change per signal kind (default :class:`Tolerance`).
    filter_window : float, optional
        Compare the signals averaged over a centred moving window of this length [s]
        (:func:`sim.tools.signals.filtered_error_stats`) instead of point-wise; the tolerance then
        applies to the averaged signals (ranges are those of the unfiltered signals).

    Returns
    -------
    ConvergenceReport
        ``converged`` is False when a signal changed by more than allowed, when either run
        did not complete, when the fine log does not cover the coarse one's span, when a
        signal is missing from one log, or when the logs state steps that are not ``h`` and
        ``h/2``.
    """
    from sim.tools.signals import check_same_scene, error_stats, filtered_error_stats, log_signals, log_status

    if filter_window is not None and not (math.isfinite(filter_window) and filter_window > 0):
        raise ScenarioError(f"reference: filter_window {filter_window!r} s must be a positive finite number")
    tolerance = tolerance or Tolerance()
    coarse = coarse if hasattr(coarse, "topic") else read_log(coarse)
    fine = fine if hasattr(fine, "topic") else read_log(fine)
    check_same_scene(fine, coarse)
    dt_coarse, dt_fine = _log_dt(coarse), _log_dt(fine)
    problems = []
    for log, name in ((coarse, "coarse"), (fine, "fine")):
        status, when = log_status(log)
        if status != "complete":
            problems.append(f"the {name} run (step {_log_dt(log):.4g} s) is {status}"
                            + (f" at t = {when:.4g} s" if status == "diverged" else ""))
    if math.isfinite(dt_coarse) and math.isfinite(dt_fine) and abs(dt_fine * 2 / dt_coarse - 1) > DT_RATIO_SLACK:
        problems.append(f"the logs are not at h and h/2 (steps {dt_coarse:.6g} s and {dt_fine:.6g} s)")
    ref, other = log_signals(fine), log_signals(coarse)
    missing = sorted(set(ref) ^ set(other))
    if missing:
        problems.append(f"signals in only one of the logs: {', '.join(missing)}")
    checks = []
    for name, sig in ref.items():
        if name not in other:
            continue
        if filter_window:
            stats = filtered_error_stats(sig.t, sig.y, other[name].t, other[name].y, filter_window)
        else:
            stats = error_stats(sig.t, sig.y, other[name].t, other[name].y)
        checks.append(SignalCheck(name, sig.kind, stats.max_abs, tolerance.allowed(sig.kind, stats.ref_range),
                                  stats.ref_range, stats.t_max))
        span_end = sig.t[-1] - (filter_window / 2 if filter_window else 0.0)  # the last whole window
        if stats.samples and abs(stats.t_end - span_end) > 1e-6 + (0.5 * filter_window if filter_window else 0.0) \
                and not problems:
            problems.append(f"the logs cover different spans ({other[name].t[-1]:.6g} s and {sig.t[-1]:.6g} s)")
    if not checks:
        problems.append("no signal to compare")
    converged = not problems and all(c.ok for c in checks)
    return ConvergenceReport(converged, dt_coarse, dt_fine, tolerance, checks, problems, str(coarse.path), str(fine.path),
                             filter_window)


def require_converged(coarse, fine, tolerance: Tolerance | None = None, *,
                      filter_window: float | None = None) -> ConvergenceReport:
    """:func:`check_convergence`, raising :class:`NotConvergedError` (with the reasons) when it fails."""
    report = check_convergence(coarse, fine, tolerance, filter_window=filter_window)
    if not report.converged:
        raise NotConvergedError(report.rejection())
    return report


# ---------------------------------------------------------------------------------------
# Computing and caching references
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReferenceSettings:
    """How a reference is computed (part of its cache key)."""

    coupling: str = "implicit"
    hydraulic_substeps: int = 1
    start_dt: float | None = None  # s; default the scenario's dt
    tolerance: Tolerance = Tolerance()
    filter_window: float | None = None  # s: convergence of moving averages (None: point-wise)


@dataclass
class Reference:
    """A converged reference run.

    Attributes
    ----------
    log_path : Path
        The reference log (the run at ``h/2``).
    coarse_log_path : Path
        The run at ``h`` of the convergence proof.
    dt : float
        Step of the reference run [s].
    report : ConvergenceReport
    key : str
        Cache key.
    cached : bool
        Taken from the cache (no run now).
    wall_time : float
        Wall time spent computing it now [s] (0 when cached).
    runs : list of dict
        The ladder: ``{"dt", "wall_time", "status"}`` per run made.
    """

    log_path: Path
    coarse_log_path: Path
    dt: float
    report: ConvergenceReport
    key: str
    cached: bool
    wall_time: float
    scenario_path: Path
    settings: ReferenceSettings
    runs: list = field(default_factory=list)

    def settings_text(self) -> str:
        s = self.settings
        sub = f", {s.hydraulic_substeps} hydraulic substeps" if s.hydraulic_substeps != 1 else ""
        window = f", converged on {s.filter_window:g} s moving averages" if s.filter_window else ""
        return f"MuJoCo mode, {s.coupling} coupling, dt {self.dt:.4g} s{sub}{window}"


def _scenario_state(s: Scenario) -> dict:
    """Effective settings of a scenario that change its reference, as JSON."""
    return {
        "duration": s.duration,
        "log_rate_hz": s.log_rate_hz,
        "fidelity": s.fidelity,
        "actuator_fidelity": dict(sorted(s.actuator_fidelity.items())),
        "stepper": s.stepper,
        "qpos": s.qpos,
        "qvel": s.qvel,
        "equilibrium": s.equilibrium,
        "base_pressure": s.base_pressure,
        "pressures": s.pressures,
        "inputs": {k: [v.t.tolist(), v.value.tolist()] for k, v in sorted(s.inputs.items())},
        "controllers": {k: {f: ([v.t.tolist(), v.value.tolist()] if f == "setpoint" else v) for f, v in vars(c).items()}
                        for k, c in sorted(s.controllers.items())},
    }


def reference_key(scenario: Scenario, settings: ReferenceSettings) -> str:
    """Cache key: SHA-256 of the MJCF, circuit and scenario contents, effective settings and ``settings``."""
    payload = {
        "version": REFERENCE_VERSION,
        "hydroplant": version(),
        "files": content_hash(*input_paths(scenario)),  # MJCF (with includes and assets), circuit, scenario, CSV
        "code": code_hash(),  # the hydraulics/ and sim/ source: a code change recomputes the reference
        "scenario": _scenario_state(scenario),
        "settings": {k: v for k, v in asdict(settings).items() if not (k == "filter_window" and v is None)},
    }
    return content_hash(json.dumps(payload, sort_keys=True).encode())


def start_step(scenario: Scenario, start_dt: float | None = None) -> float:
    """First step of the ladder: ``start_dt`` (default the scenario's dt) rounded down to log period / n."""
    period = 1.0 / scenario.log_rate_hz
    h = start_dt if start_dt is not None else scenario.dt
    n = max(1, math.ceil(period / h - 1e-9))
    return period / n


def _log_hashes(directory: Path) -> dict:
    return {name: content_hash(directory / name) for name in REFERENCE_LOGS}


def _load_cached(directory: Path, scenario: Scenario, settings: ReferenceSettings, key: str):
    """The cached reference in ``directory``, or None when missing or failing a check (see the module docstring)."""
    info_path = directory / "reference.json"
    if not info_path.is_file():
        return None
    try:
        info = json.loads(read_text(info_path, "reference cache"))
        if (not isinstance(info, dict) or info.get("key") != key or info.get("digest") != entry_digest(info)
                or info.get("logs") != _log_hashes(directory)):
            return None
        fine, coarse = directory / "reference.mcap", directory / "coarse.mcap"
        report = check_convergence(coarse, fine, settings.tolerance, filter_window=settings.filter_window)
    except (OSError, ValueError, LookupError, TypeError, EOFError, RecursionError, McapError):  # (CircuitError: a ValueError)
        return None
    if not report.converged:
        return None
    return Reference(fine, coarse, float(info["dt"]), report, key, True, 0.0, scenario.path, settings, info.get("runs", []))


def compute_reference(scenario, *, tolerance: Tolerance | None = None, cache_dir=DEFAULT_CACHE_DIR,
                      start_dt: float | None = None, coupling: str = "implicit", hydraulic_substeps: int = 1,
                      max_halvings: int = MAX_HALVINGS, max_steps: int = MAX_STEPS, fresh: bool = False,
                      progress: bool = False, filter_window: float | None = None) -> Reference:
    """The converged reference of a scenario, from the cache or computed now.

    Parameters
    ----------
    scenario : str, Path or Scenario
        The scenario, with any overrides already applied (e.g. a shortened duration).
        Its mode, coupling, dt and substeps are replaced; everything else is kept.
    tolerance : Tolerance, optional
        Allowed change when the step is halved (default :class:`Tolerance`).
    cache_dir : str or Path
        Cache directory (default ``.cache/references``).
    start_dt : float, optional
        First step of the ladder [s] (default the scenario's dt); rounded down to divide
        the log period.
    coupling : {"implicit", "explicit"}
    hydraulic_substeps : int
    max_halvings : int
        Give up after ``start_dt / 2**max_halvings``.
    max_steps : int
        Give up rather than make a run of more steps than this.
    fresh : bool
        Ignore (and replace) a cached reference.
    progress : bool
        Print one line per run to stderr.
    filter_window : float, optional
        Prove convergence on the signals averaged over this centred moving window [s]
        instead of point-wise (see the module docstring); part of the cache key.

    Raises
    ------
    NotConvergedError
        No pair of the ladder converged within the limits; the message has the finest
        pair's rejection.
    """
    from sim.run.runner import run

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    settings = ReferenceSettings(coupling, hydraulic_substeps, start_dt, tolerance or Tolerance(), filter_window)
    key = reference_key(scenario, settings)
    cache_dir = Path(cache_dir)
    directory = cache_dir / key[:24]
    if not fresh:
        cached = _load_cached(directory, scenario, settings, key)
        if cached is not None:
            if progress:
                print(f"reference: cached {directory} (dt {cached.dt:.4g} s)", file=sys.stderr)
            return cached
    h = start_step(scenario, start_dt)
    base = scenario.with_overrides(mode="mujoco", coupling=coupling, hydraulic_substeps=hydraulic_substeps)
    cache_dir.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{key[:12]}-", dir=cache_dir))
    runs, previous, report = [], None, None
    started = _time.perf_counter()
    try:
        for level in range(max_halvings + 1):
            dt = h / 2**level
            steps = round(scenario.duration / dt)
            if steps > max_steps:
                break
            path = work / f"level{level}.mcap"
            result = run(base.with_overrides(dt=dt), out=path)
            runs.append({"dt": dt, "wall_time": result.wall_time, "status": result.status})
            if previous is not None:
                report = check_convergence(previous, path, settings.tolerance, filter_window=filter_window)
                if progress:
                    worst = report.worst()
                    share = f"worst {worst.name} {worst.change / worst.allowed:.3g}× allowed" if worst else ""
                    print(f"reference: dt {dt:.4g} s, {result.wall_time:.1f} s wall, {share}"
                          f"{' -> converged' if report.converged else ''}", file=sys.stderr)
                if report.converged:
                    break
            elif progress:
                print(f"reference: dt {dt:.4g} s, {result.wall_time:.1f} s wall", file=sys.stderr)
            previous = path
        if report is None or not report.converged:
            why = report.rejection() if report is not None else "no pair of runs fits in the limits"
            raise NotConvergedError(
                f"{scenario.path}: no converged reference within {max_halvings} halvings of {h:.4g} s and {max_steps} steps "
                f"per run: {why}. Loosen the tolerance, shorten the duration, or allow more steps.")
        final = directory.with_name(directory.name + ".new")
        shutil.rmtree(final, ignore_errors=True)
        final.mkdir()
        shutil.move(str(previous), final / "coarse.mcap")
        shutil.move(str(path), final / "reference.mcap")
        info = {"key": key, "dt": dt, "scenario": str(scenario.path), "settings": asdict(settings), "runs": runs,
                "logs": _log_hashes(final)}
        info = json.loads(json.dumps(info))  # (as it reads back: tuples become lists)
        info["digest"] = entry_digest(info)
        (final / "reference.json").write_text(json.dumps(info, indent=1, sort_keys=True))
        shutil.rmtree(directory, ignore_errors=True)
        final.rename(directory)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    report = check_convergence(directory / "coarse.mcap", directory / "reference.mcap", settings.tolerance,
                               filter_window=filter_window)
    return Reference(directory / "reference.mcap", directory / "coarse.mcap", dt, report, key, False,
                     _time.perf_counter() - started, scenario.path, settings, runs)
