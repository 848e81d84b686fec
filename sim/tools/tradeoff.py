"""``hydroplant tradeoff``: accuracy against cost over modes, couplings and step settings.

::

    hydroplant tradeoff SCENARIO | --example NAME [--scheduler tcp://host:port [--worker-timeout S]] [--out DIR] [--quick]
        [--duration S] [--json]

Exit status 0 when every setting ran stable, 4 when the report is written but some settings diverged or
failed (the report names them; with every setting failed there is no figure), 2 for bad input.

Sweeps the step ``dt``, the hydraulic substeps (MuJoCo mode), the XPBD substeps and
iterations (PBD modes, when the PBD plant is importable), both couplings and the fidelity
level (``incompressible`` / ``compressible`` / ``lines``, :data:`hydraulics.network.FIDELITIES`)
(:func:`sweep_settings`), runs every setting through :func:`sim.tools.sweep.run_sweep` (a local
process pool, or a Dask cluster with ``--scheduler``), and measures per setting

* the cost: wall-clock seconds per simulated second, the median of ``repeats`` runs
  (timings depend on the machine and on what else runs; the errors do not), and
* the errors against the converged reference (:mod:`sim.tools.reference`): the largest and RMS
  error of joint positions, strokes and pressures (:mod:`sim.tools.compare`), plus the energy
  drift and whether the run diverged.

A setting that cannot run is a result with status ``error``; its error text (exception type and message,
one line) is in the rows and the ``error`` column of ``tradeoff.csv``, and it is not cached.  With
``--scheduler`` the scene's files travel to the workers as content (:func:`sim.tools.sweep.scene_bundle`),
every worker first runs :func:`warm_up_points`, and ``--worker-timeout`` bounds the wait for a worker.

Writes ``tradeoff.csv`` (one row per setting), ``pareto.png`` (error against cost,
log-log, Pareto fronts drawn) and ``tradeoff.md`` naming the Pareto-optimal settings, e.g.
"for ≤ 1 mm stroke error the fastest setting is …".  The dt ladder keeps every step a
divisor (or a multiple) of the log period, so runs and reference log at common instants.

Fidelity: the reference is at the scenario's own level unless ``reference_fidelity`` (``--reference-fidelity``)
names another (``lines`` measures what lumping the hoses costs as well); a setting at another level than
the scenario's is uniform (its per-actuator ``[fidelity]`` overrides dropped).  Its errors then include
the model's simplification, which is what tells whether ``incompressible`` is good enough.
"""

from __future__ import annotations

import csv
import io
import math
import statistics
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydraulics.components import CircuitError
from hydraulics.extras import require

from sim.io.files import check_outputs, write_output
from sim.tools.sweep import WORKER_TIMEOUT, Cluster, point_file, run_sweep, scene_bundle

__all__ = [
    "ERROR_COLUMNS",
    "TradeoffResult",
    "code_hash",
    "dt_ladder",
    "error_rows",
    "pareto_front",
    "pareto_statements",
    "reference_floors",
    "run_point",
    "sweep_plan",
    "sweep_points",
    "stability_statements",
    "sweep_settings",
    "tradeoff",
    "warm_up_points",
]

DEFAULT_REPEATS = 3
QUICK_REPEATS = 1
WARM_UP_STEPS = 20  # steps of the untimed warm-up run per worker process, mode and coupling
REPEAT_BELOW_S = 10.0  # s of wall time: a run longer than this is timed once, not `repeats` times
FRESH_CACHES = frozenset({"reference", "sweep"})  # the caches `tradeoff(fresh=...)` can ignore
KIND_SCALE = {"joint": (1e3, "mrad"), "stroke": (1e3, "mm"), "pressure": (1e-5, "bar")}  # display factor, unit
ERROR_COLUMNS = ("status", "diverged_at_s", "joint_max", "joint_rms", "stroke_max_m", "stroke_rms_m",
                 "pressure_max_pa", "pressure_rms_pa", "energy_drift_rel")
SETTING_COLUMNS = ("label", "mode", "coupling", "fidelity", "dt_s", "hydraulic_substeps", "pbd_substeps", "pbd_iterations")
COST_COLUMNS = ("wall_per_sim_s", "wall_per_sim_s_runs")


def code_hash() -> str:
    """Content hash of the simulation code (``hydraulics/`` and ``sim/`` minus the analysis tools), see :func:`sim.tools.sweep.code_hash`."""
    from sim.tools.sweep import code_hash as simulation_code_hash

    return simulation_code_hash()


def dt_ladder(scenario, exponents) -> list[float]:
    """Steps ``≈ dt0 · 2**k`` for ``k`` in ``exponents``, each a divisor or a multiple of the log period.

    ``dt0`` is the scenario's dt rounded down to ``period / n``. Coarser steps are rounded to
    ``period / round(n / 2**k)`` (or ``period · round(2**k / n)`` beyond the period).
    """
    from sim.tools.reference import start_step

    period = 1.0 / scenario.log_rate_hz
    n0 = round(period / start_step(scenario))
    out = []
    for k in exponents:
        ratio = n0 / 2.0**k
        dt = period / round(ratio) if ratio >= 1 else period * max(1, round(1 / ratio))
        if not any(math.isclose(dt, d, rel_tol=1e-9) for d in out):
            out.append(dt)
    return out


