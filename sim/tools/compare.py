"""``hydroplant compare``: runs of a scenario against its converged reference.

::

    hydroplant compare SCENARIO | --example NAME [--methods mujoco,mujoco:explicit,pbd,pbd-naive] [--out DIR] [--json]
    hydroplant compare REFERENCE.mcap RUN.mcap [RUN2.mcap ...] [--out DIR] [--json]

Exit status 0 when every run is stable, 4 when the report is written but some run diverged or did
not complete (:data:`sim.commands.EXIT_PARTIAL`), 2 for bad input.

The first form computes (or takes from the cache) the converged MuJoCo-mode reference of
the scenario (:mod:`sim.tools.reference`), runs each method (``mode`` or ``mode:coupling``, :mod:`sim.methods`), and
writes into ``--out``: one MCAP log per run, ``reference.mcap``, ``merged.mcap`` (topics
prefixed ``/reference/...``, ``/mujoco/...``, ``/pbd/...``; open it in Foxglove), and
``report.md`` with a table per run and PNG figures.  The second form does the same for
existing logs, the first one taken as the reference.

Compared signals (:func:`log_signals`): every scalar joint position [rad or m], every
cylinder stroke [m], every cylinder chamber and motor port pressure [Pa].  The error
metrics are pure functions of (time, value) arrays: :func:`align` puts two signals on
common times (the sparser of the two grids, over the span both cover, the other signal
interpolated linearly), :func:`error_stats` gives the maximum and RMS absolute error and
both relative to the reference's range.

Where point-wise errors are not a meaningful measure -- the excavator's teeth stick-slipping
through the soil at ~6 Hz, where the instant of each slip moves with the step and point-wise
differences of pressures stay large at any affordable step -- :func:`filtered_error_stats`
compares the signals after a centred moving average over a stated window
(:func:`moving_average`, default :data:`DEFAULT_FILTER_WINDOW` = 0.1 s): an offset passes
unchanged, a delay ``d`` of a sine of frequency ω shows as ``2a·sin(ωd/2)·sinc(ωw/2)``,
and chatter faster than the window averages out. ``compare --filter-window`` reports both.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hydraulics.components import CircuitError
from hydraulics.extras import require

from sim.io.files import check_outputs, write_output
from sim.io.log_recover import verify_log
from sim.methods import DEFAULT_COUPLING, default_methods
from sim.io.mcap_log import RESULT_METADATA, RUN_METADATA, merge_logs, read_log
from sim.tools.signals import (CYLINDER_PREFIX, DEFAULT_FILTER_WINDOW, ENERGY_TOPIC, JOINT_TOPIC, KIND_DISPLAY, KIND_UNITS,  # noqa: F401
                               KINDS, MOTOR_PREFIX, TIME_MATCH_NS, ErrorStats, Signal, align, check_same_scene, energy_drift,
                               error_series, error_stats, filtered_error_stats, log_signals, log_status, moving_average,
                               richardson_first_order, scene_identity)

__all__ = [
    "ErrorStats",
    "KINDS",
    "RunComparison",
    "Signal",
    "align",
    "compare_logs",
    "compare_runs",
    "energy_drift",
    "error_series",
    "error_stats",
    "filtered_error_stats",
    "moving_average",
    "DEFAULT_FILTER_WINDOW",
    "log_signals",
    "log_status",
    "parse_runs",
]

# ---------------------------------------------------------------------------------------
# One run against the reference
# ---------------------------------------------------------------------------------------


@dataclass
class RunComparison:
    """A run log against the reference log.

    Attributes
    ----------
    label : str
        Run label (``mujoco``, ``pbd``, ``mujoco-explicit``, file stem ...).
    log_path : Path
    status : str
        ``complete``, ``diverged``, ``incomplete`` ...
    diverged_at : float
        Time of divergence [s] (NaN unless diverged).
    signals : dict of str to ErrorStats
        Per compared signal.
    wall_time, real_time_factor : float
        From the run (NaN for existing logs without them).
    energy : dict
        :func:`energy_drift` of the run.
    """

    label: str
    log_path: Path
    status: str
    diverged_at: float
    signals: dict = field(default_factory=dict)
    wall_time: float = math.nan
    real_time_factor: float = math.nan
    energy: dict = field(default_factory=dict)
    settings: str = ""
    filtered: dict = field(default_factory=dict)  # str -> ErrorStats of the moving averages (empty: not computed)
    filter_window: float = math.nan  # s

    def kind_stats(self, kind: str, filtered: bool = False) -> dict:
        """Worst signal of a kind: ``max_abs``, ``rms``, ``max_rel`` (maxima over its signals) and ``worst``.

        ``filtered=True``: of the moving-averaged signals (:func:`filtered_error_stats`).
        """
        source = self.filtered if filtered else self.signals
        rows = {n: s for n, s in source.items() if _kind_of(n) == kind and s.samples}
        if not rows:
            return {"max_abs": math.nan, "rms": math.nan, "max_rel": math.nan, "worst": ""}
        worst = max(rows, key=lambda n: rows[n].max_abs)
        return {
            "max_abs": rows[worst].max_abs,
            "rms": max(s.rms for s in rows.values()),
            "max_rel": max((s.max_rel for s in rows.values() if math.isfinite(s.max_rel)), default=math.nan),
            "worst": worst,
        }

    @property
    def stable(self) -> bool:
        return self.status == "complete"


def _kind_of(signal_name: str) -> str:
    head = signal_name.split(" ", 1)[0]
    return {"joint": "joint", "stroke": "stroke"}.get(head, "pressure")


def compare_logs(ref_log, log, *, label: str | None = None, wall_time: float = math.nan,
                 real_time_factor: float = math.nan, filter_window: float | None = None) -> RunComparison:
    """Compare a run log with the reference log (paths or :class:`RunLog`).

    ``filter_window`` [s]: also the errors of the signals averaged over that window
    (:func:`filtered_error_stats`), in ``RunComparison.filtered``.
    """
    ref_log = ref_log if hasattr(ref_log, "topic") else read_log(ref_log)
    log = log if hasattr(log, "topic") else read_log(log)
    check_same_scene(ref_log, log)
    ref, run = log_signals(ref_log), log_signals(log)
    stats = {name: error_stats(ref[name].t, ref[name].y, run[name].t, run[name].y) for name in ref if name in run}
    status, when = log_status(log)
    meta = log.metadata.get(RUN_METADATA, {})
    settings = run_settings_text(meta)
    filtered = {}
    if filter_window:
        filtered = {name: filtered_error_stats(ref[name].t, ref[name].y, run[name].t, run[name].y, filter_window)
                    for name in ref if name in run}
    return RunComparison(label or log.path.stem, log.path, status, when if status == "diverged" else math.nan, stats,
                         wall_time, real_time_factor, energy_drift(log), settings, filtered,
                         float(filter_window) if filter_window else math.nan)


def circuit_scales(log) -> dict:
    """Scales for relative errors from the circuit attached to a log.

    Returns
    -------
    dict
        ``"stroke"``: cylinder name -> stroke [m]; ``"relief_pa"``: the highest relief
        cracking pressure of the circuit [Pa] (NaN when none or no circuit attached).
    """
    import tomllib

    data = log.attachments.get("circuit.toml")
    out = {"stroke": {}, "relief_pa": math.nan}
    if data is None:
        return out
    try:
        circuit = tomllib.loads(data.decode() if isinstance(data, bytes) else str(data))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError):
        return out
    reliefs = []
    for comp in circuit.get("component", []):
        if not isinstance(comp, dict):
            continue
        if "stroke" in comp and "name" in comp:
            out["stroke"][comp["name"]] = float(comp["stroke"])
        if "relief" in str(comp.get("type", "")) and "cracking_pressure" in comp:
            reliefs.append(float(comp["cracking_pressure"]))
    if reliefs:
        out["relief_pa"] = max(reliefs)
    return out


def percent_table(comparisons: list, scales: dict) -> str:
    """Markdown: per run, the largest stroke error in % of that cylinder's stroke and the largest
    pressure error in % of the highest relief setting, point-wise and (when computed) filtered.  A circuit
    without a relief valve has no pressure columns, one without cylinders no stroke columns."""
    relief = scales.get("relief_pa", math.nan)
    strokes = scales.get("stroke", {})
    window = next((c.filter_window for c in comparisons if math.isfinite(c.filter_window)), math.nan)
    kinds = ([("stroke", "stroke max [% of stroke]", f"stroke, {window:g} s average [% of stroke]")] if strokes else []) \
        + ([("pressure", f"pressure max [% of {_num(relief / 1e5)} bar]",
             f"pressure, {window:g} s average [% of relief]")] if math.isfinite(relief) else [])
    head = ["run"] + [k[1] for k in kinds] + ([k[2] for k in kinds] if math.isfinite(window) else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def worst(source):
        rows = {"stroke": [(100 * v.max_abs / strokes[n.removeprefix("stroke ")], n) for n, v in source.items()
                           if n.startswith("stroke ") and n.removeprefix("stroke ") in strokes and v.samples],
                "pressure": [(100 * v.max_abs / relief, n) for n, v in source.items()
                             if _kind_of(n) == "pressure" and v.samples]}
        fmt = lambda found: f"{_num(max(found)[0])} ({max(found)[1]})" if found else "–"  # noqa: E731
        return [fmt(rows[kind]) for kind, _, _ in kinds]

    for c in comparisons:
        row = [c.label] + worst(c.signals)
        if math.isfinite(window):
            row += worst(c.filtered) if c.filtered else ["–"] * len(kinds)
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def run_settings_text(meta: dict) -> str:
    """Short description of a run's settings from its ``hydroplant.run`` metadata."""
    if not meta:
        return ""
    mode = meta.get("mode", "?")
    coupling = "" if mode == "pbd-naive" else f", {meta.get('coupling', '?')}"  # the naive scheme is always explicit
    text = f"{mode}{coupling}, dt {float(meta.get('dt_s', 'nan')):.4g} s"
    if mode == "mujoco" and meta.get("hydraulic_substeps", "1") != "1":
        text += f", {meta['hydraulic_substeps']} hydraulic substeps"
    if mode.startswith("pbd"):
        text += f", {meta.get('pbd_substeps', '?')} substeps × {meta.get('pbd_iterations', '?')} iterations"
    if meta.get("fidelity", "compressible") != "compressible":
        text += f", {meta['fidelity']}"
    return text


