"""Accuracy against cost on the seed cylinder and the excavator approach: compare + tradeoff, printed.

    python bench/bench_tradeoff.py [--full] [--docs] [--scenes seed,excavator,excavator_ls] [--no-compare]
                                   [--scheduler tcp://host:port] [--workers N]

1. Seed cylinder (the seed report's Figure 3 scene), 0.1 s at the seed's 1200 Hz: the converged
   reference against MuJoCo implicit, MuJoCo explicit and, when the PBD plant imports, PBD (XPBD
   rows, implicit coupling) and naive PBD (the seed's explicit scheme) -- the seed's Figure 4.
2. Excavator dig cycle shortened to its first 1.75 s (hold, then boom down, stick out, bucket
   open onto its end stop, first contact at 1.58 s), at the scenario's 1 kHz: the same runs.
   Longer spans include the teeth stick-slipping through the soil, where the implicit MuJoCo
   reference does not converge point-wise at any step: below 31 µs every halving still moves
   the bucket cap pressure by ~4.7 bar (halving table in docs/validation.md); see ``--full-dig``.
2b. ``--full-dig``: the excavator comparison over the whole 20 s dig instead: reference proven on
   0.1 s moving averages (:data:`FULL_DIG_TOLERANCE`, ladder from :data:`FULL_DIG_START_DT`),
   runs :data:`FULL_DIG_RUNS` (MuJoCo implicit / implicit-linear / rosenbrock / explicit at 1 ms, PBD at
   60 Hz × 10 and × 40 substeps and 1 kHz × 20, ``incompressible`` at 1/30 s in both modes).
2c. ``--full-dig`` with the scene ``excavator_ls``: the load-sensing excavator's dig (``dig_ls``, the same spool
   commands on the load-sensing circuit) compared the same way over its whole 20 s (:data:`LS_DIG_RUNS`: MuJoCo
   implicit, implicit-linear and rosenbrock at 1 ms, PBD at 1 kHz with the scenario's 20 substeps and at 60 Hz × 40); it has no
   trade-off sweep.
3. The tradeoff sweep of both (``--full``: every setting of :func:`sim.tools.tradeoff.sweep_settings`,
   3 timed runs each, fidelity levels included (``incompressible`` at a frame-rate step, ``lines``);
   default: the quick sweep, with ``incompressible`` at dt0 and ≈ 1/30 s).

Outputs go to ``logs/bench-tradeoff/``; with ``--docs`` the figures (PNG), tables (CSV) and
Markdown are copied to ``docs/figures/``. References and sweep points are cached
(``.cache/references``, ``.cache/sweeps``), so a rerun only recomputes what changed.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.tools.compare import RunSpec, compare_runs, default_modes, parse_runs, summary_table  # noqa: E402
from sim.tools.reference import Tolerance  # noqa: E402
from sim.io.scenario import as_scenario  # noqa: E402
from sim.tools.tradeoff import pareto_table, stability_statements, tradeoff  # noqa: E402
from sim.tools.sweep import Cluster  # noqa: E402

SEED = ROOT / "models/seed_cylinder/closed.scenario.toml"
DIG = ROOT / "models/excavator/dig.scenario.toml"
DIG_LS = ROOT / "models/excavator/dig_ls.scenario.toml"
DIG_DURATION = 1.75  # s: up to just after the first contact (see the module docstring)
DOCS = ROOT / "docs/figures"
FULL_DIG_WINDOW = 0.1  # s: the reference of the full dig is proven on moving averages over this window
# Filtered changes: joints and strokes 1e-3 of their range; pressures 2 bar (0.54 % of the 373 bar port relief),
# above the step-independent ~1 bar spread of the 0.1 s averages during the stick-slip (halving table in docs/validation.md).
FULL_DIG_TOLERANCE = Tolerance(relative=1e-3, pressure=2e5)
FULL_DIG_START_DT = 1e-3 / 2**7  # s: ladder 7.8 µs → 3.9 µs (coarser pairs: see the halving table)
FULL_DIG_MAX_STEPS = 6_000_000
FULL_DIG_RUNS = {  # label -> (mode, coupling, overrides)
    "mujoco-implicit-1ms": ("mujoco", "implicit", {"dt": 1e-3}),
    "mujoco-implicit-linear-1ms": ("mujoco", "implicit-linear", {"dt": 1e-3}),
    "mujoco-rosenbrock-1ms": ("mujoco", "rosenbrock", {"dt": 1e-3}),
    "mujoco-explicit-1ms": ("mujoco", "explicit", {"dt": 1e-3}),
    "pbd-60Hz-x10": ("pbd", "implicit", {"dt": 1 / 60, "pbd_substeps": 10}),
    "pbd-60Hz-x40": ("pbd", "implicit", {"dt": 1 / 60, "pbd_substeps": 40}),
    "pbd-1kHz-x20": ("pbd", "implicit", {"dt": 1e-3, "pbd_substeps": 20}),
    "mujoco-incompressible-30Hz": ("mujoco", "implicit", {"dt": 1 / 30, "fidelity": "incompressible"}),
    "pbd-incompressible-30Hz": ("pbd", "implicit", {"dt": 1 / 30, "pbd_substeps": 10, "fidelity": "incompressible"}),
}

LS_DIG_RUNS = {  # the load-sensing excavator's runs against its reference (label -> mode, coupling, overrides)
    "mujoco-implicit-1ms": ("mujoco", "implicit", {"dt": 1e-3}),
    "mujoco-implicit-linear-1ms": ("mujoco", "implicit-linear", {"dt": 1e-3}),
    "mujoco-rosenbrock-1ms": ("mujoco", "rosenbrock", {"dt": 1e-3}),
    "pbd-1kHz": ("pbd", "implicit", {"dt": 1e-3}),
    "pbd-60Hz-x40": ("pbd", "implicit", {"dt": 1 / 60, "pbd_substeps": 40}),
}


def full_dig_compare(out: Path, scenario: Path = DIG, runs: dict = FULL_DIG_RUNS):
    """A dig's comparison over the whole cycle (see the module docstring, 2b and 2c): ``runs`` maps a label to
    (mode, coupling, overrides)."""
    specs = [RunSpec(mode, coupling, label) for label, (mode, coupling, _) in runs.items()
             if mode == "mujoco" or "pbd" in default_modes()]
    return compare_runs(scenario, specs, out, tolerance=FULL_DIG_TOLERANCE, filter_window=FULL_DIG_WINDOW,
                        progress=True,
                        reference_options={"start_dt": FULL_DIG_START_DT, "max_steps": FULL_DIG_MAX_STEPS},
                        run_overrides={label: o for label, (_, _, o) in runs.items()},
                        figure_runs=[label for label in runs if "incompressible" not in label])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="the full sweep (default: quick)")
    parser.add_argument("--docs", action="store_true", help="copy figures and tables to docs/figures/")
    parser.add_argument("--scheduler", help="Dask scheduler address (default: local process pool)")
    parser.add_argument("--workers", type=int, help="local worker processes (default: CPU count)")
    parser.add_argument("--out", type=Path, default=ROOT / "logs/bench-tradeoff")
    parser.add_argument("--scenes", default="seed,excavator,excavator_ls",
                        help="comma-separated subset of seed, excavator, excavator_ls (the last with --full-dig only)")
    parser.add_argument("--no-compare", action="store_true", help="only the tradeoff sweeps (no compare runs)")
    parser.add_argument("--full-dig", action="store_true", help="excavator compare over the whole 20 s dig "
                        "(reference on 0.1 s moving averages)")
    parser.add_argument("--no-tradeoff", action="store_true", help="only the compare runs (no tradeoff sweeps)")
    args = parser.parse_args(argv)
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    os.chdir(ROOT)  # the caches are relative to the repository
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}")
    modes = default_modes()
    if "pbd" not in modes:
        print("PBD plant not importable: comparing MuJoCo explicit and implicit only")
    outputs = {}
    for name, scenario, duration in (("seed", SEED, None), ("excavator", DIG, DIG_DURATION),
                                     ("excavator_ls", DIG_LS, None)):
        if name not in scenes or (name == "excavator_ls" and (args.no_compare or not args.full_dig)):
            continue
        started = time.perf_counter()
        out = None if args.no_compare else args.out / f"{name}-compare"
        if out is not None and name.startswith("excavator") and args.full_dig:
            out = args.out / f"{name}-compare-full"
            result = full_dig_compare(out, scenario, LS_DIG_RUNS if name == "excavator_ls" else FULL_DIG_RUNS)
            print(f"\n## {name}: compare, full dig ({time.perf_counter() - started:.0f} s), reference {result.reference_text}")
            print(summary_table(result.comparisons))
        elif out is not None:
            result = compare_runs(scenario, parse_runs(modes), out, duration=duration, progress=True)
            print(f"\n## {name}: compare ({time.perf_counter() - started:.0f} s), reference {result.reference_text}")
            print(summary_table(result.comparisons))
        if args.no_tradeoff or name == "excavator_ls":
            outputs[name] = (out, None)
            continue
        started = time.perf_counter()
        tout = args.out / f"{name}-tradeoff"
        t = tradeoff(as_scenario(scenario, duration=duration), tout, cluster=Cluster(args.scheduler, args.workers),
                     quick=not args.full, progress=True)
        print(f"\n## {name}: tradeoff, {len(t.rows)} settings ({time.perf_counter() - started:.0f} s)")
        for kind in ("stroke", "pressure"):
            for s in t.statements[kind]:
                print(f"- {s}")
        for s in stability_statements(t.rows):
            print(f"- {s}")
        print(pareto_table(t.rows))
        outputs[name] = (out, tout)
    if args.docs:
        DOCS.mkdir(parents=True, exist_ok=True)
        for name, (out, tout) in outputs.items():
            if out is not None:
                shutil.copyfile(out / "overlay.png", DOCS / f"{name}-compare-overlay.png")
                shutil.copyfile(out / "error.png", DOCS / f"{name}-compare-error.png")
                report = (out / "report.md").read_text().replace("(overlay.png)", f"({name}-compare-overlay.png)")
                (DOCS / f"{name}-compare.md").write_text(report.replace("(error.png)", f"({name}-compare-error.png)"))
            if tout is None:
                continue
            shutil.copyfile(tout / "pareto.png", DOCS / f"{name}-pareto.png")
            shutil.copyfile(tout / "tradeoff.csv", DOCS / f"{name}-tradeoff.csv")
            (DOCS / f"{name}-tradeoff.md").write_text((tout / "tradeoff.md").read_text().replace("(pareto.png)", f"({name}-pareto.png)"))
        print(f"\ncopied to {DOCS.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