def sweep_settings(scenario, *, quick: bool = False, modes=None, fidelities=None) -> list[dict]:
    """The settings to sweep: dicts of mode, coupling, fidelity, dt, hydraulic_substeps, pbd_substeps, pbd_iterations.

    ``dt0`` is the scenario's step (see :func:`dt_ladder`). Full sweep:

    - MuJoCo implicit at dt0·{4, 2, 1, 1/2, …, 1/16} and explicit at dt0·{2, 1, 1/2, …, 1/32}, each with
      1 and 4 hydraulic substeps; MuJoCo rosenbrock (one hydraulic substep: no Newton solve) at
      dt0·{4, 2, 1, 1/2, …, 1/16};
    - PBD implicit at dt0·{2, 1, 1/2} × {5, 10, 20} substeps with at most 20 substeps per dt0 (its cost
      grows with the substep rate), 1 iteration, plus 4 iterations at dt0 × 10 substeps; PBD explicit at
      dt0·{1, 1/2} × 20 substeps;
    - naive PBD at dt0·{1, 1/2} × {10, 20} substeps.

    Quick: MuJoCo implicit at dt0·{2, 1, 1/2, 1/4}, explicit at dt0·{1, 1/2, 1/4, 1/8}, PBD implicit at
    dt0 × {10, 20} substeps, naive PBD at dt0·{1, 1/2} × 20 substeps.

    All of these at the scenario's fidelity.  Other levels (``fidelities``; default every level,
    quick: the scenario's and ``incompressible``), MuJoCo mode implicit:

    - ``incompressible`` at dt0·{32, 4, 1} (≈ 1/30 s at a 1 kHz scenario: a frame-rate step), and in
      PBD mode at dt0 × 10 substeps; quick: dt0·{32, 1};
    - ``compressible`` / ``lines`` at dt0·{2, 1, 1/2}; quick: dt0 (not when the circuit has no hoses:
      the two levels then build the same network).
    """
    from sim.tools.compare import pbd_available

    from hydraulics.network import FIDELITIES

    if modes is None:
        modes = ["mujoco", "pbd", "pbd-naive"] if pbd_available()[0] else ["mujoco"]
    if fidelities is None:
        fidelities = (scenario.fidelity, "incompressible") if quick else FIDELITIES
    bad = [f for f in fidelities if f not in FIDELITIES]
    if bad:
        raise CircuitError(f"fidelities {bad} are not among {list(FIDELITIES)}")
    s = scenario
    out = []
    level = scenario.fidelity

    def add(mode, coupling, exps, hyd=(1,), sub=(None,), it=(None,), max_rate=math.inf):
        for k, dt in zip(exps, dt_ladder(scenario, exps)):
            for h in hyd:
                for n in sub:
                    if n is not None and n * 2.0 ** (-k) > max_rate:
                        continue
                    for i in it:
                        setting = {"mode": mode, "coupling": coupling, "fidelity": level, "dt": dt, "hydraulic_substeps": h,
                                   "pbd_substeps": n if n is not None else s.pbd_substeps,
                                   "pbd_iterations": i if i is not None else s.pbd_iterations}
                        if setting not in out:
                            out.append(setting)

    if "mujoco" in modes:
        if quick:
            add("mujoco", "implicit", (1, 0, -1, -2))
            add("mujoco", "explicit", (0, -1, -2, -3))
        else:
            add("mujoco", "implicit", (2, 1, 0, -1, -2, -3, -4), hyd=(1, 4))
            add("mujoco", "rosenbrock", (2, 1, 0, -1, -2, -3, -4))
            add("mujoco", "explicit", (1, 0, -1, -2, -3, -4, -5), hyd=(1, 4))
    if "pbd" in modes:
        if quick:
            add("pbd", "implicit", (0,), sub=(10, 20), it=(1,))
        else:
            add("pbd", "implicit", (1, 0, -1), sub=(5, 10, 20), it=(1,), max_rate=20)
            add("pbd", "implicit", (0,), sub=(10,), it=(4,))
            add("pbd", "explicit", (0, -1), sub=(20,), it=(1,))
    if "pbd-naive" in modes:
        if quick:
            add("pbd-naive", "explicit", (0, -1), sub=(20,), it=(1,))
        else:
            add("pbd-naive", "explicit", (0, -1), sub=(10, 20), it=(1,))
    if scenario.fidelity == "incompressible":
        out = [o for o in out if o["mode"] != "pbd-naive"]  # the naive scheme needs pressure states
    from hydraulics.circuit import load_circuit

    has_hoses = bool(load_circuit(scenario.circuit).by_kind("hose"))
    for level in dict.fromkeys(fidelities):
        if level == scenario.fidelity or (not has_hoses and "incompressible" not in (level, scenario.fidelity)):
            continue  # without hoses 'lines' and 'compressible' build the same network
        if level == "incompressible":
            if "mujoco" in modes:
                add("mujoco", "implicit", (5, 0) if quick else (5, 2, 0))
            if "pbd" in modes and not quick:
                add("pbd", "implicit", (0,), sub=(10,), it=(1,))
        elif "mujoco" in modes:
            add("mujoco", "implicit", (0,) if quick else (1, 0, -1))
    return out