# ---------------------------------------------------------------------------------------
# Runs of a scenario
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunSpec:
    """One run of ``compare``: a mode and a coupling, and its label (merge prefix, file name)."""

    mode: str
    coupling: str
    label: str

    @property
    def method(self) -> str:
        """The method's name (:mod:`sim.methods`): ``mujoco:explicit``, ``pbd-naive``."""
        from sim.methods import Method

        return Method(self.mode, self.coupling).name


def pbd_available() -> tuple[bool, str]:
    """Whether the PBD modes can run here, and why not."""
    try:
        from sim.plants.pbd import make_pbd_plant  # noqa: F401
    except ImportError as exc:
        return False, f"the PBD plant is not available ({exc})"
    return True, ""


def default_modes() -> str:
    """:func:`sim.methods.default_methods`, comma-separated (PBD mode's when the PBD plant imports)."""
    return ",".join(default_methods(pbd_available()[0]))


def parse_runs(text: str, default_coupling: str = DEFAULT_COUPLING) -> list[RunSpec]:
    """Parse ``"mujoco,mujoco:explicit,pbd"`` into run specs.

    Each item is a method (:mod:`sim.methods`): ``mode`` or ``mode:coupling`` (a bare mode uses
    ``default_coupling``; the dash spelling ``mujoco-explicit`` is read with a deprecation warning). The
    label (file name and merge prefix) is the mode when that mode appears once, else ``mode-coupling``.
    """
    from sim.methods import MethodError, parse_methods

    try:
        methods = parse_methods(text, default_coupling)
    except MethodError as exc:
        raise CircuitError(f"--methods: {exc}") from None
    if any(m.blend for m in methods):
        raise CircuitError("--methods: compare runs no '+blend' method; use 'hydroplant run --pbd-blend'")
    counts = {m.mode: sum(1 for mm in methods if mm.mode == m.mode) for m in methods}
    return [RunSpec(m.mode, m.coupling, m.mode if counts[m.mode] == 1 else f"{m.mode}-{m.coupling}") for m in methods]


