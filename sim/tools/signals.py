"""Signals of a run log and the error metrics between two logs: what ``compare`` reports and the reference's
convergence check (:mod:`sim.tools.reference`) measures.

Pure functions on a log's samples: :func:`log_signals` (joint positions, cylinder strokes, chamber and motor port
pressures), :func:`align` (the samples at common times, within :data:`TIME_MATCH_NS`), :func:`error_stats`
(point-wise) and :func:`filtered_error_stats` (after a moving average over ``window`` [s]), the first-order
Richardson estimate of a finer run (:func:`richardson_first_order`), :func:`energy_drift`, :func:`log_status` and the
scene check of two logs (:func:`check_same_scene`).  Both tools import them from here, so neither imports the other.

Example
-------
>>> import numpy as np
>>> t = np.linspace(0.0, 1.0, 11)
>>> round(error_stats(t, t, t, t + 0.01).max_abs, 12)
0.01
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hydraulics.components import CircuitError

from sim.io.mcap_log import RESULT_METADATA, RUN_METADATA, read_log

KINDS = ("joint", "stroke", "pressure")  # signal groups, in table order
KIND_UNITS = {"joint": "rad or m", "stroke": "m", "pressure": "Pa"}
KIND_DISPLAY = {"joint": (1e3, "mrad or mm"), "stroke": (1e3, "mm"), "pressure": (1e-5, "bar")}  # factor, unit
JOINT_TOPIC = "/hydroplant/joint_states"
CYLINDER_PREFIX = "/hydroplant/cylinders/"
MOTOR_PREFIX = "/hydroplant/motors/"
NODE_TOPIC = "/hydroplant/nodes"
ENERGY_TOPIC = "/hydroplant/energy"
TIME_MATCH_NS = 1000  # sample times closer than this [ns] count as the same instant
DEFAULT_FILTER_WINDOW = 0.1  # s: window of the moving-average (filtered) error metric


# ---------------------------------------------------------------------------------------
# Signals and error metrics (pure functions)
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Signal:
    """One compared signal of a log.

    Attributes
    ----------
    name : str
        ``"joint <j>"``, ``"stroke <cyl>"``, ``"p_cap <cyl>"``, ``"p_rod <cyl>"``,
        ``"p_a <motor>"``, ``"p_b <motor>"``.
    kind : {"joint", "stroke", "pressure"}
    t : ndarray, shape (n,)
        Simulation time [s].
    y : ndarray, shape (n,)
        Value [rad or m, m, Pa].
    """

    name: str
    kind: str
    t: np.ndarray
    y: np.ndarray


def log_signals(log) -> dict[str, Signal]:
    """The compared signals of a run log (a path or a :class:`sim.io.mcap_log.RunLog`): joint positions, cylinder
    strokes and chamber pressures, motor port pressures; for a scene without any of these (a circuit on a test bench)
    the node pressures."""
    if not hasattr(log, "topic"):
        log = read_log(log)
    out: dict[str, Signal] = {}
    if JOINT_TOPIC in log:
        joints = log.topic(JOINT_TOPIC)
        for name in joints.fields:
            if name.startswith("position/"):
                joint = name.removeprefix("position/")
                out[f"joint {joint}"] = Signal(f"joint {joint}", "joint", joints.t, joints[name])
    for topic in log.topics:
        if topic.startswith(CYLINDER_PREFIX):
            cyl = topic.removeprefix(CYLINDER_PREFIX)
            data = log.topic(topic)
            for label, column, kind in (("stroke", "position_m", "stroke"), ("p_cap", "p_cap_pa", "pressure"),
                                        ("p_rod", "p_rod_pa", "pressure")):
                if column in data.fields:
                    out[f"{label} {cyl}"] = Signal(f"{label} {cyl}", kind, data.t, data[column])
        elif topic.startswith(MOTOR_PREFIX):
            motor = topic.removeprefix(MOTOR_PREFIX)
            data = log.topic(topic)
            for label, column in (("p_a", "p_a_pa"), ("p_b", "p_b_pa")):
                if column in data.fields:
                    out[f"{label} {motor}"] = Signal(f"{label} {motor}", "pressure", data.t, data[column])
    if not out and NODE_TOPIC in log:  # a test bench of the circuit alone: its node pressures are what it shows
        nodes = log.topic(NODE_TOPIC)
        for name in nodes.fields:
            if name.startswith("pressure_pa."):
                node = name.removeprefix("pressure_pa.")
                out[f"p {node}"] = Signal(f"p {node}", "pressure", nodes.t, nodes[name])
    return out


def align(t_ref, y_ref, t, y):
    """Two signals on common times.

    Parameters
    ----------
    t_ref, y_ref : array_like, shape (n,)
        Reference times [s] (increasing) and values.
    t, y : array_like, shape (m,)
        The other signal.

    Returns
    -------
    times, ref, other : ndarray, shape (k,)
        Over the span both signals cover, at the times of the sparser grid there (the
        reference's when equally dense); the other signal is interpolated linearly.
        Where both grids hold the same instants (within 1 µs) no value is interpolated.
        Samples where either value is not finite are dropped. ``k`` may be 0.
    """
    t_ref, y_ref, t, y = (np.asarray(a, dtype=float) for a in (t_ref, y_ref, t, y))
    ok_ref, ok = np.isfinite(y_ref) & np.isfinite(t_ref), np.isfinite(y) & np.isfinite(t)
    t_ref, y_ref, t, y = t_ref[ok_ref], y_ref[ok_ref], t[ok], y[ok]
    if len(t_ref) == 0 or len(t) == 0:
        empty = np.zeros(0)
        return empty, empty, empty
    slack = TIME_MATCH_NS * 1e-9
    lo, hi = max(t_ref[0], t[0]) - slack, min(t_ref[-1], t[-1]) + slack
    in_ref = (t_ref >= lo) & (t_ref <= hi)
    in_other = (t >= lo) & (t <= hi)
    if in_other.sum() < in_ref.sum():  # the other grid is sparser: evaluate there
        times = t[in_other]
        return times, _resample(t_ref, y_ref, times), y[in_other]
    times = t_ref[in_ref]
    return times, y_ref[in_ref], _resample(t, y, times)


def _resample(t, y, times):
    """y(times) by linear interpolation, exact at samples within 1 µs of ``times``."""
    out = np.interp(times, t, y)
    i = np.clip(np.searchsorted(t, times), 0, len(t) - 1)
    for j in (i, np.maximum(i - 1, 0)):
        hit = np.abs(t[j] - times) <= TIME_MATCH_NS * 1e-9
        out[hit] = y[j][hit]
    return out


@dataclass(frozen=True)
class ErrorStats:
    """Error of a signal against the reference over the compared span.

    Attributes
    ----------
    max_abs, rms : float
        Largest and root-mean-square absolute error (signal units); NaN if nothing overlaps.
    ref_range : float
        Peak-to-peak of the reference over its whole log (signal units).
    max_rel, rms_rel : float
        ``max_abs`` and ``rms`` divided by ``ref_range`` (NaN when the range is 0).
    t_max : float
        Time of the largest error [s].
    t_end : float
        Last compared time [s] (earlier than the reference's end when the run stopped).
    samples : int
        Number of compared samples.
    """

    max_abs: float
    rms: float
    ref_range: float
    max_rel: float
    rms_rel: float
    t_max: float
    t_end: float
    samples: int


def richardson_first_order(t_fine, y_fine, t_coarse, y_coarse):
    """Richardson extrapolation of a first-order method: 2·y(h/2) − y(h), at the finer run's times.

    ``y_fine`` [any unit] from step h/2 at times ``t_fine`` [s], ``y_coarse`` from step h at ``t_coarse`` [s]
    (interpolated linearly, exact at shared instants).  For an error C·h + O(h²) the result is off by O(h²) only;
    |y_fine − result| is then the h/2 run's own error.
    """
    t_fine, y_fine = np.asarray(t_fine, dtype=float), np.asarray(y_fine, dtype=float)
    return 2.0 * y_fine - _resample(np.asarray(t_coarse, dtype=float), np.asarray(y_coarse, dtype=float), t_fine)


def error_series(t_ref, y_ref, t, y):
    """``(times, y − y_ref)`` on the common times of :func:`align`."""
    times, ref, other = align(t_ref, y_ref, t, y)
    return times, other - ref


def error_stats(t_ref, y_ref, t, y) -> ErrorStats:
    """Max and RMS error of ``(t, y)`` against ``(t_ref, y_ref)``; see :class:`ErrorStats`."""
    y_ref_all = np.asarray(y_ref, dtype=float)
    finite = y_ref_all[np.isfinite(y_ref_all)]
    ref_range = float(np.ptp(finite)) if len(finite) else math.nan
    times, e = error_series(t_ref, y_ref, t, y)
    if len(e) == 0:
        return ErrorStats(math.nan, math.nan, ref_range, math.nan, math.nan, math.nan, math.nan, 0)
    a = np.abs(e)
    i = int(np.argmax(a))
    max_abs, rms = float(a[i]), float(np.sqrt(np.mean(e * e)))
    rel = (lambda v: v / ref_range) if ref_range > 0 else (lambda v: math.nan)
    return ErrorStats(max_abs, rms, ref_range, rel(max_abs), rel(rms), float(times[i]), float(times[-1]), len(e))


def moving_average(t, y, window: float):
    """Centred moving average of ``y(t)`` over ``window`` seconds.

    Parameters
    ----------
    t : array_like, shape (n,)
        Increasing sample times [s] (any spacing).
    y : array_like, shape (n,)
        Values (any unit), finite.
    window : float
        Averaging window [s], > 0.

    Returns
    -------
    times, mean : ndarray, shape (k,)
        ``mean[i] = (1/w)·∫ y dt`` over ``[times[i] − w/2, times[i] + w/2]``, the integral of
        the piecewise-linear interpolant (exact for a linear signal), at the samples whose whole
        window lies inside ``[t[0], t[-1]]``. ``k`` may be 0 (span shorter than the window).
    """
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    if not (math.isfinite(window) and window > 0):
        raise ValueError(f"moving average: window {window!r} s must be a positive finite number")
    if len(t) < 2:
        return np.zeros(0), np.zeros(0)
    integral = np.concatenate(([0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(t))))
    lo, hi = t - window / 2, t + window / 2
    slack = TIME_MATCH_NS * 1e-9
    ok = (lo >= t[0] - slack) & (hi <= t[-1] + slack)
    lo, hi = np.clip(lo[ok], t[0], t[-1]), np.clip(hi[ok], t[0], t[-1])
    return t[ok], (np.interp(hi, t, integral) - np.interp(lo, t, integral)) / window


def filtered_error_stats(t_ref, y_ref, t, y, window: float = DEFAULT_FILTER_WINDOW) -> ErrorStats:
    """:func:`error_stats` of the two signals after a centred moving average over ``window`` [s].

    Both signals are put on common times (:func:`align`), each is averaged over the window
    (:func:`moving_average`), and the max / RMS of the difference is taken where the whole
    window lies inside the compared span. ``ref_range`` is the unfiltered reference's
    peak-to-peak, as for the point-wise metric, so tolerances relative to the range mean the
    same in both.
    """
    y_ref_all = np.asarray(y_ref, dtype=float)
    finite = y_ref_all[np.isfinite(y_ref_all)]
    ref_range = float(np.ptp(finite)) if len(finite) else math.nan
    times, ref, other = align(t_ref, y_ref, t, y)
    times_f, ref_f = moving_average(times, ref, window) if len(times) else (np.zeros(0), np.zeros(0))
    _, other_f = moving_average(times, other, window) if len(times) else (np.zeros(0), np.zeros(0))
    if len(times_f) == 0:
        return ErrorStats(math.nan, math.nan, ref_range, math.nan, math.nan, math.nan, math.nan, 0)
    e = other_f - ref_f
    a = np.abs(e)
    i = int(np.argmax(a))
    max_abs, rms = float(a[i]), float(np.sqrt(np.mean(e * e)))
    rel = (lambda v: v / ref_range) if ref_range > 0 else (lambda v: math.nan)
    return ErrorStats(max_abs, rms, ref_range, rel(max_abs), rel(rms), float(times_f[i]), float(times_f[-1]), len(e))


def energy_drift(log) -> dict:
    """Energy-balance residual of a run log (pump work − Δ(kinetic+potential+oil) − dissipation).

    Returns
    -------
    dict
        ``final_j`` (residual at the last sample), ``max_abs_j`` and ``relative`` =
        ``max_abs_j`` / energy scale, the scale being the larger of the final pump work and the
        largest kinetic + oil energy of the run [J] (1 J at least). NaN without an energy topic.
    """
    if not hasattr(log, "topic"):
        log = read_log(log)
    if ENERGY_TOPIC not in log:
        return {"final_j": math.nan, "max_abs_j": math.nan, "relative": math.nan}
    e = log.topic(ENERGY_TOPIC)
    residual = e["residual_j"]
    finite = residual[np.isfinite(residual)]
    if len(finite) == 0:
        return {"final_j": math.nan, "max_abs_j": math.nan, "relative": math.nan}
    moving = e["kinetic_j"] + e["oil_j"]
    scale = max(1.0, float(np.nanmax(np.abs(e["pump_work_j"]), initial=0.0)), float(np.nanmax(np.abs(moving), initial=0.0)))
    max_abs = float(np.max(np.abs(finite)))
    return {"final_j": float(finite[-1]), "max_abs_j": max_abs, "relative": max_abs / scale}


def log_status(log) -> tuple[str, float]:
    """``(status, time)`` of a run log: ``"complete"``, ``"diverged"`` (time of divergence [s]), …"""
    result = log.metadata.get(RESULT_METADATA, {})
    status = result.get("status", "unknown")
    try:
        when = float(result.get("time_s", "nan"))
    except ValueError:
        when = math.nan
    if status == "diverged" and not math.isfinite(when):
        when = log.end_time_ns / 1e9
    return status, when




def scene_identity(log) -> dict:
    """What identifies the scene of a log: name and the MJCF and circuit attachments' contents."""
    run = log.metadata.get(RUN_METADATA, {})
    ident = {"scene": run.get("scene")}
    for name, data in log.attachments.items():
        if name.endswith(".xml"):
            ident["mjcf"] = data
        elif name == "circuit.toml":
            ident["circuit"] = data
    return ident


def check_same_scene(ref_log, log) -> None:
    """Raise :class:`CircuitError` when two logs are of different scenes or share no signal."""
    a, b = scene_identity(ref_log), scene_identity(log)
    for key, what in (("scene", "scene name"), ("mjcf", "MJCF"), ("circuit", "circuit")):
        if a.get(key) is not None and b.get(key) is not None and a[key] != b[key]:
            detail = f" ({a[key]!r} vs {b[key]!r})" if key == "scene" else " (attachments differ)"
            raise CircuitError(f"{ref_log.path} and {log.path} are logs of different scenes: their {what} differ{detail}")
    if not set(log_signals(ref_log)) & set(log_signals(log)):
        raise CircuitError(f"{ref_log.path} and {log.path} have no joint, stroke or pressure signal in common; "
                           "they are not logs of the same scene")