def setting_label(p: dict, default_fidelity: str | None = None) -> str:
    """``mujoco implicit dt 1 ms``, ``… ×4 hydraulic substeps``, ``pbd dt 1 ms 20 substeps × 1 iterations``,
    with ``[incompressible]`` appended when the setting's fidelity is not ``default_fidelity``."""
    text = f"{p['mode']} {p['coupling']} dt {p['dt'] * 1e3:.4g} ms"
    if p["mode"] == "mujoco":
        if p["hydraulic_substeps"] != 1:
            text += f" ×{p['hydraulic_substeps']} hydraulic substeps"
    else:
        coupling = "" if p["mode"] == "pbd-naive" else f" {p['coupling']}"  # the naive scheme is always explicit
        text = f"{p['mode']}{coupling} dt {p['dt'] * 1e3:.4g} ms, {p['pbd_substeps']} substeps × {p['pbd_iterations']} iterations"
    fidelity = p.get("fidelity")
    if fidelity is not None and fidelity != default_fidelity:
        text += f" [{fidelity}]"
    return text


def sweep_plan(scenario, settings: list[dict], *, repeats: int):
    """Sweep points and the :class:`~sim.tools.sweep.Bundle` of the scene's files they name.

    A point is a setting plus what its result depends on: the bundle's digest (the contents and layout of
    the MJCF with its includes and assets, the circuit, the scenario and its inputs CSV), the scenario's
    path inside the bundle, the code hash, duration and repeats -- no path of this machine.
    """
    bundle, rel = scene_bundle(scenario)
    code = code_hash()
    points = [{**setting, "fidelity": setting.get("fidelity", scenario.fidelity), "scenario_fidelity": scenario.fidelity,
               "scenario": rel, "bundle": bundle.digest, "code": code, "duration": scenario.duration,
               "repeats": repeats, "repeat_below_s": REPEAT_BELOW_S} for setting in settings]
    return points, bundle


def sweep_points(scenario, settings: list[dict], *, repeats: int) -> list[dict]:
    """The points of :func:`sweep_plan`."""
    return sweep_plan(scenario, settings, repeats=repeats)[0]


def _overrides(point: dict) -> dict:
    overrides = {k: point[k] for k in ("mode", "coupling", "dt", "hydraulic_substeps", "pbd_substeps", "pbd_iterations",
                                       "duration")}
    if point.get("fidelity") is not None and point["fidelity"] != point.get("scenario_fidelity"):
        overrides.update(fidelity=point["fidelity"], actuator_fidelity={})  # another level: the whole network at it
    return overrides


def run_point(point: dict) -> dict:
    """Sweep worker: run one setting ``repeats`` times (once if a run takes over ``repeat_below_s``);
    cost, status and the compared signals of the run.

    Returns
    -------
    dict
        ``status``, ``diverged_at_s``, ``message``, ``wall_per_sim_s`` (median), ``wall_per_sim_s_runs``,
        ``energy`` (:func:`sim.tools.compare.energy_drift`) and ``signals`` ``{name: {"kind", "t", "y"}}``
        (NaN where not finite). A run that raises gives ``status = "error"`` and the message.
    """
    from sim.tools.compare import energy_drift, log_signals, log_status
    from sim.io.mcap_log import read_log
    from sim.run.runner import run

    overrides = _overrides(point)
    scenario = point_file(point)
    costs = []
    with tempfile.TemporaryDirectory(prefix="hydroplant-tradeoff-") as tmp:
        try:
            _warm_up(point, overrides, Path(tmp))
            for r in range(point["repeats"]):
                result = run(scenario, out=Path(tmp) / f"run{r}.mcap", overrides=overrides)
                costs.append(result.wall_time / result.simulated_time if result.simulated_time > 0 else math.inf)
                if result.wall_time > point["repeat_below_s"]:
                    break  # long runs are timed once
            log = read_log(result.log_path)
        except Exception as exc:  # a setting the plant refuses is a result, not a crash of the sweep
            return {"status": "error", "message": f"{type(exc).__name__}: {exc}", "diverged_at_s": math.nan,
                    "wall_per_sim_s": math.nan, "wall_per_sim_s_runs": costs, "energy": {}, "signals": {}}
        status, when = log_status(log)
        signals = {name: {"kind": s.kind, "t": s.t.tolist(), "y": s.y.tolist()} for name, s in log_signals(log).items()}
        return {"status": status, "message": result.message, "diverged_at_s": when if status == "diverged" else math.nan,
                "wall_per_sim_s": statistics.median(costs), "wall_per_sim_s_runs": costs, "energy": energy_drift(log),
                "signals": signals}


_WARM: set = set()  # (scenario, mode, coupling) already run in this worker process


def _warm_up(point: dict, overrides: dict, tmp: Path) -> None:
    """One short untimed run per scenario, mode and coupling in each worker process, so that one-time costs
    (imports, compilation, caches) are not charged to the first timed setting."""
    from sim.run.runner import run

    key = (point_file(point), point["mode"], point["coupling"], point.get("fidelity"))
    if key in _WARM:
        return
    short = {**overrides, "duration": min(point["duration"], WARM_UP_STEPS * point["dt"])}
    run(point_file(point), out=tmp / "warm-up.mcap", overrides=short)
    _WARM.add(key)