OUTPUT_NAMES = ("merged.mcap", "report.md", "overlay.png", "error.png")
"""What compare writes into its folder besides the run logs (``reference.mcap``, ``<label>.mcap``)."""


def _copy_into(source, stream) -> None:
    with open(source, "rb") as src:
        while block := src.read(1 << 20):
            stream.write(block)


@dataclass
class CompareResult:
    """What ``compare`` wrote."""

    reference_label: str
    reference_log: Path
    reference_text: str
    comparisons: list
    report_path: Path
    merged_path: Path | None
    figures: list


def compare_runs(scenario, specs: list[RunSpec], out_dir, *, dt: float | None = None, duration: float | None = None,
                 tolerance=None, cache_dir=None, fresh_reference: bool = False, progress: bool = False,
                 filter_window: float | None = None, reference_options: dict | None = None,
                 run_overrides: dict | None = None, figure_runs: list | None = None) -> CompareResult:
    """Reference + one run per spec of a scenario; logs, merged log, report and figures in ``out_dir``.

    ``filter_window`` [s]: the reference's convergence is checked on the signals averaged over
    that window (:func:`sim.tools.reference.check_convergence`), and the report adds the errors of the
    averaged signals. ``reference_options``: more keyword arguments of
    :func:`sim.tools.reference.compute_reference` (``start_dt``, ``max_steps`` …). ``run_overrides``:
    label -> scenario overrides for that run (e.g. ``{"pbd-40": {"pbd_substeps": 40}}``).
    ``figure_runs``: labels of the runs drawn in the figures (default all; the tables list all).
    """
    from sim.tools.reference import DEFAULT_CACHE_DIR, compute_reference
    from sim.run.runner import run
    from sim.io.scenario import as_scenario

    scenario = as_scenario(scenario, duration=duration)
    out_dir = Path(out_dir)
    check_outputs(out_dir, ["reference.mcap", *(f"{s.label}.mcap" for s in specs), *OUTPUT_NAMES],
                  [scenario.path, scenario.circuit, scenario.mjcf], what="compare output")
    out_dir.mkdir(parents=True, exist_ok=True)
    if any(s.mode.startswith("pbd") for s in specs):
        ok, why = pbd_available()
        if not ok:
            raise CircuitError(f"--modes: {why}; leave the pbd modes out")
    reference = compute_reference(scenario, tolerance=tolerance, cache_dir=cache_dir or DEFAULT_CACHE_DIR,
                                  fresh=fresh_reference, progress=progress, filter_window=filter_window,
                                  **(reference_options or {}))
    ref_copy = write_output(out_dir / "reference.mcap", lambda f: _copy_into(reference.log_path, f), what="compare output")
    ref_log = read_log(ref_copy)
    comparisons = []
    from sim.progress import Progress

    report = Progress(len(specs), "compare", "runs") if progress else None
    for done, spec in enumerate(specs, 1):
        path = out_dir / f"{spec.label}.mcap"
        overrides = {"mode": spec.mode, "coupling": spec.coupling, "dt": dt, **(run_overrides or {}).get(spec.label, {})}
        result = run(scenario, out=path, overrides=overrides, overwrite=True)  # compare's own files in its folder
        if report is not None:
            report(done, note=f"{spec.label}: {result.status}, {result.wall_time:.2f} s wall")
        comparisons.append(compare_logs(ref_log, path, label=spec.label, wall_time=result.wall_time,
                                        real_time_factor=result.real_time_factor, filter_window=filter_window))
    merged = out_dir / "merged.mcap"
    merge_logs({"reference": ref_copy, **{c.label: c.log_path for c in comparisons}}, merged, overwrite=True)
    title = f"{scenario.scene_name}/{scenario.name}, {scenario.duration:g} s"
    ref_text = f"{reference.settings_text()} ({'cached' if reference.cached else f'computed in {reference.wall_time:.0f} s'})"
    convergence_text = reference.report.text()
    if filter_window:  # the same pair point-wise, for the record
        from sim.tools.reference import check_convergence

        pointwise = check_convergence(reference.coarse_log_path, reference.log_path, reference.settings.tolerance)
        worst = sorted(pointwise.checks, key=lambda c: -(c.change / c.allowed if c.allowed > 0 else math.inf))[:3]
        convergence_text += (
            f"\n\nPoint-wise, the same pair is {'converged' if pointwise.converged else 'NOT converged'} at that tolerance"
            + (": " + "; ".join(f"{c.name} changes by {c.change * KIND_DISPLAY[c.kind][0]:.3g} {KIND_DISPLAY[c.kind][1]} "
                                f"at t = {c.t_max:.3g} s ({c.change / c.allowed:.2g}× allowed)" for c in worst) if worst else "")
            + ".")
    return _write_report(out_dir, title, "reference", ref_log, ref_text, convergence_text, comparisons, merged,
                         figure_runs=figure_runs)


def compare_existing(logs: list, out_dir, *, filter_window: float | None = None) -> CompareResult:
    """``compare A.mcap B.mcap …``: A is the reference (``filter_window`` as in :func:`compare_runs`)."""
    for path in logs:
        if not Path(path).is_file():
            raise CircuitError(f"{path}: log file not found")
    out_dir = Path(out_dir)
    check_outputs(out_dir, OUTPUT_NAMES, logs, what="compare output")  # never over an input: compare DIR/merged.mcap
    try:
        ref_log = read_log(logs[0])
        others = [read_log(p) for p in logs[1:]]
    except ValueError as exc:
        raise CircuitError(str(exc)) from None
    for log in (ref_log, *others):
        if RUN_METADATA not in log.metadata:
            raise CircuitError(f"{log.path}: not a hydroplant log (no '{RUN_METADATA}' metadata record; its topics: "
                               f"{', '.join(log.topics[:3]) or 'none'}); compare reads logs written by 'hydroplant run'")
    for path in logs:  # a damaged chunk would otherwise surface deep in a topic read or the merge
        if damage := verify_log(path).damage:
            raise CircuitError(f"{path}: damaged log ({damage[0].what} at bytes {damage[0].start}..{damage[0].end}); "
                               f"'hydroplant log recover {path}' keeps every chunk that checks")
    comparisons = []
    labels = set()
    for log in others:
        label = log.path.stem
        while label in labels or label == "reference":
            label += "_"
        labels.add(label)
        comparisons.append(compare_logs(ref_log, log, label=label, filter_window=filter_window))
    out_dir.mkdir(parents=True, exist_ok=True)
    meta = ref_log.metadata.get(RUN_METADATA, {})
    title = f"{meta.get('scene', '?')} logs: {', '.join(Path(p).name for p in logs)}"
    ref_text = f"{ref_log.path.name} ({run_settings_text(meta) or 'no run metadata'})"
    merged = out_dir / "merged.mcap"
    try:
        merge_logs({"reference": ref_log.path, **{c.label: c.log_path for c in comparisons}}, merged, overwrite=True)
    except ValueError:
        merged = None  # a prefix Foxglove would not like (file stem with odd characters): skip the merged log
    return _write_report(out_dir, title, "reference", ref_log, ref_text, "", comparisons, merged)