def warm_up_points(points: list[dict]) -> None:
    """The untimed warm-up run of every scenario, mode, coupling and fidelity among ``points``, in this process
    (on each Dask worker before the timed points: imports and kernel compilation charged to no setting).
    A setting that fails here fails again, and is reported, as a point."""
    with tempfile.TemporaryDirectory(prefix="hydroplant-warm-up-") as tmp:
        for point in points:
            try:
                _warm_up(point, _overrides(point), Path(tmp))
            except Exception:  # noqa: BLE001 -- the point itself reports it
                continue


def error_rows(points: list[dict], results: list[dict], ref_signals: dict, filter_window: float | None = None) -> list[dict]:
    """One row per point: settings, cost and errors against the reference signals (SI units).

    ``filter_window`` [s]: errors of the signals averaged over a centred moving window
    (:func:`sim.tools.compare.filtered_error_stats`) instead of point-wise.
    """
    from sim.tools.compare import error_stats, filtered_error_stats

    rows = []
    for p, r in zip(points, results):
        row = {"label": setting_label(p, p.get("scenario_fidelity")), "mode": p["mode"], "coupling": p["coupling"],
               "fidelity": p.get("fidelity", p.get("scenario_fidelity")), "dt_s": p["dt"],
               "hydraulic_substeps": p["hydraulic_substeps"], "pbd_substeps": p["pbd_substeps"],
               "pbd_iterations": p["pbd_iterations"], "status": r["status"], "diverged_at_s": r["diverged_at_s"],
               "error": error_text(r),
               "wall_per_sim_s": r["wall_per_sim_s"], "wall_per_sim_s_runs": " ".join(f"{c:.4g}" for c in r["wall_per_sim_s_runs"]),
               "message": " ".join(str(r.get("message") or "").split())}
        worst = {kind: (math.nan, math.nan) for kind in KIND_SCALE}
        for name, ref in ref_signals.items():
            sig = r["signals"].get(name)
            if sig is None:
                continue
            t, y = np.array(sig["t"]), np.array(sig["y"], dtype=float)
            s = (error_stats(ref.t, ref.y, t, y) if filter_window is None
                 else filtered_error_stats(ref.t, ref.y, t, y, window=filter_window))
            if s.samples:
                m, q = worst[ref.kind]
                worst[ref.kind] = (np.fmax(m, s.max_abs), np.fmax(q, s.rms))
        row["joint_max"], row["joint_rms"] = map(float, worst["joint"])
        row["stroke_max_m"], row["stroke_rms_m"] = map(float, worst["stroke"])
        row["pressure_max_pa"], row["pressure_rms_pa"] = map(float, worst["pressure"])
        row["energy_drift_rel"] = float(r["energy"].get("relative", math.nan)) if r["energy"] else math.nan
        rows.append(row)
    return rows


def error_text(result: dict) -> str:
    """The one-line error of a point that could not run (exception type and message), or ``""``."""
    if result.get("status") != "error":
        return ""
    return " ".join(str(result.get("message") or "error (no message)").split())


def error_table(rows: list[dict]) -> list[tuple]:
    """The engine-independent part of the rows: settings and errors, no timings."""
    def plain(v):
        return None if isinstance(v, float) and math.isnan(v) else v  # NaN != NaN; None == None

    return [tuple(plain(row[c]) for c in SETTING_COLUMNS + ERROR_COLUMNS) for row in rows]


KIND_COLUMN = {"joint": "joint_max", "stroke": "stroke_max_m", "pressure": "pressure_max_pa"}


def _feasible(row) -> bool:
    return row["status"] == "complete" and math.isfinite(row["wall_per_sim_s"])


def pareto_front(rows: list[dict], kind: str = "stroke") -> list[int]:
    """Indices of the Pareto-optimal stable rows for (cost, max error of ``kind``), cheapest first."""
    column = KIND_COLUMN[kind]
    candidates = sorted((i for i, r in enumerate(rows) if _feasible(r) and math.isfinite(r[column])),
                        key=lambda i: (rows[i]["wall_per_sim_s"], rows[i][column]))
    front, best = [], math.inf
    for i in candidates:
        if rows[i][column] < best:
            front.append(i)
            best = rows[i][column]
    return front


def pareto_statements(rows: list[dict], kind: str = "stroke", floor: float = 0.0) -> list[str]:
    """"for ≤ 1 mm stroke error, the fastest setting is …" for decade thresholds spanning the front.

    Thresholds below ``floor`` (the reference's own accuracy, SI units) are not stated.
    """
    column = KIND_COLUMN[kind]
    factor, unit = KIND_SCALE[kind]
    front = pareto_front(rows, kind)
    if not front:
        return [f"no stable setting to rank by {kind} error"]
    errors = [rows[i][column] * factor for i in front]
    lo = math.floor(math.log10(max(min(errors), 1e-12)))
    hi = math.ceil(math.log10(max(max(errors), 1e-12)))
    out = []
    for e in range(lo, hi + 1):
        threshold = 10.0**e
        if threshold < floor * factor:
            continue  # not resolved by the reference
        ok = [i for i in front if rows[i][column] * factor <= threshold]
        if not ok:
            continue
        i = ok[0]  # front is cheapest first
        text = (f"for ≤ {threshold:g} {unit} {kind} error, the fastest setting is {rows[i]['label']} "
                f"({rows[i]['wall_per_sim_s']:.3g} s wall per simulated s, max {kind} error {rows[i][column] * factor:.3g} {unit})")
        if not out or not out[-1].endswith(text.split(", the fastest setting is ")[1]):
            out.append(text)
    return out