# ---------------------------------------------------------------------------------------
# Report and figures
# ---------------------------------------------------------------------------------------


def _num(value: float, digits: int = 3) -> str:
    return f"{value:.{digits}g}" if math.isfinite(value) else "–"


def _status_text(c: RunComparison) -> str:
    if c.status == "diverged":
        return f"diverged at {c.diverged_at:.4g} s"
    return "stable" if c.status == "complete" else c.status


def summary_table(comparisons: list, filtered: bool = False) -> str:
    """Markdown table: one row per run (``filtered``: errors of the moving-averaged signals)."""
    head = ["run", "settings", "status", "wall [s]", "RTF"]
    for kind in KINDS:
        unit = KIND_DISPLAY[kind][1]
        head += [f"{kind} max [{unit}]", f"{kind} RMS [{unit}]"]
    head += ["energy drift [J]", "drift / scale"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in comparisons:
        row = [c.label, c.settings or "–", _status_text(c), _num(c.wall_time), _num(c.real_time_factor)]
        for kind in KINDS:
            s = c.kind_stats(kind, filtered)
            factor = KIND_DISPLAY[kind][0]
            row += [_num(s["max_abs"] * factor), _num(s["rms"] * factor)]
        row += [_num(c.energy.get("max_abs_j", math.nan)), _num(c.energy.get("relative", math.nan))]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def signal_table(c: RunComparison) -> str:
    """Markdown table of one run: every signal's max and RMS error."""
    lines = ["| signal | max error | RMS error | max / range | at t [s] | compared until [s] |", "|---|---|---|---|---|---|"]
    for name, s in c.signals.items():
        factor, unit = KIND_DISPLAY[_kind_of(name)]
        lines.append(f"| {name} | {_num(s.max_abs * factor)} {unit} | {_num(s.rms * factor)} {unit} | "
                     f"{_num(100 * s.max_rel)} % | {_num(s.t_max, 4)} | {_num(s.t_end, 4)} |")
    return "\n".join(lines)


def _pyplot():
    matplotlib = require("matplotlib", "tools", "drawing the figures")

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


COLORS = ("tab:blue", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray", "tab:olive")


def overlay_figure(ref_log, comparisons: list, path, *, title: str = "", max_cylinders: int = 3) -> Path:
    """Reference vs every run: stroke and cap pressure of each cylinder over time (the seed's Figure 4); without
    cylinders the joints, or a test bench's node pressures."""
    plt = _pyplot()
    ref = log_signals(ref_log)
    runs = [(c.label, log_signals(read_log(c.log_path)), c) for c in comparisons]
    cylinders = [n.removeprefix("stroke ") for n in ref if n.startswith("stroke ")][:max_cylinders]
    panels = [(f"stroke {c}", f"p_cap {c}") for c in cylinders]
    if not panels:  # no cylinder: joints, or on a test bench the node pressures
        shown = [n for n in ref if n.startswith(("joint ", "p "))][:2 * max_cylinders]
        panels = [tuple(shown[i:i + 2]) for i in range(0, len(shown), 2)]
    rows = len(panels)
    fig, axes = plt.subplots(rows, 2, figsize=(10, 2.4 * rows + 1.0), squeeze=False, sharex=True, layout="constrained")
    for r, names in enumerate(panels):
        for k, name in enumerate(names):
            ax = axes[r][k]
            if name not in ref:
                ax.set_visible(False)
                continue
            sig = ref[name]
            factor, unit = KIND_DISPLAY[sig.kind]
            if sig.kind == "joint":
                factor, unit = 1.0, "rad or m"
            ax.plot(sig.t, sig.y * factor, color="tab:orange", lw=2.2, label="reference", zorder=1)
            lo, hi = np.nanmin(sig.y * factor), np.nanmax(sig.y * factor)
            pad = 0.25 * (hi - lo) + 1e-12
            for i, (label, sigs, c) in enumerate(runs):
                if name not in sigs:
                    continue
                s = sigs[name]
                y = np.where(np.isfinite(s.y), s.y * factor, np.nan)
                ax.plot(s.t, y, color=COLORS[i % len(COLORS)], lw=1.0, label=f"{label} ({_status_text(c)})", zorder=2)
                if c.status == "diverged":
                    ax.axvline(c.diverged_at, color=COLORS[i % len(COLORS)], ls=":", lw=0.8)
            ax.set_ylim(lo - pad, hi + pad)
            ax.set_ylabel(f"{name} [{unit}]", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]", fontsize=8)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 3), fontsize=7, frameon=False)
    if title:
        fig.suptitle(title, fontsize=9)
    try:
        return write_output(path, lambda f: fig.savefig(f, format="png", dpi=90), what="figure")
    finally:
        plt.close(fig)


def error_figure(ref_log, comparisons: list, path, *, title: str = "") -> Path:
    """Error over time of every run: per kind, the largest |error| over its signals (log scale)."""
    plt = _pyplot()
    ref = log_signals(ref_log)
    run_signals = [log_signals(read_log(c.log_path)) for c in comparisons]
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.0), squeeze=False)
    for k, kind in enumerate(KINDS):
        ax = axes[0][k]
        factor, unit = KIND_DISPLAY[kind]
        top = 0.0
        for i, (c, sigs) in enumerate(zip(comparisons, run_signals)):
            worst_t, worst_e = None, None
            for name, sig in ref.items():
                if sig.kind != kind or name not in sigs:
                    continue
                t, e = error_series(sig.t, sig.y, sigs[name].t, sigs[name].y)
                if worst_t is None:
                    worst_t, worst_e = t, np.abs(e)
                elif len(t) == len(worst_t):
                    worst_e = np.maximum(worst_e, np.abs(e))
            if worst_t is not None and len(worst_t):
                y = worst_e * factor
                top = max(top, float(np.max(y)))
                ax.semilogy(worst_t, np.maximum(y, 1e-30), color=COLORS[i % len(COLORS)], lw=1.0, label=c.label)
        if top > 0:
            ax.set_ylim(top * 1e-5, top * 2)  # five decades below the largest error
        ax.set_title(f"{kind} error [{unit}]", fontsize=8)
        ax.set_xlabel("t [s]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3, which="both")
    handles, labels = axes[0][0].get_legend_handles_labels()
    if handles:
        axes[0][0].legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    try:
        return write_output(path, lambda f: fig.savefig(f, format="png", dpi=90), what="figure")
    finally:
        plt.close(fig)


def _write_report(out_dir: Path, title: str, ref_label: str, ref_log, ref_text: str, convergence_text: str,
                  comparisons: list, merged, figure_runs: list | None = None) -> CompareResult:
    drawn = [c for c in comparisons if figure_runs is None or c.label in figure_runs]
    overlay = overlay_figure(ref_log, drawn, out_dir / "overlay.png", title=title)
    errors = error_figure(ref_log, drawn, out_dir / "error.png", title=title)
    left_out = [c.label for c in comparisons if c not in drawn]
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        f"# Comparison: {title}",
        "",
        f"Written {stamp}. Reference: {ref_text}.",
        "",
    ]
    if convergence_text:
        lines += [convergence_text, ""]
    lines += [
        "## Runs against the reference",
        "",
        "Errors are over the span each run covers (up to its divergence), on common sample times; "
        "joint errors in mrad (mm for slide joints), strokes in mm, pressures in bar. Energy drift: largest "
        "|pump work − Δ(kinetic + potential + oil) − dissipation| of the run; scale: the larger of the pump work "
        "and the largest kinetic + oil energy.",
        "",
        summary_table(comparisons),
        "",
    ]
    window = next((c.filter_window for c in comparisons if math.isfinite(c.filter_window)), math.nan)
    if math.isfinite(window):
        lines += [
            f"Errors of the signals averaged over a centred {window:g} s moving window (`filtered_error_stats`; "
            "chatter faster than the window averages out, offsets and slow drifts stay):",
            "",
            summary_table(comparisons, filtered=True),
            "",
        ]
    scales = circuit_scales(ref_log)
    if scales["stroke"] or math.isfinite(scales["relief_pa"]):
        lines += ["Relative to the machine: " + ", ".join(
                      ([] if not scales["stroke"] else ["stroke errors in % of each cylinder's stroke"])
                      + ([] if not math.isfinite(scales["relief_pa"]) else
                         ["pressure errors in % of the circuit's highest relief setting"]))
                  + " (worst signal in brackets):", "", percent_table(comparisons, scales), ""]
    lines += [
        f"![reference vs runs]({overlay.name})",
        "",
        f"![error over time]({errors.name})",
        "",
    ]
    if left_out:
        lines += [f"Not drawn in the figures (tables only): {', '.join(left_out)}.", ""]
    for c in comparisons:
        lines += [f"### {c.label}: {c.settings or c.log_path.name}, {_status_text(c)}", "", signal_table(c), ""]
    files = ["reference.mcap"] + [c.log_path.name for c in comparisons] + ([merged.name] if merged else [])
    lines += ["Logs: " + ", ".join(f"`{f}`" for f in files) + ("" if not merged else
              f" (`{merged.name}`: every log with topics prefixed `/<run>/`, for Foxglove)"), ""]
    report = write_output(out_dir / "report.md", lambda f: f.write("\n".join(lines).encode()), what="report")
    return CompareResult(ref_label, ref_log.path, ref_text, comparisons, report, merged, [overlay, errors])


# ---------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------


def add_parser(subparsers):
    """Register ``hydroplant compare`` (declared in :func:`sim.commands.add_compare`)."""
    from sim.commands import add_compare

    return add_compare(subparsers)


def _stats_json(s: ErrorStats) -> dict:
    return {"max_abs": s.max_abs, "rms": s.rms, "ref_range": s.ref_range, "max_rel": s.max_rel, "rms_rel": s.rms_rel,
            "t_max_s": s.t_max, "t_end_s": s.t_end, "samples": s.samples}


def run_json(c: RunComparison) -> dict:
    """One run of a :class:`CompareResult` as the ``runs`` item of ``compare --json`` (SI units)."""
    from sim.methods import Method

    meta = read_log(c.log_path).metadata.get(RUN_METADATA, {}) if Path(c.log_path).is_file() else {}
    method = Method(meta["mode"], meta.get("coupling", "implicit")).name if meta.get("mode") else None
    return {
        "label": c.label, "method": method, "settings": c.settings, "log": str(c.log_path), "status": c.status,
        "stable": c.stable, "diverged_at_s": c.diverged_at, "wall_time_s": c.wall_time,
        "real_time_factor": c.real_time_factor,
        "errors": {kind: c.kind_stats(kind) for kind in KINDS},
        "filtered_errors": {kind: c.kind_stats(kind, True) for kind in KINDS} if c.filtered else None,
        "filter_window_s": c.filter_window,
        "energy_drift": {"final_j": c.energy.get("final_j"), "max_abs_j": c.energy.get("max_abs_j"),
                         "relative": c.energy.get("relative")},
        "signals": {name: _stats_json(s) for name, s in c.signals.items()},
    }