def stability_statements(rows: list[dict]) -> list[str]:
    """Per mode and coupling: the largest stable step and the smallest that was not."""
    groups: dict[str, list] = {}
    for r in rows:
        key = r["mode"] if r["mode"] == "pbd-naive" else f"{r['mode']} {r['coupling']}"
        if "[" in r["label"]:
            key += f" [{r.get('fidelity')}]"
        groups.setdefault(key, []).append(r)
    out = []
    for key, group in groups.items():
        stable = [r["dt_s"] for r in group if r["status"] == "complete"]
        unstable = [r["dt_s"] for r in group if r["status"] != "complete"]
        if not unstable:
            out.append(f"{key}: stable at every step tried (up to {max(stable) * 1e3:.4g} ms)")
        elif not stable:
            out.append(f"{key}: not stable at any step tried (down to {min(unstable) * 1e3:.4g} ms)")
        else:
            mixed = [d for d in unstable if d <= max(stable)]
            text = f"{key}: stable up to dt = {max(stable) * 1e3:.4g} ms, not stable from {min(d for d in unstable if d > max(stable)) * 1e3:.4g} ms" \
                if any(d > max(stable) for d in unstable) else f"{key}: largest stable dt {max(stable) * 1e3:.4g} ms"
            if mixed:
                text += f" (and not at {', '.join(f'{d * 1e3:.4g}' for d in sorted(set(mixed)))} ms with some substep settings)"
            out.append(text)
    return out


def reference_floors(report) -> dict:
    """Largest h → h/2 change of the reference per kind (SI units): errors below it are not resolved."""
    floors = {kind: 0.0 for kind in KIND_SCALE}
    for c in report.checks:
        if math.isfinite(c.change):
            floors[c.kind] = max(floors[c.kind], c.change)
    return floors


def write_csv(rows: list[dict], path) -> Path:
    columns = SETTING_COLUMNS + ERROR_COLUMNS + COST_COLUMNS + ("pareto_stroke", "pareto_pressure", "error")
    fronts = {kind: set(pareto_front(rows, kind)) for kind in ("stroke", "pressure")}
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(columns)
    for i, row in enumerate(rows):
        values = ([row[c] for c in columns[:-3]] + [i in fronts["stroke"], i in fronts["pressure"]]
                  + [row.get("error", "")])
        w.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in values])
    return write_output(path, lambda f: f.write(text.getvalue().encode()), what="table")


MARKERS = {(True, "implicit"): "o", (True, "explicit"): "s", (True, "rosenbrock"): "D", (False, "implicit"): "^",
           (False, "explicit"): "v"}  # (MuJoCo?, coupling)
FIDELITY_MARKERS = {"incompressible": "D", "lines": "P", "compressible": "h"}  # settings at another level than the scenario's
MODE_COLORS = {"mujoco": "tab:blue", "pbd": "tab:green", "pbd-naive": "tab:red"}


def pareto_figure(rows: list[dict], path, *, title: str = "", kinds=("stroke", "pressure")) -> Path:
    """Log-log error against cost per kind; diverged settings on the top edge; the Pareto front as a step line."""
    from sim.tools.compare import _pyplot

    plt = _pyplot()
    from matplotlib import ticker

    fig, axes = plt.subplots(1, len(kinds), figsize=(5 * len(kinds), 4.2), squeeze=False, layout="constrained")
    for ax, kind in zip(axes[0], kinds):
        column = KIND_COLUMN[kind]
        factor, unit = KIND_SCALE[kind]
        stable = [r for r in rows if _feasible(r) and math.isfinite(r[column]) and r[column] > 0]
        top = max((r[column] * factor for r in stable), default=1.0) * 3
        groups = {}  # legend: one proxy per mode and coupling, in order of appearance
        any_diverged = False
        for r in rows:
            if not math.isfinite(r["wall_per_sim_s"]):
                continue
            color = MODE_COLORS.get(r["mode"], "tab:gray")
            marker = MARKERS.get((r["mode"] == "mujoco", r["coupling"]), "o")
            key = (r["mode"], "" if r["mode"] == "pbd-naive" else r["coupling"])
            if "[" in r["label"]:  # at another fidelity than the scenario's
                marker = FIDELITY_MARKERS.get(r.get("fidelity"), marker)
                key = key + (f"[{r.get('fidelity')}]",)
            groups.setdefault(" ".join(k for k in key if k), (color, marker))
            filled = r["hydraulic_substeps"] == 1 if r["mode"] == "mujoco" else r["pbd_iterations"] == 1
            if _feasible(r) and r in stable:
                ax.scatter(r["wall_per_sim_s"], r[column] * factor, c=color if filled else "none", edgecolors=color,
                           marker=marker, s=28, zorder=3)
            else:
                ax.scatter(r["wall_per_sim_s"], top, c=color, marker="x", s=28, zorder=3)
                any_diverged = True
        for label, (color, marker) in groups.items():
            ax.scatter([], [], c=color, marker=marker, s=28, label=label)
        if any_diverged:
            ax.scatter([], [], c="tab:gray", marker="x", s=28, label="not stable (drawn at the top edge, in its colour)")
        front = pareto_front(rows, kind)
        if front:
            xs = [rows[i]["wall_per_sim_s"] for i in front]
            ys = [rows[i][column] * factor for i in front]
            ax.step(xs, ys, where="post", color="k", lw=0.8, alpha=0.6, label="Pareto front", zorder=2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            axis.set_minor_formatter(ticker.NullFormatter())
        ax.set_xlabel("cost [s wall per s simulated]", fontsize=8)
        ax.set_ylabel(f"max {kind} error [{unit}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3, which="both")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 4), fontsize=7, frameon=False)
    if title:
        fig.suptitle(title + "  (open markers: hydraulic substeps or PBD iterations > 1)", fontsize=9)
    try:
        return write_output(path, lambda f: fig.savefig(f, format="png", dpi=90), what="figure")
    finally:
        plt.close(fig)


@dataclass
class TradeoffResult:
    rows: list
    csv_path: Path
    figure_path: Path | None  # None when no setting finished with a cost to draw
    report_path: Path
    statements: dict
    reference_text: str


def evaluate(scenario, settings: list[dict], reference_log, *, repeats: int = DEFAULT_REPEATS, scheduler=None,
             workers=None, cache_dir=None, progress=None, filter_window: float | None = None, fresh: bool = False,
             worker_timeout: float = WORKER_TIMEOUT) -> list[dict]:
    """Run the settings through :func:`sim.tools.sweep.run_sweep` and return the error rows against ``reference_log``
    (``filter_window``: see :func:`error_rows`; ``fresh``: every point computed again, none read from the cache).

    With a ``scheduler`` the scene's files travel to the workers as content (:func:`sweep_plan`), each worker
    first runs :func:`warm_up_points`, and ``worker_timeout`` [s] bounds the wait for a first worker."""
    from sim.tools.compare import log_signals
    from sim.io.mcap_log import read_log

    points, bundle = sweep_plan(scenario, settings, repeats=repeats)
    # The reference is not in the points: the workers return signals, the errors are computed here.
    results = run_sweep(run_point, points, scheduler=scheduler, workers=workers, cache_dir=cache_dir, progress=progress,
                        fresh=fresh, bundles=[bundle], worker_timeout=worker_timeout, warm_up=warm_up_points)
    return error_rows(points, results, log_signals(read_log(reference_log)), filter_window)


OUTPUT_NAMES = ("tradeoff.csv", "pareto.png", "tradeoff.md")
"""What tradeoff writes into its folder (each checked first, and written without following a link)."""


def tradeoff(scenario, out_dir, *, cluster: Cluster = Cluster(), quick: bool = False, modes=None,
             repeats=None, tolerance=None, cache_dir=None, sweep_cache=None, fresh=frozenset(),
             progress: bool = False, fidelities=None, reference_fidelity: str | None = None,
             filter_window: float | None = None) -> TradeoffResult:
    """The full sweep of a scenario; writes ``tradeoff.csv``, ``pareto.png`` and ``tradeoff.md`` into ``out_dir``.

    ``cluster``: where the settings run (:class:`~sim.tools.sweep.Cluster`: a Dask scheduler with its
    worker timeout, or a local pool of ``workers`` processes).

    ``fidelities`` are the levels swept (see :func:`sweep_settings`); ``reference_fidelity`` the level of
    the reference (default: the scenario's own, per-actuator overrides included). ``filter_window`` [s]
    compares the signals averaged over a centred moving window, for the reference's convergence and the
    errors alike (for runs whose point-wise signals never converge, e.g. the whole excavator dig with
    the teeth's stick-slip in the soil). ``fresh``: the caches to ignore, any of ``"reference"`` and
    ``"sweep"`` (results are still written to them).  ``scenario``: a :class:`~sim.io.scenario.Scenario`
    or its path (``as_scenario(path, duration=...)`` for a shorter run).
    """
    from sim.tools.reference import DEFAULT_CACHE_DIR, compute_reference
    from sim.io.scenario import as_scenario

    scenario = as_scenario(scenario)
    unknown = set(fresh) - FRESH_CACHES
    if unknown:
        raise ValueError(f"fresh: {sorted(unknown)} not among {sorted(FRESH_CACHES)}")
    out_dir = Path(out_dir)
    check_outputs(out_dir, OUTPUT_NAMES, [scenario.path, scenario.circuit, scenario.mjcf], what="tradeoff output")
    out_dir.mkdir(parents=True, exist_ok=True)
    reference_scenario = scenario
    if reference_fidelity is not None and reference_fidelity != scenario.fidelity:
        reference_scenario = scenario.with_overrides(fidelity=reference_fidelity, actuator_fidelity={})
    reference = compute_reference(reference_scenario, tolerance=tolerance, cache_dir=cache_dir or DEFAULT_CACHE_DIR,
                                  fresh="reference" in fresh, progress=progress, filter_window=filter_window)
    settings = sweep_settings(scenario, quick=quick, modes=modes, fidelities=fidelities)
    repeats = repeats or (QUICK_REPEATS if quick else DEFAULT_REPEATS)

    from sim.progress import Progress

    report = Progress(len(settings), "tradeoff", "settings") if progress else None

    cache = Path(sweep_cache) if sweep_cache else Path(".cache/sweeps") / f"{scenario.scene_name}-{scenario.name}"
    rows = evaluate(scenario, settings, reference.log_path, repeats=repeats, scheduler=cluster.scheduler,
                    workers=cluster.workers, cache_dir=cache, progress=report, filter_window=filter_window,
                    fresh="sweep" in fresh, worker_timeout=cluster.worker_timeout)
    title = f"{scenario.scene_name}/{scenario.name}, {scenario.duration:g} s"
    csv_path = write_csv(rows, out_dir / "tradeoff.csv")
    drawable = [r for r in rows if math.isfinite(r["wall_per_sim_s"])]
    fig = pareto_figure(rows, out_dir / "pareto.png", title=title) if drawable else None  # nothing to draw: no figure
    floors = reference_floors(reference.report)
    statements = {kind: pareto_statements(rows, kind, floors[kind]) for kind in ("stroke", "pressure", "joint")}
    ref_text = (f"{reference.settings_text()}, fidelity {reference_scenario.fidelity_label}; "
                f"{reference.report.text().splitlines()[0]}")
    lines = [f"# Accuracy against cost: {title}", "", f"Reference: {ref_text}", "",
             f"{len(rows)} settings. Cost: wall-clock time per simulated second, the median of {repeats} run(s) "
             f"(one for runs over {REPEAT_BELOW_S:g} s), {'on the workers of ' + str(cluster.scheduler) if cluster.scheduler else 'in a local process pool'}; "
             "timings vary with the machine and its load, errors do not. Errors: largest over the run against the reference"
             + (f" of the signals averaged over a centred {filter_window:g} s moving window" if filter_window else "") + "; "
             f"settings marked [level] run at that fidelity instead of the scenario's ({scenario.fidelity_label}), so their "
             "errors include the simpler model's.", ""]
    for kind in ("stroke", "pressure", "joint"):
        lines += [f"- {s}" for s in statements[kind]]
    floor_text = ", ".join(f"{floors[k] * KIND_SCALE[k][0]:.2g} {KIND_SCALE[k][1]} ({k})" for k in ("stroke", "pressure", "joint"))
    lines += ["", f"The reference is accurate to about its own h → h/2 change: {floor_text}; smaller thresholds are not "
              "stated, and errors near these values are the reference's as much as the setting's."]
    lines += ["", "Stability:", ""] + [f"- {s}" for s in stability_statements(rows)]
    failed = [r for r in rows if r["status"] != "complete"]
    if failed:
        lines += ["", f"{len(failed)} of {len(rows)} settings did not run stable: "
                  + "; ".join(f"{r['label']} ({r['status']}{': ' + r['message'] if r.get('message') else ''})" for r in failed)]
    lines += ["", f"![Pareto]({fig.name})" if fig else "No figure: no setting finished with a cost to draw.", "",
              pareto_table(rows), ""]
    report_path = write_output(out_dir / "tradeoff.md", lambda f: f.write("\n".join(lines).encode()), what="report")
    return TradeoffResult(rows, csv_path, fig, report_path, statements, ref_text)


def pareto_table(rows: list[dict], kinds=("stroke", "pressure")) -> str:
    """Markdown table of the settings on any Pareto front (cheapest first)."""
    chosen = sorted(set().union(*(pareto_front(rows, k) for k in kinds)), key=lambda i: rows[i]["wall_per_sim_s"])
    lines = ["| setting | cost [s/s] | joint max [mrad or mm] | stroke max [mm] | pressure max [bar] | energy drift |",
             "|---|---|---|---|---|---|"]
    for i in chosen:
        r = rows[i]
        lines.append(f"| {r['label']} | {r['wall_per_sim_s']:.3g} | {r['joint_max'] * 1e3:.3g} | {r['stroke_max_m'] * 1e3:.3g} | "
                     f"{r['pressure_max_pa'] * 1e-5:.3g} | {r['energy_drift_rel']:.2g} |")
    diverged = [r["label"] for r in rows if r["status"] != "complete"]
    if diverged:
        lines += ["", f"Not stable ({len(diverged)}): " + "; ".join(
            f"{r['label']} ({r['status']}{' at %.3g s' % r['diverged_at_s'] if r['status'] == 'diverged' else ''}"
            f"{': ' + r['error'] if r.get('error') else ''})"
            for r in rows if r["status"] != "complete")]
    return "\n".join(lines)


def add_parser(subparsers):
    """Register ``hydroplant tradeoff`` (declared in :func:`sim.commands.add_tradeoff`)."""
    from sim.commands import add_tradeoff

    return add_tradeoff(subparsers)


def result_json(result: TradeoffResult, exit_code: int) -> dict:
    """``tradeoff --json``: the document of docs/cli-json.md (SI units)."""
    from sim.methods import Method

    fronts = {kind: set(pareto_front(result.rows, kind)) for kind in ("stroke", "pressure", "joint")}
    settings = []
    for i, r in enumerate(result.rows):
        settings.append({
            "label": r["label"], "method": Method(r["mode"], r["coupling"]).name, "mode": r["mode"],
            "coupling": r["coupling"], "fidelity": r["fidelity"], "dt_s": r["dt_s"],
            "hydraulic_substeps": r["hydraulic_substeps"], "pbd_substeps": r["pbd_substeps"],
            "pbd_iterations": r["pbd_iterations"], "status": r["status"], "message": r.get("message", ""),
            "error": r.get("error", ""), "diverged_at_s": r["diverged_at_s"], "wall_per_sim_s": r["wall_per_sim_s"],
            "errors": {"joint_max": r["joint_max"], "joint_rms": r["joint_rms"], "stroke_max_m": r["stroke_max_m"],
                       "stroke_rms_m": r["stroke_rms_m"], "pressure_max_pa": r["pressure_max_pa"],
                       "pressure_rms_pa": r["pressure_rms_pa"]},
            "energy_drift_rel": r["energy_drift_rel"],
            "pareto": {kind: i in front for kind, front in fronts.items()},
        })
    failed = [r["label"] for r in result.rows if r["status"] != "complete"]
    return {
        "command": "tradeoff", "status": "partial" if failed else "ok", "exit_code": exit_code,
        "reference": result.reference_text, "csv": str(result.csv_path),
        "figure": str(result.figure_path) if result.figure_path else None, "report": str(result.report_path),
        "statements": result.statements, "settings": settings, "failed": failed,
    }


def main(args) -> int:
    """``hydroplant tradeoff``; returns the exit code: 0 every setting stable, 4 some diverged or failed (the report
    is written)."""
    from sim.cli import EXIT_OK, EXIT_PARTIAL, scenario_argument

    require("matplotlib", "tools", "hydroplant tradeoff")  # before any run: its figures are drawn at the end
    from sim.tools.reference import Tolerance
    from sim.io.scenario import MODES

    scenario_path = scenario_argument(args, "tradeoff")
    for name in ("duration", "tolerance", "filter_window", "worker_timeout"):
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise CircuitError(f"--{name.replace('_', '-')}: {value!r} must be a positive finite number")
    for name in ("workers", "repeats"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise CircuitError(f"--{name}: {value!r} must be >= 1")
    if args.scheduler is not None and not args.scheduler.startswith(("tcp://", "tls://", "inproc://", "ucx://")):
        raise CircuitError(f"--scheduler: {args.scheduler!r} is not a scheduler address like tcp://host:8786")
    if args.scheduler is not None:
        from sim.tools.sweep import check_scheduler, check_workers

        check_scheduler(args.scheduler)  # a closed port: one line now, not after the reference is computed
        check_workers(args.scheduler, args.worker_timeout or WORKER_TIMEOUT)  # a cluster without workers: the same
    modes = None
    if args.modes:
        modes = [m.strip() for m in args.modes.split(",") if m.strip()]
        bad = [m for m in modes if m not in MODES]
        if bad:
            raise CircuitError(f"--modes: {bad} not in {list(MODES)}")
    from hydraulics.network import FIDELITIES

    fidelities = None
    if args.fidelities:
        fidelities = [f.strip() for f in args.fidelities.split(",") if f.strip()]
        bad = [f for f in fidelities if f not in FIDELITIES]
        if bad or not fidelities:
            raise CircuitError(f"--fidelities: {bad or args.fidelities!r} not in {list(FIDELITIES)}")
    if args.reference_fidelity is not None and args.reference_fidelity not in FIDELITIES:
        raise CircuitError(f"--reference-fidelity: {args.reference_fidelity!r} is not one of {list(FIDELITIES)}")
    from sim.io.scenario import as_scenario, load_scenario

    scenario = load_scenario(scenario_path)
    out = args.out or Path("logs") / f"tradeoff-{scenario.scene_name}-{scenario.name}"
    fresh = FRESH_CACHES if args.fresh else {"reference"} if args.fresh_reference else frozenset()
    cluster = Cluster(args.scheduler, args.workers, args.worker_timeout or WORKER_TIMEOUT)
    result = tradeoff(as_scenario(scenario, duration=args.duration), out, cluster=cluster,
                      quick=args.quick, modes=modes, repeats=args.repeats,
                      tolerance=Tolerance(relative=args.tolerance) if args.tolerance else None,
                      fresh=fresh, progress=True, fidelities=fidelities,
                      reference_fidelity=args.reference_fidelity, filter_window=args.filter_window)
    failed = [r for r in result.rows if r["status"] != "complete"]
    code = EXIT_PARTIAL if failed else EXIT_OK
    as_json = getattr(args, "json", False)
    text = sys.stderr if as_json else sys.stdout
    for kind in ("stroke", "pressure"):
        for s in result.statements[kind]:
            print(s, file=text)
    print(f"table: {result.csv_path}\nfigure: {result.figure_path or 'none (no setting to draw)'}\n"
          f"report: {result.report_path}", file=text)
    if failed:
        errors = sum(1 for r in failed if r["status"] == "error")
        print(f"tradeoff: {len(failed)} of {len(result.rows)} settings did not run stable ({errors} failed with an "
              "error); exit status 4", file=sys.stderr)
    if as_json:
        from sim.jsonout import emit

        emit(result_json(result, code))
    return code