def result_json(result: CompareResult, exit_code: int) -> dict:
    """``compare --json``: the document of docs/cli-json.md."""
    failed = [c.label for c in result.comparisons if not c.stable]
    return {
        "command": "compare", "status": "partial" if failed else "ok", "exit_code": exit_code,
        "reference": {"log": str(result.reference_log), "settings": result.reference_text},
        "report": str(result.report_path), "merged_log": str(result.merged_path) if result.merged_path else None,
        "figures": [str(f) for f in result.figures],
        "runs": [run_json(c) for c in result.comparisons],
        "failed": failed,
    }


def main(args) -> int:
    """``hydroplant compare``; returns the exit code: 0 every run stable, 4 some diverged or did not complete."""
    import sys

    from sim.cli import EXIT_OK, EXIT_PARTIAL

    require("matplotlib", "tools", "hydroplant compare")  # before any run: its figures are drawn at the end
    inputs = list(args.inputs)
    if getattr(args, "example", None):
        if inputs:
            raise CircuitError("compare: give either a SCENARIO file (or logs) or --example NAME, not both")
        from sim.io.examples import example_path

        inputs = [example_path(args.example)]
    if not inputs:
        raise CircuitError("compare: give a SCENARIO file, --example NAME, or two or more .mcap logs")
    if all(p.suffix == ".mcap" for p in inputs):
        if len(inputs) < 2:
            raise CircuitError(f"{inputs[0]}: compare needs a reference log and at least one more log")
        out = args.out or Path("logs") / f"compare-{inputs[0].stem}"
        result = compare_existing(inputs, out, filter_window=getattr(args, "filter_window", None))
    elif len(inputs) == 1:
        from sim.tools.reference import Tolerance
        from sim.io.scenario import load_scenario

        scenario = load_scenario(inputs[0])
        for name in ("dt", "duration", "tolerance", "filter_window"):
            value = getattr(args, name, None)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise CircuitError(f"--{name.replace('_', '-')}: {value!r} must be a positive finite number")
        max_steps = getattr(args, "max_steps", None)
        if max_steps is not None and max_steps < 1:
            raise CircuitError(f"--max-steps: {max_steps!r} must be a positive number of steps")
        specs = parse_runs(args.modes or default_modes(), scenario.coupling)
        tolerance = Tolerance(relative=args.tolerance) if args.tolerance else None
        out = args.out or Path("logs") / f"compare-{scenario.scene_name}-{scenario.name}"
        result = compare_runs(scenario, specs, out, dt=args.dt, duration=args.duration, tolerance=tolerance,
                              cache_dir=args.cache, fresh_reference=args.fresh_reference or args.fresh, progress=True,
                              filter_window=getattr(args, "filter_window", None),
                              reference_options={"max_steps": args.max_steps} if getattr(args, "max_steps", None) else None)
    else:
        raise CircuitError(f"compare takes one scenario file or two or more .mcap logs, got {[str(p) for p in inputs]}")
    failed = [c for c in result.comparisons if not c.stable]
    code = EXIT_PARTIAL if failed else EXIT_OK
    text = sys.stderr if getattr(args, "json", False) else sys.stdout
    print(summary_table(result.comparisons), file=text)
    print(f"report: {result.report_path}", file=text)
    if result.merged_path:
        print(f"merged log: {result.merged_path}", file=text)
    if failed:
        print(f"compare: {len(failed)} of {len(result.comparisons)} runs not stable: "
              + ", ".join(f"{c.label} ({_status_text(c)})" for c in failed), file=sys.stderr)
    if getattr(args, "json", False):
        from sim.jsonout import emit

        emit(result_json(result, code))
    return code
